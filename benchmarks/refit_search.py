"""Does the CMA-ES search after a refit's LM (``DiagnoseSettings.refit_search``) reach the noise floor?

For rendered calibration videos (``benchmarks/diagnose_calibration.py``: the video, its scene
``.yaml`` and ``.truth.json`` in ``--videos-dir``, its diagnose record in
``benchmarks/results/diagnose_calibration/``), repeats diagnose's refit of the HIDDEN effect
from the record's base estimate and screen (:func:`galileo_jax.criticism.diagnosis.refit_init`,
:func:`galileo_jax.criticism.diagnosis.fit_model`), with the search, and reports the profile RMSE of
the LM-only refit in the record ('before') and of the new refit ('after') against the noise
floor and the attainable RMSE (the MJX simulation at the true parameters). Issue 3's target:
the RMSE with the effect added within 1.3x the noise floor. This measures the refit only; whether
``diagnose`` names the effect first needs the full calibration.

Resumable: one record per video in ``--out``; tables in ``benchmarks/results/refit_search.{md,json}``.

    python benchmarks/refit_search.py --videos-dir .calib linear_drag_3 quadratic_drag_1
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from types import SimpleNamespace

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from _common import code_version, machine_line, write_atomic  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
RECORDS = RESULTS / "diagnose_calibration"


def run_one(name: str, videos: Path) -> dict:
    """Refit ``name``'s hidden effect with the search; the record (dict) of before/after."""
    import jax

    from galileo_jax.criticism.diagnosis import DiagnoseSettings

    from galileo_jax.criticism.models import candidate_effects, fit_model, Union

    from galileo_jax.criticism.screening import refit_init
    from galileo_jax.effects import available_effects
    from galileo_jax.observe import observe, read_video
    from galileo_jax.scene import load_scene

    rec = json.loads((RECORDS / f"{name}.json").read_text())
    truth = json.loads((videos / f"{name}.truth.json").read_text())
    effect = available_effects()[rec["effect"]]
    scene = load_scene(videos / f"{name}.yaml")
    obs = observe(read_video(videos / f"{name}.mp4", fps_override=scene.video.fps), scene, progress=False)
    settings = DiagnoseSettings()
    union = Union([scene], [obs], [e for e in candidate_effects(scene, None) if e.params], settings)
    names = union.problem.names
    base = SimpleNamespace(result=SimpleNamespace(theta=np.array([rec["fitted"]["base"][n][0] for n in names]),
                                                  fixed=tuple(union.held(()))))
    init = refit_init(union, base, effect, rec["screen"])
    t = time.perf_counter()
    fit = fit_model(union, (effect.name,), settings, jax.random.PRNGKey(7), init=init,
                    starts=settings.refit_starts, screen=settings.refit_screen)
    refit_s = time.perf_counter() - t
    before = next((r["rmse_after"] for r in rec["refits"] if r["effect"] == effect.name), float("nan"))
    params = truth["effects"][effect.name]
    fitted = {p.name: fit.summary["parameters"][p.name]["mean"] for p in effect.params}
    return {"video": name, "effect": effect.name, "truth": params, "fitted": fitted, "noise_floor": rec["noise_floor"],
            "attainable_rmse": rec["attainable_rmse"], "rmse_base": rec["rmse_base"], "rmse_before": before,
            "rmse_lm": (fit.search or {}).get("rmse_lm", float("nan")), "rmse_after": fit.rmse, "after_over_floor": fit.rmse / rec["noise_floor"],
            "search": fit.search, "refit_s": refit_s, "named_first_in_record": rec["named_first"],
            "code": code_version("benchmarks/refit_search.py"), "machine": machine_line()}


def write_tables(out: Path) -> None:
    recs = [json.loads(p.read_text()) for p in sorted(out.glob("*.json"))]
    lines = ["# Refit with CMA-ES search (rendered calibration videos)", "",
             f"machine: {machine_line()}", "",
             "Command: `python benchmarks/refit_search.py --videos-dir DIR NAME ...`. The hidden effect's refit, "
             "from the base estimate and screen of the video's diagnose record: 'record' is that record's refit "
             "(LM from screened starts; older code, other random starts), 'LM' this run's LM end, 'after' the "
             "same refit followed by 40 CMA-ES generations of 32 and LM again (`DiagnoseSettings.refit_search`). "
             "RMSE in m/s; target: after <= 1.3x floor.", "",
             "| video | truth | fitted | RMSE base | record | LM | after | floor | attainable | after/floor | "
             "search gain (nats) | refit (s) |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in recs:
        s = r["search"] or {}
        gain = s.get("loglik", np.nan) - s.get("loglik_lm", np.nan)
        lines.append(f"| {r['video']} | {', '.join(f'{k} {v:.3g}' for k, v in r['truth'].items())} | "
                     f"{', '.join(f'{v:.3g}' for v in r['fitted'].values())} | {r['rmse_base']:.4f} | "
                     f"{r['rmse_before']:.4f} | {r.get('rmse_lm', np.nan):.4f} | {r['rmse_after']:.4f} | {r['noise_floor']:.4f} | "
                     f"{r['attainable_rmse']:.4f} | {r['after_over_floor']:.2f} | {gain:.2f} | {r['refit_s']:.0f} |")
    ok_b = sum(r["rmse_before"] <= 1.3 * r["noise_floor"] for r in recs)
    ok_lm = sum(r.get("rmse_lm", np.inf) <= 1.3 * r["noise_floor"] for r in recs)
    ok_a = sum(r["after_over_floor"] <= 1.3 for r in recs)
    lines += ["", f"Within 1.3x the floor: record {ok_b}, LM {ok_lm}, after the search {ok_a}, of {len(recs)}."]
    write_atomic(RESULTS / "refit_search.md", "\n".join(lines) + "\n")
    write_atomic(RESULTS / "refit_search.json", json.dumps(recs, indent=1, default=float))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="+", help="calibration video names, e.g. linear_drag_3")
    ap.add_argument("--videos-dir", required=True, help="folder with <name>.mp4, .yaml and .truth.json")
    ap.add_argument("--out", default=str(RESULTS / "refit_search"))
    args = ap.parse_args(argv)
    from galileo_jax.jaxcache import enable_compilation_cache

    enable_compilation_cache()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name in args.names:
        path = out / f"{name}.json"
        if not path.exists():
            rec = run_one(name, Path(args.videos_dir))
            write_atomic(path, json.dumps(rec, indent=1, default=float))
            print(f"{name}: RMSE {rec['rmse_before']:.4f} -> {rec['rmse_after']:.4f} "
                  f"({rec['after_over_floor']:.2f}x floor, {rec['refit_s']:.0f} s)", flush=True)
        write_tables(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
