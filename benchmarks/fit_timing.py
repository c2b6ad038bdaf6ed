"""Wall time of `fit` on the shipped example, cold (empty compilation cache) and warm.

Usage: python benchmarks/fit_timing.py [--video examples/ramp20_example.mp4] [--methods grad grad:prior mh]

A method ``M:INIT`` runs ``fit --method M --init INIT`` (``grad:prior``: grad's multi-start
search from the prior; plain ``grad`` is fit's default, started from the CNN where one reads
the scene).

Each run is a fresh process (as a user would run it). "cold" uses an empty persistent
compilation cache; "warm" reruns with the cache the cold run filled. Writes
benchmarks/results/fit_timing.{md,json} with the machine it ran on.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from _common import machine_line, write_atomic  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def run_fit(video: str, method: str, cache: str, out: str, extra: tuple[str, ...] = ()) -> float:
    env = dict(os.environ, GALILEO_JAX_CACHE=cache, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    name, _, init = method.partition(":")
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "galileo_jax.fit", video, "--method", name, "--out", out, "--quiet",
                    *(("--init", init) if init else ()), *extra], check=True, env=env, cwd=ROOT)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--video", default="examples/ramp20_example.mp4")
    ap.add_argument("--methods", nargs="+", default=["grad", "mh"])
    ap.add_argument("--engine", help="fit's --engine (default: fit's own choice)")
    ap.add_argument("--out", default="fit_timing", help="table name in benchmarks/results (fit_timing_gpu on a GPU)")
    args = ap.parse_args()
    extra = ("--engine", args.engine) if args.engine else ()
    rows = []
    for method in args.methods:
        with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as out:
            cold = run_fit(args.video, method, cache, out, extra)
            warm = run_fit(args.video, method, cache, out, extra)
            result = json.loads((Path(out) / "result.json").read_text())
        rows.append({"method": method, "cold_s": round(cold, 1), "warm_s": round(warm, 1),
                     "init": result["diagnostics"].get("init"),
                     "estimate": {k: v.get("estimate") for k, v in result["parameters"].items()}})
        print(rows[-1], flush=True)
        _write(args, rows)  # after each method: a run stopped early keeps its rows


def _write(args, rows: list[dict]) -> None:
    machine = machine_line()
    res = ROOT / "benchmarks" / "results"
    res.mkdir(parents=True, exist_ok=True)
    from galileo_jax.report.results import write_json

    write_json(res / f"{args.out}.json", {"machine": machine, "video": args.video, "engine": args.engine or "auto",
                                          "rows": rows})
    lines = [f"# fit wall time on {args.video}", "", f"Machine: {machine}", "",
             f"Engine: {args.engine or 'auto'}. Each run is a fresh process; cold: empty compilation cache.", "",
             "| method | started from | cold (s) | warm cache (s) | k1 | k2 | phi |", "|---|---|---|---|---|---|---|"]
    lines += [f"| {r['method']} | {r.get('init') or '-'} | {r['cold_s']} | {r['warm_s']} | "
              + " | ".join(f"{r['estimate'].get(n, float('nan')):.4f}" for n in ("k1", "k2", "phi")) + " |"
              for r in rows]
    write_atomic(res / f"{args.out}.md", "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
