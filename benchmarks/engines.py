"""Rollouts per second of the ramp scene: MJX ``jit(vmap(scan))`` vs C MuJoCo's batched ``mujoco.rollout``.

Issue 5, benchmark 2. Same machine, same run, same model (``scenes/ramp_20.yaml``, two boxes,
dt = 1/240 s, ``--seconds`` of simulated time per rollout), same random parameters (masses
in (0.1, 1) kg, k1 in (0.05, 0.3), k2 in (0.05, 0.6)). Per batch size B:

* ``mjx``: ``jax.jit(jax.vmap(rollout))`` of :func:`galileo_jax.physics.simulate.rollout`, the program
  every fit runs (float64), timed after its compilation;
* ``mujoco``: :func:`galileo_jax.physics.simulate_c.rollout_poses_host`: B model copies with their
  parameters, one ``mujoco.rollout`` over a thread pool of all cores (the C engine as ``fit
  --engine mujoco`` runs it, model copies included), and ``mujoco (in jit)``: the same through
  its host call (an XLA FFI target, :mod:`galileo_jax.physics.host_call`) inside ``jit(vmap)``, as
  the samplers call it.

Reported: rollouts per second (best of ``--repeats``) and the ratio C / MJX. Compile time of
the MJX program: cold (empty persistent cache) and warm (JAX's persistent compilation cache
filled by the cold run), each measured in a fresh subprocess. Writes
``benchmarks/results/engines.{md,json}``.

    python benchmarks/engines.py [--batches 1,4,16,64,256,1024,4096] [--seconds 2.0]
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
from _common import machine_line  # noqa: E402

#: Largest single MJX vmap (see measure).
MJX_CHUNK = 256
ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def _setup(seconds: float):
    from galileo_jax.physics.simulate import make_simulator, steps_needed
    from galileo_jax.scene import load_scene

    sim = make_simulator(load_scene(ROOT / "scenes" / "ramp_20.yaml"), 30.0)
    return sim, steps_needed(sim, seconds)


def _params(batch: int, seed: int = 0):
    import numpy as np

    rng = np.random.default_rng(seed)
    mass = rng.uniform(0.1, 1.0, (batch, 2))
    friction = np.c_[rng.uniform(0.05, 0.3, batch), rng.uniform(0.05, 0.6, batch)]
    return mass, friction


def compile_time(seconds: float, batch: int) -> dict:
    """In this process: time to the first result of the MJX batch program, and a second call."""
    import jax

    from galileo_jax.jaxcache import enable_compilation_cache
    from galileo_jax.physics.simulate import PhysParams, rollout

    enable_compilation_cache()
    t0 = time.perf_counter()
    sim, n = _setup(seconds)
    build = time.perf_counter() - t0
    f = jax.jit(jax.vmap(lambda m, k: rollout(sim, PhysParams(m, k), n).pose))
    mass, friction = _params(batch)
    t = time.perf_counter()
    f(mass, friction).block_until_ready()
    first = time.perf_counter() - t
    t = time.perf_counter()
    f(mass, friction).block_until_ready()
    run = time.perf_counter() - t
    return {"build_s": build, "first_call_s": first, "run_s": run, "compile_s": first - run}


def measure(batches: list[int], seconds: float, repeats: int, chunk: int):
    """Yield one row per batch size (rollouts per second of each engine, their position difference)."""
    import jax
    import numpy as np

    from galileo_jax.inference.problem import map_batch
    from galileo_jax.physics.simulate import PhysParams, rollout
    from galileo_jax.physics import simulate_c
    from galileo_jax.physics.simulate_c import rollout_poses, rollout_poses_host

    simulate_c.CACHE_ROLLOUTS = 0  # every repeat simulates (the callback would remember the inputs)
    sim, n = _setup(seconds)
    # One vmap of 4096 MJX rollouts deadlocks on this CPU (jaxlib 0.10.2: every thread idle, as
    # 64 vmapped LM starts did), and so did chunks of 1024; above MJX_CHUNK the batch runs as
    # lax.map over vmapped chunks, through the project's own map_batch. On a GPU ``chunk`` is the
    # largest batch: one vmap.
    mjx_fn = jax.jit(lambda m, k: map_batch(lambda a: rollout(sim, PhysParams(*a), n).pose, (m, k), chunk))
    on_cpu = jax.default_backend() == "cpu"
    cb_fn = jax.jit(jax.vmap(lambda m, k: rollout_poses(sim, m, k, n)))
    for b in batches:
        mass, friction = _params(b)
        row = {"batch": b, "n_steps": n, "mjx_chunk": min(b, chunk)}
        for name, fn in (("mjx", lambda: mjx_fn(mass, friction).block_until_ready()),
                         ("mujoco", lambda: rollout_poses_host(sim, mass, friction, n)),
                         ("mujoco_jit", lambda: cb_fn(mass, friction).block_until_ready())):
            fn()  # compile / warm
            best = np.inf
            reps = repeats if b < 1024 or name != "mjx" or not on_cpu else 1
            for _ in range(reps):
                t = time.perf_counter()
                out = fn()
                best = min(best, time.perf_counter() - t)
            row[f"{name}_rollouts_per_s"] = b / best
            if name == "mjx":
                ref = np.asarray(out)
            elif name == "mujoco":
                diff = np.abs(np.asarray(out)[..., :2] - ref[..., :2])
                row["max_position_diff_m"] = float(np.max(diff))
                row["median_position_diff_m"] = float(np.median(np.max(diff, axis=(1, 2, 3))))
        row["ratio_mujoco_over_mjx"] = row["mujoco_rollouts_per_s"] / row["mjx_rollouts_per_s"]
        print(f"B={b:5d}: mjx {row['mjx_rollouts_per_s']:9.1f}/s, mujoco {row['mujoco_rollouts_per_s']:9.1f}/s "
              f"(in jit {row['mujoco_jit_rollouts_per_s']:9.1f}/s), ratio {row['ratio_mujoco_over_mjx']:.1f}x, "
              f"max |dx| {row['max_position_diff_m']:.2e} m", flush=True)
        yield row


def write_tables(result: dict, name: str = "engines") -> None:
    """``<name>.json`` and ``<name>.md``; ``engines.md`` also gets the GPU run's table
    (``engines_gpu.json``, ``--out engines_gpu``) when there is one."""
    from galileo_jax.report.results import atomic_path, write_json

    write_json(RESULTS / f"{name}.json", result)
    lines = _table(result, "# Engines: MJX jit(vmap(scan)) vs C MuJoCo mujoco.rollout (ramp_20 scene)")
    gpu = RESULTS / "engines_gpu.json"
    if name == "engines" and gpu.exists():
        lines += [""] + _table(json.loads(gpu.read_text()), "## On a GPU (MJX's design target)")
    with atomic_path(RESULTS / f"{name}.md") as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    if name != "engines" and (RESULTS / "engines.json").exists():
        write_tables(json.loads((RESULTS / "engines.json").read_text()))


def _table(result: dict, title: str) -> list[str]:
    c = result["compile"]
    lines = [title, "",
             f"machine: {result['machine']}", "",
             f"Command: `{result['command']}`. {result['seconds']} s of simulated time per rollout "
             f"({result['rows'][0]['n_steps']} steps at dt = 1/240 s), float64. Rollouts per second, best of "
             f"{result['repeats']}" + (" (1 for MJX at B >= 1024)" if result.get("backend", "cpu") == "cpu" else "")
             + "; C MuJoCo timings include the per-rollout model copies "
             "and mj_setConst. 'in jit': the C engine through its host call inside jit(vmap), as the samplers "
             "call it. Position diff: largest |x, z| difference of the two engines' trajectories (same parameters)."
             + "".join(f" MJX at batch {r['batch']}: lax.map over vmapped chunks of {r['mjx_chunk']} (one vmap of "
                       "4096, and chunks of 1024, deadlocked: jaxlib 0.10.2 on this CPU, every thread idle)."
                       for r in result["rows"] if r.get("mjx_chunk", r["batch"]) < r["batch"])
             + ("" if any(r.get("mjx_chunk", r["batch"]) < r["batch"] for r in result["rows"])
                else " MJX runs every batch as one vmap."),
             "", "| batch | MJX (rollouts/s) | C MuJoCo | C MuJoCo in jit | C / MJX | max position diff (m) | "
                 "median of per-rollout max (m) |",
             "|---|---|---|---|---|---|---|"]
    for r in result["rows"]:
        lines.append(f"| {r['batch']} | {r['mjx_rollouts_per_s']:.1f} | {r['mujoco_rollouts_per_s']:.1f} | "
                     f"{r['mujoco_jit_rollouts_per_s']:.1f} | {r['ratio_mujoco_over_mjx']:.1f} | "
                     f"{r['max_position_diff_m']:.1e} | {r['median_position_diff_m']:.1e} |")
    lines += ["", f"MJX compile time of the batch-{c['batch']} program (fresh process each): cold cache "
                  f"{c['cold']['compile_s']:.1f} s, with the persistent cache {c['warm']['compile_s']:.1f} s "
                  f"(scene build {c['cold']['build_s']:.1f} / {c['warm']['build_s']:.1f} s). "
                  "The C engine compiles nothing."]
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batches", default="1,4,16,64,256,1024,4096")
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per rollout")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--compile-batch", type=int, default=16)
    ap.add_argument("--chunk", type=int, help=f"largest single MJX vmap (default {MJX_CHUNK} on a CPU, "
                    "the largest batch on a GPU)")
    ap.add_argument("--out", default="engines", help="table name in benchmarks/results (default engines; "
                    "engines_gpu for a GPU run, which engines.md then shows too)")
    ap.add_argument("--compile-only", action="store_true", help=argparse.SUPPRESS)  # the subprocess' mode
    ap.add_argument("--merge", action="store_true",
                    help="keep the committed table's other batch sizes and compile times; measure only --batches")
    args = ap.parse_args(argv)
    os.environ.setdefault("MUJOCO_GL", "egl")
    if args.compile_only:
        print(json.dumps(compile_time(args.seconds, args.compile_batch)))
        return 0
    old = json.loads((RESULTS / f"{args.out}.json").read_text()) if args.merge else None
    comp = old["compile"] if old else {"batch": args.compile_batch}
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, GALILEO_JAX_CACHE=cache)
        for label in () if old else ("cold", "warm"):
            out = subprocess.run([sys.executable, __file__, "--compile-only", "--seconds", str(args.seconds),
                                  "--compile-batch", str(args.compile_batch)], env=env, check=True,
                                 capture_output=True, text=True).stdout
            comp[label] = json.loads(out.strip().splitlines()[-1])
            print(f"compile ({label} cache): {comp[label]['compile_s']:.1f} s", flush=True)
    from galileo_jax.jaxcache import enable_compilation_cache

    enable_compilation_cache()
    import jax

    batches = [int(b) for b in args.batches.split(",")]
    chunk = args.chunk or (MJX_CHUNK if jax.default_backend() == "cpu" else max(batches))
    machine = machine_line()
    import mujoco

    done = []
    for row in measure(batches, args.seconds, args.repeats, chunk):  # tables written after each batch size
        done.append(row)  # (a run stopped early keeps its rows)
        new = {r["batch"] for r in done}
        # rows measured now replace the committed ones of the same batch size
        rows = sorted([r for r in (old["rows"] if old else []) if r["batch"] not in new] + done,
                      key=lambda r: r["batch"])
        write_tables({"machine": machine, "backend": jax.default_backend(), "jax": jax.__version__,
                      "mujoco": mujoco.__version__,
                      "command": (old["command"] + "`, then `" if old else "") + "python benchmarks/engines.py "
                      + " ".join(argv if argv is not None else sys.argv[1:]),
                      "seconds": args.seconds, "repeats": old["repeats"] if old else args.repeats, "compile": comp,
                      "rows": rows}, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
