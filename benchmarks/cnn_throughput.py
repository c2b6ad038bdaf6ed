"""CNN training throughput: simulated training examples per second, per engine and batch.

One training step of :mod:`galileo_jax.train` (``configs/cnn_ramp20.yaml``: 20 degree scene,
96 samples at 30 fps, ``views`` = 8 noisy copies per rollout) is one jitted function that draws
``rollouts`` parameter vectors, simulates them on the engine (MJX vmapped, or C MuJoCo's batched
rollout through a callback), adds noise and takes an optimiser step. Per (engine, rollouts per
step): the compile time of the step (its first call) and examples per second over ``--steps``
further steps (rollouts x views per step / wall time).

Writes ``benchmarks/results/<out>.{md,json}`` (default ``cnn_throughput``; ``cnn_throughput_gpu``
for a GPU run) and adds the table to ``cnn_accuracy.md`` (re-rendered from ``cnn_accuracy.json``).

    python benchmarks/cnn_throughput.py [--engines mjx,mujoco] [--rollouts 32,256] [--steps 20]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from _common import machine_line  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def measure(engine: str, rollouts: int, steps: int) -> dict:
    """Compile time and examples per second of the training step on ``engine`` with ``rollouts``
    simulations per step."""
    import jax

    from galileo_jax.train import load_train_config, make_train_step, setup

    cfg = load_train_config(ROOT / "configs" / "cnn_ramp20.yaml").model_copy(
        update={"engine": engine, "rollouts": rollouts})
    s, state = setup(cfg)
    step = make_train_step(s)
    t = time.perf_counter()
    state, metrics = step(state)
    jax.block_until_ready(metrics["loss"])
    compile_s = time.perf_counter() - t
    t = time.perf_counter()
    for _ in range(steps):
        state, metrics = step(state)
    jax.block_until_ready(metrics["loss"])
    wall = time.perf_counter() - t
    per_step = rollouts * cfg.views
    return {"engine": engine, "rollouts_per_step": rollouts, "examples_per_step": per_step, "steps": steps,
            "compile_s": compile_s, "examples_per_s": steps * per_step / wall, "rollouts_per_s": steps * rollouts / wall,
            "loss": float(metrics["loss"])}


def table(result: dict) -> list[str]:
    """Markdown lines of one throughput run (also used by ``cnn_accuracy.md``)."""
    lines = [f"machine: {result['machine']}", "",
             f"Command: `{result['command']}`. One training step of configs/cnn_ramp20.yaml (8 noisy views per "
             f"rollout); compile: the step's first call; rates over the next {result['rows'][0]['steps']} steps.", "",
             "| engine | rollouts per step | examples per step | examples/s | rollouts/s | compile (s) |",
             "|---|---|---|---|---|---|"]
    lines += [f"| {r['engine']} | {r['rollouts_per_step']} | {r['examples_per_step']} | {r['examples_per_s']:.0f} | "
              f"{r['rollouts_per_s']:.0f} | {r['compile_s']:.1f} |" for r in result["rows"]]
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--engines", default="mjx,mujoco")
    ap.add_argument("--rollouts", default="32,256", help="simulations per training step (comma-separated)")
    ap.add_argument("--steps", type=int, default=20, help="timed steps after the compiling one")
    ap.add_argument("--out", default="cnn_throughput", help="table name in benchmarks/results")
    args = ap.parse_args(argv)
    os.environ.setdefault("MUJOCO_GL", "egl")
    from galileo_jax.jaxcache import enable_compilation_cache
    from galileo_jax.report.results import atomic_path, write_json

    enable_compilation_cache()
    rows = []
    for engine in args.engines.split(","):
        for n in (int(r) for r in args.rollouts.split(",")):
            rows.append(measure(engine, n, args.steps))
            r = rows[-1]
            print(f"{engine} x {n}: {r['examples_per_s']:.0f} examples/s ({r['rollouts_per_s']:.0f} rollouts/s), "
                  f"compile {r['compile_s']:.1f} s", flush=True)
            result = {"machine": machine_line(), "command": "python benchmarks/cnn_throughput.py "
                      + " ".join(argv if argv is not None else sys.argv[1:]), "rows": rows}
            write_json(RESULTS / f"{args.out}.json", result)
            with atomic_path(RESULTS / f"{args.out}.md") as tmp:
                tmp.write_text("\n".join(["# CNN training throughput", ""] + table(result)) + "\n")
    acc = RESULTS / "cnn_accuracy.json"
    if acc.exists():
        from cnn_accuracy import write_tables

        old = json.loads(acc.read_text())
        write_tables(old["models"], old["tests"], old["machine"])
    return 0


if __name__ == "__main__":
    sys.exit(main())
