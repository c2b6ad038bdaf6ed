"""Does ``diagnose`` name the hidden effect, and stay quiet when there is none?

Renders videos of a scene (default ``scenes/ramp_20.yaml``, two boxes, 1.9 s at 30 fps;
``rolling``: ``scenes/roll_30.yaml``, 480x270, pixel noise) whose truth includes one hidden
effect with a value drawn from the effect's ``synth_range`` (or no effect), with random base
parameters drawn as ``synth --random`` draws them (:func:`galileo_jax.synth.draw_informative_params`:
object 1 slides and reaches object 2, or the floor), tracks them, runs
:func:`galileo_jax.criticism.diagnosis.diagnose` with every applicable candidate, and records per video:
the decision, whether the hidden effect was named first, and the base and final RMSE against
two floors: the tracker's noise floor (what a user sees, :func:`galileo_jax.criticism.noise.noise_floor`)
and the *attainable* floor, the RMSE of the simulation at the true parameters (hidden effect
included) against the tracked profile, on the engine the diagnosis fits that model on (C
MuJoCo, the renderer's own, or MJX for effects that act every step, whose error against the
C MuJoCo renderer it then also holds). Issue 3's targets: for each effect, named first on >= 4 of 5
videos with the RMSE falling >= 2x to <= 1.3x the noise floor; with no effect, "no missing
effect" on >= 19 of 20.

Two families of videos (``--family``):

* ``ours``: the renderer's defaults, the physics diagnose fits (orthographic camera, 480x270,
  pixel noise SD 2), effect values drawn from each effect's ``synth_range``;
* ``foreign``: videos the model cannot reproduce exactly (:func:`render_foreign`): a perspective
  camera 1.8-2.6 m away whose scale file is exact only in the plane of the objects' centres
  (their tracked faces are 1-2% nearer), MuJoCo's elliptic friction cone, the ramp a board
  10-20 mm thick with an edge at its foot (:class:`galileo_jax.physics.model.WorldPhysics`), 640x360,
  pixel noise SD 1.5-3, the hand in every other video, either direction, and effects of the
  sizes real ones have (:func:`realistic_effect_values`). The scene file is the one a user would
  write (no calibration tolerance): diagnose's default calibration nuisances are what cope with
  the scale error. The board's thickness is stated in it as measured with a ruler (to the mm,
  :func:`stated_scene`);
* ``foreign_board_unstated``: the same videos with a scene file that leaves the board out (a
  flush ramp): what happens when a user does not describe their setup.

Resumable: each video's record is written to ``<out>/<effect>_<i>.json`` and skipped when
present. The summary goes to ``benchmarks/results/diagnose_calibration.{md,json}``. The
diagnoses can be spread over processes or machines: ``--stage render`` renders the videos
(and their ``.truth.json``) into ``--out``; ``--stage analyse --indices 1`` diagnoses the
rendered ones there, one process per video if wanted.

    python benchmarks/diagnose_calibration.py --effects none,quadratic_drag --videos 5
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
from _common import code_version, machine_line, rendered, write_atomic  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: Video timing of every rendered video (frames per second, seconds).
FPS, DURATION = 30.0, 1.9
RESULTS = ROOT / "benchmarks" / "results"


#: The scene of each hidden effect: rolling needs a round object alone on the ramp (MJX cannot
#: collide a cylinder with a box), every other effect the two-box 20 degree ramp.
SCENES = {"rolling": ROOT / "scenes" / "roll_30.yaml"}


def scene_for(effect: str, default: Path) -> Path:
    return SCENES.get(effect, default)


def render_one(scene_path: Path, effect: str, i: int, work: Path, seed: int) -> tuple[Path, float]:
    """Render video ``<work>/<effect>_<i>.mp4`` (with its ``.yaml`` scene and ``.truth.json``)
    from parameters drawn for this (effect, index, seed); kept if already there. Returns its
    path and the render time in s (nan when it was already there)."""
    from galileo_jax.effects import get_effect
    from galileo_jax.scene import load_scene
    from galileo_jax.synth import draw_informative_params, render_video

    video = work / f"{effect}_{i}.mp4"
    if rendered(video, (".truth.json", ".yaml")):
        return video, float("nan")
    scene = load_scene(scene_path)
    rng = np.random.default_rng(seed * 1000 + i + 17 * len(effect))
    effects = () if effect == "none" else (get_effect(effect).name,)
    params = draw_informative_params(scene, rng, effects, fps=FPS, rest_frames=round(0.3 * FPS),
                                     n_frames=int(round(DURATION * FPS)))
    t0 = time.perf_counter()
    render_video(scene, params, video, fps=FPS, duration=DURATION, width=480, height=270, noise_sd=2.0,
                 seed=seed + i, progress=False, effects=effects)
    return video, time.perf_counter() - t0


#: Fraction of the net slide acceleration g (sin - k cos) that air drag takes at object 1's top
#: speed on the ramp in the foreign family (issue: real drag is 10-20%).
DRAG_FRACTION = (0.10, 0.20)
#: Realistic effect sizes of the foreign family, by parameter (uniform; velocity_friction's sign
#: drawn at random). ``restitution`` stops at the fitted parameter's upper bound, 0.8 (real: 0.7-0.9).
REALISTIC = {"restitution": (0.7, 0.8), "dk_ramp": (-0.08, -0.05), "v0": (0.3, 0.5), "dk_dv": (0.1, 0.2)}


def realistic_effect_values(scene, effect: str, params: dict, rng: np.random.Generator) -> dict:
    """Effect values of the sizes real ones have, for drawn base ``params``: air drag taking
    :data:`DRAG_FRACTION` of the net acceleration a = g (sin - k1 cos) at object 1's speed at
    the ramp's foot without drag, v^2 = 2 a d (d: its start distance along the ramp), i.e.
    c = f / (2 d) for quadratic drag (a_drag = c v^2) and b = f a / v for linear drag
    (a_drag = b v); the others from :data:`REALISTIC`. Returns {parameter: value}."""
    import math

    if effect in ("none", "rolling"):
        return {}
    if effect in ("quadratic_drag", "linear_drag"):
        f = rng.uniform(*DRAG_FRACTION)
        d = scene.objects[0].start
        a = scene.gravity * (math.sin(scene.ramp.angle) - params["k1"] * math.cos(scene.ramp.angle))
        if effect == "quadratic_drag":
            return {"drag_quadratic": f / (2 * d)}
        return {"drag_linear": f * a / math.sqrt(2 * a * d)}
    from galileo_jax.effects import get_effect

    (param,) = [p.name for p in get_effect(effect).params]
    value = rng.uniform(*REALISTIC[param])
    return {param: value * (rng.choice([-1.0, 1.0]) if param == "dk_dv" else 1.0)}


def foreign_draw(scene, effect: str, i: int, seed: int):
    """Draw i of ``effect`` in the foreign family (module docstring): the hidden effect, the
    parameters with effect values of realistic size, and the world's physics (elliptic cone, a
    board 10-20 mm thick). Returns ``(rng, effects, timing, params, world)``; ``rng`` goes on to
    draw the video's look (:func:`render_foreign`)."""
    from galileo_jax.effects import get_effect
    from galileo_jax.physics.model import WorldPhysics
    from galileo_jax.synth import draw_informative_params

    rng = np.random.default_rng(seed * 1000 + i + 17 * len(effect) + 500_000)
    effects = () if effect == "none" else (get_effect(effect).name,)
    timing = dict(fps=FPS, rest_frames=round(0.3 * FPS), n_frames=int(round(DURATION * FPS)))
    # a drag's realistic size depends on k1: draw with a small drag, then set it (less drag only
    # lets object 1 go farther, so the draw stays informative)
    provisional = {"drag_quadratic": 0.05, "drag_linear": 0.1} if effect in ("quadratic_drag", "linear_drag") else {}
    values = {} if provisional else realistic_effect_values(scene, effect, {}, rng)
    params = draw_informative_params(scene, rng, effects, fixed_effects={**provisional, **values}, **timing)
    params.update(realistic_effect_values(scene, effect, params, rng) if provisional else {})
    world = WorldPhysics(cone="elliptic", ramp_thickness=float(rng.uniform(0.01, 0.02)))
    return rng, effects, timing, params, world


def render_foreign(scene_path: Path, effect: str, i: int, work: Path, seed: int) -> tuple[Path, float]:
    """Render video ``<work>/<effect>_<i>.mp4`` of the foreign family (module docstring), kept if
    already there. Returns its path and the render time in s (nan when it was already there)."""
    from galileo_jax.scene import load_scene
    from galileo_jax.synth import render_video

    video = work / f"{effect}_{i}.mp4"
    if rendered(video, (".truth.json", ".yaml")):
        return video, float("nan")
    scene = load_scene(scene_path)
    rng, effects, _, params, world = foreign_draw(scene, effect, i, seed)
    t0 = time.perf_counter()
    render_video(scene, params, video, fps=FPS, duration=DURATION, width=640, height=360,
                 noise_sd=float(rng.uniform(1.5, 3.0)), hand=bool(i % 2), seed=seed + i, progress=False,
                 effects=effects, look="checker", camera="perspective", camera_distance=float(rng.uniform(1.8, 2.6)),
                 direction="left" if i % 4 >= 2 else "right", world=world)
    return video, time.perf_counter() - t0


#: Renderer of each family of videos.
FAMILIES = {"ours": render_one, "foreign": render_foreign, "foreign_board_unstated": render_foreign}


def stated_scene(scene, family: str, truth: dict):
    """The scene file a user of ``family`` writes: for ``foreign``, the ramp board's thickness
    measured with a ruler (the true one rounded to the mm) in ``ramp.thickness``; for
    ``foreign_board_unstated`` (and ``ours``) the scene as rendered (a flush ramp)."""
    t = (truth.get("world") or {}).get("ramp_thickness", 0.0)
    if family != "foreign" or not t:
        return scene
    return scene.model_copy(update={"ramp": scene.ramp.model_copy(update={"thickness": round(float(t), 3)})})


def run_one(scene_path: Path, effect: str, i: int, work: Path, seed: int, family: str = "ours",
            search_patience: int | None = None) -> dict:
    """Render (unless already rendered) and diagnose one video; the record written per video."""
    from galileo_jax.criticism.diagnosis import diagnose, DiagnoseSettings
    from galileo_jax.observe import observe, read_video
    from galileo_jax.scene import load_scene

    video, t_render = FAMILIES[family](scene_path, effect, i, work, seed)
    truth = json.loads(video.with_suffix(".truth.json").read_text())
    effects = tuple(truth["hidden_effects"])
    params = {k: truth[k] for k in ("m1", "k1", "m2", "k2") if k in truth}
    for name in effects:
        params.update(truth["effects"][name])
    rendered_scene = stated_scene(load_scene(video.with_suffix(".yaml")), family, truth)
    clip = read_video(video, fps_override=rendered_scene.video.fps)
    obs = observe(clip, rendered_scene, progress=False)
    t1 = time.perf_counter()
    diag = diagnose(rendered_scene, obs, DiagnoseSettings(search_patience=search_patience), seed=seed)
    d = diag.decision
    attainable = attainable_rmse(rendered_scene, obs, params, effects, truth["release_time"])
    first = d["missing_effects"][0] if d["missing_effects"] else None
    tied = [e for r in diag.rounds[:1] if r.indistinguishable for e in r.indistinguishable["effects"]]
    screen = diag.rounds[0].screen if diag.rounds else []
    rank = next((k + 1 for k, r in enumerate(screen) if r["effect"] == effect), None)
    return {"effect": effect, "index": i, "family": family, "truth": params,
            "unexplained_misfit": bool(d.get("unexplained_misfit", False)),
            "stated_ramp_thickness": rendered_scene.ramp.thickness,
            "calibration": diag.calibration(), "world": truth.get("world"), "decision": d["message"], "named_first": first,
            "correct": (first == effect) if effect != "none" else (first is None),
            "tied_with_truth": effect in tied, "tied": tied,
            "screen_rank_of_truth": rank, "rmse_base": d["rmse_base"], "rmse_final": d["rmse_final"],
            "noise_floor": d["noise_floor"], "rmse_drop_factor": d["rmse_base"] / max(d["rmse_final"], 1e-12),
            "final_over_floor": d["rmse_ratio_to_floor"], "attainable_rmse": attainable,
            "final_over_attainable": d["rmse_final"] / attainable,
            "refits": [{k: getattr(x, k) for k in ("effect", "engine", "delta_loglik", "lr_scaled", "p_value",
                                                   "rmse_after", "negligible", "supported")}
                       for x in (diag.rounds[0].refits if diag.rounds else [])],
            "screen": screen, "verdict_base": d["verdict_base"], "verdict_final": d["verdict_final"],
            "fitted": {f.name: {n: [float(v), float(lo), float(hi)] for n, v, (lo, hi) in
                                zip(f.result.names, f.result.theta, f.result.interval90)} for f in diag.fits},
            "render_s": t_render, "diagnose_s": time.perf_counter() - t1, "timings": diag.timings,
            "code": code_version("benchmarks/diagnose_calibration.py")}


def attainable_rmse(scene, obs, params: dict, effects, release_time: float) -> float:
    """RMSE (m/s) of the simulation at the TRUE parameters (hidden effects included, true
    release time) against the tracked profile, on the engine ``diagnose`` fits that model on
    (:func:`galileo_jax.criticism.diagnosis.model_engine`): the best any fit of the right model can do."""
    from galileo_jax.criticism.diagnosis import DiagnoseSettings
    from galileo_jax.criticism.models import model_engine
    from galileo_jax.criticism.adequacy import profile_rmse
    from galileo_jax.inference.problem import Problem

    problem = Problem(scene, obs, effects=effects, engine=model_engine([scene], effects, DiagnoseSettings()))
    values = dict(params)
    if "phi" in problem.names:
        values["phi"] = (params["m1"] - params["m2"]) / (params["m1"] + params["m2"])
    values["dt_release"] = 0.0
    theta = np.array([values[n] for n in problem.names])
    if "dt_release" in problem.names:  # the fit's release time, less any effect's release delay
        delay = float(problem.engine.release_time(theta, problem.data)) - obs.release_time
        theta[problem.names.index("dt_release")] = release_time - obs.release_time - delay
    return profile_rmse(obs, np.asarray(problem.simulate(theta)))


def unexplained(record: dict) -> bool:
    """No effect named though the base model misfits beyond 1.3x the floor with structured
    residuals (the decision's ``unexplained_misfit``; derived for records written before it
    existed)."""
    if "unexplained_misfit" in record:
        return bool(record["unexplained_misfit"])
    return (record["named_first"] is None and "already fits" not in record["decision"]
            and record["rmse_base"] > 1.3 * record["noise_floor"]
            and "look like noise" not in (record.get("verdict_base") or ""))


def summarize(records: list[dict]) -> dict:
    out = {}
    for effect in sorted({r["effect"] for r in records}):
        rs = [r for r in records if r["effect"] == effect]
        row = {"videos": len(rs), "correct": sum(r["correct"] for r in rs),
               "unexplained_misfit": sum(unexplained(r) for r in rs)}
        if effect != "none":
            row["correct_or_tied"] = sum(r["correct"] or r.get("tied_with_truth", False) for r in rs)
            ok = [r for r in rs if r["correct"] and r["rmse_drop_factor"] >= 2 and r["final_over_floor"] <= 1.3]
            row["correct_and_rmse_targets"] = len(ok)
            ok = [r for r in rs if r["correct"] and r["rmse_drop_factor"] >= 2 and r["final_over_attainable"] <= 1.3]
            row["correct_and_rmse_targets_attainable"] = len(ok)
            row["median_drop_factor"] = float(np.median([r["rmse_drop_factor"] for r in rs]))
            row["median_final_over_floor"] = float(np.median([r["final_over_floor"] for r in rs]))
            row["median_final_over_attainable"] = float(np.median([r["final_over_attainable"] for r in rs]))
        row["median_diagnose_s"] = float(np.median([r["diagnose_s"] for r in rs]))
        out[effect] = row
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=str(ROOT / "scenes" / "ramp_20.yaml"))
    ap.add_argument("--effects", default="none,quadratic_drag,linear_drag,restitution,ramp_friction,initial_push,"
                                         "velocity_friction,rolling")
    ap.add_argument("--videos", type=int, default=5, help="videos per hidden effect")
    ap.add_argument("--null-videos", type=int, default=20, help="videos without a hidden effect")
    ap.add_argument("--family", choices=tuple(FAMILIES), default="ours",
                    help="ours: our renderer's defaults; foreign: videos the model cannot reproduce exactly "
                         "(module docstring)")
    ap.add_argument("--out", default=None, help="folder of the videos and per-video records (default "
                    "benchmarks/results/diagnose_calibration[_foreign]/)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--stage", choices=("all", "render", "analyse"), default="all",
                    help="render: only render the videos (kept in --out); analyse: only diagnose videos already "
                         "rendered there (to spread the diagnoses over machines); all: both")
    ap.add_argument("--indices", default=None, help="only these video indices (comma-separated), e.g. 1,2")
    ap.add_argument("--search-patience", type=int, default=None,
                    help="DiagnoseSettings.search_patience (default: its default, off)")
    args = ap.parse_args(argv)
    from galileo_jax.jaxcache import enable_compilation_cache

    enable_compilation_cache()
    stem = table_stem(args.family)
    work = Path(args.out or RESULTS / stem)
    work.mkdir(parents=True, exist_ok=True)
    effects = [e.strip() for e in args.effects.split(",") if e.strip()]
    only = {int(x) for x in args.indices.split(",")} if args.indices else None
    for i in range(max(args.videos, args.null_videos)):
        for effect in effects:
            if i >= (args.null_videos if effect == "none" else args.videos) or (only is not None and i not in only):
                continue
            path = work / f"{effect}_{i}.json"
            if path.exists():
                continue
            scene_path = scene_for(effect, Path(args.scene))
            if args.stage == "render":
                print(f"rendered {FAMILIES[args.family](scene_path, effect, i, work, args.seed)[0]}", flush=True)
                continue
            if args.stage == "analyse" and not (work / f"{effect}_{i}.mp4").exists():
                print(f"{effect} #{i}: not rendered, skipped", flush=True)
                continue
            rec = run_one(scene_path, effect, i, work, args.seed, args.family, args.search_patience)
            write_atomic(path, json.dumps(rec, indent=1, default=float))
            print(f"{effect} #{i}: {rec['decision']} ({rec['diagnose_s']:.0f} s)", flush=True)
            (work / f"{effect}_{i}.mp4").unlink(missing_ok=True)
            write_tables(work, args.family)  # after every video: a stopped run still leaves its tables
    if args.stage != "render":
        write_tables(work, args.family)
    return 0


def table_stem(family: str) -> str:
    """File stem of a family's tables and default work folder under benchmarks/results."""
    return "diagnose_calibration" + ("" if family == "ours" else f"_{family}")


def _named_fit(record: dict) -> str:
    """The named effect's fitted parameters with their 90% intervals ('-' if none, or not recorded)."""
    from galileo_jax.effects import get_effect

    name = record.get("named_first")
    fit = record.get("fitted", {}).get(f"base + {name}") if name else None
    if not fit:
        return "-"
    params = [p.name for p in get_effect(name).params]
    return ", ".join(f"{p} {fit[p][0]:.3g} [{fit[p][1]:.3g}, {fit[p][2]:.3g}]" for p in params if p in fit) or "-"


def _scale_error(record: dict) -> str:
    """The base model's fitted camera scale error in percent with its 90% interval ('-' if none)."""
    fit = record.get("calibration", {}).get("base", {}).get("scale_error")
    if not fit or fit.get("best") is None:
        return "-"
    lo, hi = fit["interval90"]
    return f"{100 * fit['best']:+.1f}% [{100 * lo:+.1f}, {100 * hi:+.1f}]"


def write_tables(work: Path, family: str = "ours") -> None:
    """Summarise every record under ``work`` into benchmarks/results/<:func:`table_stem`>.{md,json}."""
    stem = table_stem(family)
    records = [json.loads(p.read_text()) for p in sorted(work.glob("*.json")) if not p.name.endswith(".truth.json")]
    summary = summarize(records)
    machine = machine_line()
    write_atomic(RESULTS / f"{stem}.json", json.dumps({"machine": machine, "summary": summary,
                                                                   "records": records}, indent=1, default=float))
    foreign = "foreign renders: perspective camera, elliptic friction cone, ramp board with an edge, realistic effect sizes"
    title = {"ours": "rendered videos", "foreign": foreign + "; the scene file states the board's thickness",
             "foreign_board_unstated": foreign + "; the scene file leaves the board out"}[family]
    lines = [f"# diagnose calibration ({title}; scene ramp_20, rolling: roll_30)", "", f"machine: {machine}", "",
             f"Command: `python benchmarks/diagnose_calibration.py --family {family}` (resumable). 'named correctly': the hidden effect "
             "is the one named first (none: 'no missing effect'); 'or tied': named first, or reported as "
             "indistinguishable from the one named first; 'unexplained': no effect named, but the base model "
             "misfits beyond 1.3x the floor and the report says so. 'floor': the tracker's noise floor; 'attainable': the RMSE "
             "of the simulation at the true parameters, on the engine diagnose fits that model on (module docstring).",
             "",
             "| hidden effect | videos | named correctly | named or tied | unexplained | "
             "+ RMSE >= 2x lower, <= 1.3x floor | + RMSE >= 2x lower, <= 1.3x attainable | median RMSE drop | "
             "median final/floor | median final/attainable | median time (s) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    nan = float("nan")
    for effect, row in summary.items():
        lines.append(f"| {effect} | {row['videos']} | {row['correct']} | {row.get('correct_or_tied', '-')} | "
                     f"{row.get('unexplained_misfit', 0)} | "
                     f"{row.get('correct_and_rmse_targets', '-')} | {row.get('correct_and_rmse_targets_attainable', '-')} | "
                     f"{row.get('median_drop_factor', nan):.2f} | {row.get('median_final_over_floor', nan):.2f} | "
                     f"{row.get('median_final_over_attainable', nan):.2f} | {row['median_diagnose_s']:.0f} |")
    lines += ["", "Per video (RMSE in m/s: base fit -> final model, noise floor, attainable). (b): diagnosed on "
              "another machine (its record's `ran_on`; e.g. the lent machine's CPU cores, one video per core), "
              "same code and video.", "",
              "| video | hidden value | named first | its fit (90%) | tied | RMSE base -> final (floor, attainable) "
              "| scale error, base model (90%) | time (s) |", "|---|---|---|---|---|---|---|---|"]
    for r in records:
        hidden = ", ".join(f"{k} {v:.3g}" for k, v in r["truth"].items() if k not in ("m1", "k1", "m2", "k2")) or "-"
        lines.append(f"| {r['effect']}_{r['index']} | {hidden} | {r['named_first'] or 'none'} | {_named_fit(r)} | "
                     f"{', '.join(r['tied']) or '-'} | {r['rmse_base']:.4f} -> {r['rmse_final']:.4f} "
                     f"({r['noise_floor']:.4f}, {r.get('attainable_rmse', nan):.4f}) | {_scale_error(r)} | "
                     f"{r['diagnose_s']:.0f}"
                     f"{' (b)' if r.get('ran_on') else ''} |")
    write_atomic(RESULTS / f"{stem}.md", "\n".join(lines) + "\n")


if __name__ == "__main__":
    sys.exit(main())
