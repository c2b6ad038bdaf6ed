"""How much of a hidden effect is left to see after the fit, against the foreign renderer's physics.

Physics only: no camera, no tracker. For draws of the diagnose calibration's foreign family
(``benchmarks/diagnose_calibration.py``: scene ramp_20, the same parameter and effect-size draws
as its videos, MuJoCo's elliptic friction cone, a ramp board 10-20 mm thick whose thickness the
scene file states to the mm), the objects' positions at the video frames are taken as a
perfect tracker would give them (noiseless), and the model is fitted to them as ``fit --method
grad`` does (Levenberg-Marquardt on the C engine; MJX where the effect acts every physics step),
from its own starts and, as an oracle, from the truth (and the base model's fit, for the model
with the effect): the best fit the model has, not what a search finds.
Reported per draw, as the RMSE (m/s) of the velocity profile left after the fit:

* ``ours + effect``: our own physics with the hidden effect, fitted by the base model: the part
  of the effect that masses and frictions cannot absorb (what ``diagnose`` sees on our renders);
* ``foreign``: the foreign physics WITHOUT the effect, fitted by the base model: the part of the
  foreign physics the model cannot absorb (the "attainable" floor of a perfect tracker);
* ``foreign + effect``: the foreign physics with the effect, fitted by the base model (the null);
* ``foreign + effect, effect fitted``: the same, fitted by the model with the effect (the
  alternative). The drop from the null to it is all that ``diagnose`` could ever detect;
* the control: the model with the effect fitted to the foreign physics WITHOUT it, the gain
  the effect gets from absorbing the foreign physics alone (a false alarm's size).

Each drop is read as the likelihood-ratio statistic it would give at the foreign videos'
tracking noise (:func:`lr_at_floor`).

    python benchmarks/foreign_physics.py [--draws 5] [--effects linear_drag,quadratic_drag,ramp_friction]

(quadratic drag acts every physics step, so its fits run on MJX: on a 2-core CPU over 15
minutes a draw; linear drag and ramp friction run on C MuJoCo, 2-5 minutes a draw.)

Writes ``benchmarks/results/foreign_physics.{md,json}``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
#: Position SD (m) of every trace in the likelihood (no model-error floor): with one SD for all
#: traces the fit is least squares on the velocity profile.
POSITION_SD = 1e-4
#: Tracking noise floor (m/s, velocity RMSE) at which the likelihood-ratio statistic is read:
#: about the median floor of the foreign family's videos (``diagnose_calibration_foreign.md``).
FLOOR = 0.004


def observation_of(motion, fps: float):
    """A noiseless :class:`~galileo_jax.observation.Observation` of a simulated motion (every
    frame in the fit window)."""
    from galileo_jax.observation import Observation, profile_from_positions

    pos = np.asarray(motion.positions, float)
    ft = np.arange(pos.shape[0]) / fps
    # pixels: any fixed scale (the fit reads positions and the profile only)
    return Observation(frame_times=ft, positions=pos, pixels=pos * 1000.0, profile=profile_from_positions(pos, ft),
                       position_sd=np.full(2 * pos.shape[1], POSITION_SD), mask=np.ones(pos.shape[0] - 1, bool),
                       release_time=motion.release_time, fps=fps, moved=np.ones(pos.shape[1], bool))


def fitted_rmse(scene, obs, effects=(), starts=()) -> tuple[float, dict]:
    """RMSE (m/s) of the profile left after a multi-start LM fit, and the fitted parameters.

    ``starts``: parameter dicts tried as extra starts (one fit each; parameters they lack at
    their effect's neutral value), each kept as it is where the fit from it ends worse
    (Levenberg-Marquardt starts a bound's margin inside it and may stop short). With the base
    model's fit among them the model with the effect is never worse than it (as ``diagnose``
    starts its alternatives); with the truth among them the fit is the best the model can do
    (an oracle: on a ridge such as k1 against ``dk_ramp`` the plain multi-start fit stops far
    from the truth even on our own physics)."""
    import jax

    from galileo_jax.criticism.adequacy import profile_rmse
    from galileo_jax.criticism.diagnosis import DiagnoseSettings
    from galileo_jax.criticism.models import model_engine
    from galileo_jax.effects import get_effect
    from galileo_jax.inference.grad import fit_grad
    from galileo_jax.inference.problem import Problem

    problem = Problem(scene, obs, effects=effects, engine=model_engine([scene], effects, DiagnoseSettings()),
                      sd_model=0.0)
    neutral = {p.name: p.neutral for e in effects for p in get_effect(e).params}
    neutral["dt_release"] = 0.0
    best = (np.inf, None)
    for start in [None, *starts]:
        init = None if start is None else np.array([start.get(n, neutral.get(n, 0.0)) for n in problem.names])
        res = fit_grad(problem, jax.random.key(0), n_starts=4, n_screen=128, polish_rounds=1, init=init)
        for theta in [np.asarray(res.theta)] + ([] if init is None else [init]):
            rmse = profile_rmse(obs, np.asarray(problem.simulate(theta)))
            if rmse < best[0]:
                best = (rmse, theta)
    return best[0], {n: float(v) for n, v in zip(problem.names, best[1])}


def lr_at_floor(rmse_null: float, rmse_alt: float, n: int, floor: float = FLOOR) -> float:
    """The likelihood-ratio statistic 2 log(L1 / L0) that ``n`` velocity samples would give if
    white tracking noise of RMS ``floor`` (m/s) were added to the structural residuals of the two
    fits (RMSE ``rmse_null`` and ``rmse_alt``), each model's noise scale estimated from its own
    residuals: n log((floor^2 + rmse_null^2) / (floor^2 + rmse_alt^2)) (Gaussian likelihood with
    the noise scale profiled out, as ``diagnose``'s scaled LR). 3.8 is p = 0.05 for one parameter."""
    return float(n * np.log((floor**2 + rmse_null**2) / (floor**2 + rmse_alt**2)))


def one_draw(effect: str, i: int) -> dict:
    """Draw i of ``effect`` as the foreign family draws its videos; the fits above."""
    import diagnose_calibration as dc

    from galileo_jax.scene import load_scene
    from galileo_jax.synth import resolve_params, simulate_motion

    scene = load_scene(dc.scene_for(effect, ROOT / "scenes" / "ramp_20.yaml"))  # the family's default scene
    _, effects, timing, params, foreign = dc.foreign_draw(scene, effect, i, seed=0)  # its videos' draws
    thickness = foreign.ramp_thickness
    stated = scene.model_copy(update={"ramp": scene.ramp.model_copy(update={"thickness": round(thickness, 3)})})
    base = {k: params[k] for k in ("m1", "m2", "k1", "k2")}

    def observed(physics_scene, world, with_effect: bool):
        eff = effects if with_effect else ()
        motion = simulate_motion(physics_scene, resolve_params(physics_scene, params if with_effect else base, eff),
                                 dc.FPS, timing["rest_frames"], timing["n_frames"], effects=eff, world=world)
        return observation_of(motion, dc.FPS)

    t0 = time.perf_counter()
    rec = {"effect": effect, "draw": i, "hidden": {k: v for k, v in params.items() if k not in base},
           "truth": base, "ramp_thickness_m": thickness}
    truth = {"k1": params["k1"], "k2": params["k2"], "phi": (params["m1"] - params["m2"]) / (params["m1"] + params["m2"]),
             **{k: v for k, v in params.items() if k not in base}}
    rec["ours_effect"] = fitted_rmse(stated, observed(stated, None, True), starts=[truth])[0]
    both = observed(scene, foreign, True)
    n = int(np.asarray(both.profile).size)
    rec["foreign_effect"], null = fitted_rmse(stated, both, starts=[truth])
    rec["foreign_effect_fitted"], fit = fitted_rmse(stated, both, effects, starts=[null, truth])
    rec["fitted_effect"] = {k: v for k, v in fit.items() if k in rec["hidden"]}
    rec["lr"] = lr_at_floor(rec["foreign_effect"], rec["foreign_effect_fitted"], n)
    without = observed(scene, foreign, False)
    rec["foreign"], null0 = fitted_rmse(stated, without, starts=[truth])
    rec["foreign_fitted"], fit0 = fitted_rmse(stated, without, effects, starts=[null0, truth])
    rec["lr_control"] = lr_at_floor(rec["foreign"], rec["foreign_fitted"], n)
    rec["seconds"] = time.perf_counter() - t0
    return rec


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=5, help="draws per effect")
    ap.add_argument("--effects", default="linear_drag,quadratic_drag,ramp_friction")
    args = ap.parse_args(argv)
    import jax

    from galileo_jax.jaxcache import enable_compilation_cache
    from _common import machine_line, write_atomic
    from galileo_jax.report.results import write_json

    jax.config.update("jax_enable_x64", True)
    enable_compilation_cache()
    records = []
    for effect in args.effects.split(","):
        for i in range(args.draws):
            records.append(one_draw(effect, i))
            r = records[-1]
            print(f"{effect} {i}: ours+effect {r['ours_effect']:.4f}; foreign+effect {r['foreign_effect']:.4f} -> "
                  f"{r['foreign_effect_fitted']:.4f} (LR {r['lr']:.1f}); control {r['foreign']:.4f} -> "
                  f"{r['foreign_fitted']:.4f} (LR {r['lr_control']:.1f}) ({r['seconds']:.0f} s)", flush=True)
    doc = {"machine": machine_line(), "command": "python benchmarks/foreign_physics.py " + " ".join(argv or sys.argv[1:]),
           "floor_m_per_s": FLOOR, "records": records}
    write_json(RESULTS / "foreign_physics.json", doc)
    rows = ["| effect | draw | hidden value | fitted | ours + effect | foreign + effect | + effect fitted | LR "
            "| foreign | + effect fitted | control LR |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in records:
        (name, value), = r["hidden"].items()
        fitted = r["fitted_effect"].get(name, float("nan"))
        rows.append(f"| {r['effect']} | {r['draw']} | {name} {value:.3f} | {fitted:.3f} | {r['ours_effect']:.4f} | "
                    f"{r['foreign_effect']:.4f} | {r['foreign_effect_fitted']:.4f} | {r['lr']:.1f} | "
                    f"{r['foreign']:.4f} | {r['foreign_fitted']:.4f} | {r['lr_control']:.1f} |")
    md = ["# A hidden effect against the foreign renderer's physics (perfect tracking)", "",
          f"machine: {doc['machine']}", "", f"command: `{doc['command']}`", "",
          __doc__.split("\n\n")[1].replace("\n", " "), "",
          "RMSE (m/s) of the velocity profile left after each fit (module docstring). 'LR': the likelihood-ratio "
          f"statistic of the model with the effect against the base model, read at a tracking noise floor of {FLOOR} "
          "m/s (`lr_at_floor`), on the foreign physics with the effect and (control) without it.", "", *rows, ""]
    write_atomic(RESULTS / "foreign_physics.md", "\n".join(md))
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
