"""Wall time of fitting N videos of one scene one by one (``fit_grad`` per video) vs as one
batched computation (``fit_grad_batch``), on one device and on 2 forced host devices.

    python benchmarks/batch_fit.py [--videos 6] [--engine mujoco|mjx] [--devices 1 2]

N simulated two-box videos of the 20 degree scene (1.5 s at 30 fps, 1 mm position noise,
random k1 in [0.1, 0.3], k2 in [0.1, 0.4], masses in [0.2, 0.8] kg; the release time is fitted),
``grad``'s default settings (4 of 256 screened starts, 40 LM steps, 3 polish rounds of 64).
Each device count runs in its own process (``XLA_FLAGS=--xla_force_host_platform_device_count=D``
must be set before JAX starts); in each, both ways run once to compile (reported as "first")
and then once more, timed ("time"). The batched estimates are compared with the one-by-one
ones (max |difference| of theta). Writes ``benchmarks/results/batch_fit.{md,json}``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "batch_fit"
sys.path.insert(0, str(ROOT / "benchmarks"))


def worker(n_videos: int, engine: str) -> dict:
    """Run both ways in this process; return the record (JSON-ready)."""
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    from galileo_jax.jaxcache import enable_compilation_cache

    enable_compilation_cache()
    import jax
    import jax.numpy as jnp
    import numpy as np

    from galileo_jax.inference.batch import batch_problems, fit_grad_batch
    from galileo_jax.inference.grad import fit_grad
    from galileo_jax.inference.problem import simulated_observation
    from galileo_jax.physics.simulate import PhysParams
    from galileo_jax.scene import load_scene

    scene = load_scene(ROOT / "scenes" / "ramp_20.yaml")
    rng = np.random.default_rng(0)
    obs = []
    for i in range(n_videos):
        m = rng.uniform(0.2, 0.8, 2)
        k = np.array([rng.uniform(0.1, 0.3), rng.uniform(0.1, 0.4)])
        obs.append(simulated_observation(scene, PhysParams(jnp.asarray(m), jnp.asarray(k)), duration=1.5, seed=i))
    problems = batch_problems(scene, obs, engine=engine)
    key = jax.random.key(0)
    rec = {"devices": len(jax.local_devices()), "engine": engine, "videos": n_videos}
    for label, run in (("one_by_one", lambda: [fit_grad(p, key) for p in problems]),
                       ("batched", lambda: fit_grad_batch(problems, key))):
        t = time.perf_counter()
        run()
        rec[f"{label}_first_s"] = time.perf_counter() - t
        t = time.perf_counter()
        res = run()
        rec[f"{label}_s"] = time.perf_counter() - t
        rec[f"{label}_theta"] = [r.theta.tolist() for r in res]
        rec[f"{label}_lm_steps"] = int(sum(int(r.starts_iterations.sum()) for r in res))
    rec["max_abs_theta_diff"] = float(np.max(np.abs(np.asarray(rec["batched_theta"])
                                                    - np.asarray(rec["one_by_one_theta"]))))
    rec["speedup"] = rec["one_by_one_s"] / rec["batched_s"]
    return rec


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--videos", type=int, default=6)
    ap.add_argument("--engine", choices=("mujoco", "mjx"), default="mujoco")
    ap.add_argument("--devices", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        print("RECORD " + json.dumps(worker(args.videos, args.engine)), flush=True)
        return 0
    from _common import machine_line

    from galileo_jax.report.results import atomic_path, write_json

    records = []
    for d in args.devices:
        env = dict(os.environ, JAX_PLATFORMS="cpu", XLA_FLAGS=f"--xla_force_host_platform_device_count={d}")
        proc = subprocess.run([sys.executable, __file__, "--worker", "--videos", str(args.videos), "--engine",
                               args.engine], capture_output=True, text=True, env=env, cwd=ROOT)
        lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RECORD ")]
        if not lines:
            sys.exit(f"worker with {d} device(s) failed (rc {proc.returncode}): {proc.stderr[-2000:]}")
        rec = json.loads(lines[-1][len("RECORD "):])
        rec["worker_rc"] = proc.returncode
        records.append(rec)
    command = f"python benchmarks/batch_fit.py --videos {args.videos} --engine {args.engine} --devices " + \
        " ".join(map(str, args.devices))
    doc = {"machine": machine_line(), "command": command, "records": records}
    write_json(OUT.with_suffix(".json"), doc)
    lines = ["# Batched fits: N videos of one scene one by one vs as one batched computation", "",
             f"machine: {doc['machine']}", "", f"Command: `{command}` (module docstring of `benchmarks/batch_fit.py`). "
             "grad's default settings per video; time: a second run after a first (compiling) one, persistent "
             "compilation cache on; devices: forced host devices (`--xla_force_host_platform_device_count`).", "",
             "| engine | devices | videos | one by one (s) | batched (s) | speed-up | first call: one by one / batched (s) "
             "| LM steps one by one / batched | max abs theta diff |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in records:
        lines.append(f"| {r['engine']} | {r['devices']} | {r['videos']} | {r['one_by_one_s']:.1f} | "
                     f"{r['batched_s']:.1f} | {r['speedup']:.2f}x | {r['one_by_one_first_s']:.1f} / "
                     f"{r['batched_first_s']:.1f} | {r['one_by_one_lm_steps']} / {r['batched_lm_steps']} | "
                     f"{r['max_abs_theta_diff']:.1e} |")
    with atomic_path(OUT.with_suffix(".md")) as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
