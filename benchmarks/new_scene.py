"""What a new scene costs: compile time of the same fit on a scene the process has not seen.

Usage: python benchmarks/new_scene.py [--out benchmarks/results/new_scene]

Every video a user films is its own scene (its ramp angle, board, lengths, start positions).
This runs, in one process and without the persistent compilation cache, the same work on two
scenes of one structure (two boxes on a flush ramp; the second with another angle, ramp
length, start positions and box size): building the problem, one batched log-density call of
16 points, a 2-start Levenberg-Marquardt fit (``fit_grad``), and a refit with the
``initial_push`` effect (whose release delay reads the ramp angle). The first scene's times
are compilation plus work; the second's show whether its programs were compiled again. Then
the same in two fresh processes (as two runs of ``fit`` on two users' videos): the first scene
with an empty persistent compilation cache, the second scene with the cache the first filled.
Writes ``<out>.md`` and ``<out>.json``.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import machine_line, write_atomic  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def scenes():
    from galileo_jax.scene import Scene, load_scene

    a = load_scene(ROOT / "examples" / "ramp20_example.yaml")
    d = copy.deepcopy(a.model_dump())
    d["name"] = "other ramp"
    d["ramp"]["angle_deg"] = 23.7
    d["ramp"]["length"] = 0.7
    d["objects"][0]["start"] = 0.5
    d["objects"][0]["size"] = [0.07, 0.06, 0.05]
    return a, Scene.model_validate(d)


def run_scene(scene) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from galileo_jax.inference.grad import fit_grad
    from galileo_jax.inference.problem import Problem, simulated_observation
    from galileo_jax.physics.simulate import PhysParams

    truth = PhysParams(jnp.asarray([1.0, 1.5]), jnp.asarray([0.15, 0.3]))
    obs = simulated_observation(scene, truth, fps=30.0, duration=1.5, release_time=0.1, seed=1)
    out = {}
    t0 = time.perf_counter()
    problem = Problem(scene, obs)
    out["problem_s"] = time.perf_counter() - t0
    z = jnp.zeros((16, problem.dim))
    t0 = time.perf_counter()
    np.asarray(problem.log_density(z))
    out["log_density_first_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    np.asarray(problem.log_density(z + 0.1))
    out["log_density_again_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = fit_grad(problem, jax.random.PRNGKey(0), n_starts=2, n_screen=32, polish_rounds=0)
    out["fit_grad_s"] = time.perf_counter() - t0
    out["k1"] = float(res.theta[problem.names.index("k1")])
    push = Problem(scene, obs, effects=("initial_push",))
    t0 = time.perf_counter()
    res = fit_grad(push, jax.random.PRNGKey(0), n_starts=2, n_screen=32, polish_rounds=0)
    out["fit_grad_push_s"] = time.perf_counter() - t0
    return out


def worker(which: str, cache: str | None) -> None:
    """Run one or both scenes in this process and print the rows as JSON (the last line)."""
    import jax

    if cache:
        from galileo_jax.jaxcache import enable_compilation_cache

        os.environ["GALILEO_JAX_CACHE"] = cache
        enable_compilation_cache()
    labels = ("first scene", "second scene (new numbers)")
    rows = []
    for i, (label, scene) in enumerate(zip(labels, scenes())):
        if which in ("both", ("first", "second")[i]):
            rows.append({"scene": label, **{k: round(v, 2) for k, v in run_scene(scene).items()}})
            print(rows[-1], file=sys.stderr, flush=True)
    print(json.dumps({"jax": jax.__version__, "rows": rows}))


def spawn(which: str, cache: str | None = None) -> dict:
    cmd = [sys.executable, __file__, "--worker", which] + (["--cache", cache] if cache else [])
    proc = subprocess.run(cmd, check=True, stdout=subprocess.PIPE, text=True, cwd=ROOT)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "new_scene"))
    ap.add_argument("--worker", choices=("both", "first", "second"), help=argparse.SUPPRESS)
    ap.add_argument("--cache", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        worker(args.worker, args.cache)
        return
    one = spawn("both")
    with tempfile.TemporaryDirectory() as cache:
        fresh = spawn("first", cache)["rows"] + spawn("second", cache)["rows"]
    machine = machine_line()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    from galileo_jax.report.results import write_json

    write_json(out.with_suffix(".json"), {"machine": machine, "one_process": one["rows"], "fresh_processes": fresh})
    cols = ["problem_s", "log_density_first_s", "log_density_again_s", "fit_grad_s", "fit_grad_push_s"]
    head = ["| scene | " + " | ".join(c.removesuffix("_s").replace("_", " ") + " (s)" for c in cols) + " |",
            "|---|" + "---|" * len(cols)]

    def table(rows):
        return head + ["| " + r["scene"] + " | " + " | ".join(str(r[c]) for c in cols) + " |" for r in rows]

    lines = ["# What a new scene costs", "", f"machine: {machine}", "", "command: `python benchmarks/new_scene.py`",
             "", "Both scenes in one process, no persistent compilation cache:", ""] + table(one["rows"])
    lines += ["", "Each scene in a fresh process; the second process finds the first one's persistent "
              "compilation cache:", ""] + table(fresh)
    write_atomic(out.with_suffix(".md"), "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
