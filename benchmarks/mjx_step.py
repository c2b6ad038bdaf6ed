"""Where an MJX physics step's time goes: float precision x constraint-solver iterations x batch.

On a GPU one MJX step of the ramp scene took ~1.1 ms whatever the batch up to a few hundred
(``docs/gpu.md``): launch- or loop-bound, not arithmetic-bound. MJX's Newton solver is a
``lax.while_loop`` (up to ``opt.iterations``, stopping at ``opt.tolerance``) around a line search
that is a ``lax.scan`` of exactly ``opt.ls_iterations`` steps, each a ``lax.cond`` (under ``vmap``
both branches run); on a GPU every loop iteration is a kernel sequence plus a host round trip for
its condition. This benchmark times the same rollout (``scenes/ramp_20.yaml``, two boxes, 2 s at
240 Hz, random masses and frictions as ``engines.py``) under settings that remove parts of it:

* ``f64`` / ``f32``: ``jax_enable_x64`` on (the package's default) or off while the model is built
  and the program traced;
* ``it/ls``: the solver's ``opt.iterations`` / ``opt.ls_iterations`` (the package uses 20 / 10;
  ``it`` = 1 removes the while loop: one Newton step per physics step).

Reported per setting and batch: compile + first call (s), ms per physics step (best of
``--repeats``), rollouts/s, and how far the final positions lie from the package's setting (f64,
20/10) for the same parameters (max and median over the batch, m): what each shortcut costs in
physics.

    python benchmarks/mjx_step.py [--batches 1,256,4096] [--settings f64:20:10,f32:20:10,...] [--out mjx_step_gpu]

Writes ``benchmarks/results/<out>.{md,json}`` after every row.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

from _common import machine_line  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
DEFAULT_SETTINGS = "f64:20:10,f32:20:10,f64:20:4,f64:10:10,f64:1:10"


def _simulator(x64: bool, iterations: int, ls_iterations: int, seconds: float):
    """The ramp_20 simulator with the given precision and solver iterations, and its step count."""
    import jax
    from mujoco import mjx

    from galileo_jax.physics.simulate import _forward, make_simulator, steps_needed
    from galileo_jax.scene import load_scene

    sim = make_simulator(load_scene(ROOT / "scenes" / "ramp_20.yaml"), 30.0)
    n = steps_needed(sim, seconds)
    jax.config.update("jax_enable_x64", x64)
    mj = sim.mj_model.__copy__()
    mj.opt.iterations, mj.opt.ls_iterations = iterations, ls_iterations
    model = mjx.put_model(mj)
    data0 = _forward(model, mjx.make_data(model))
    return dataclasses.replace(sim, mj_model=mj, model=model, data0=data0), n


def _params(batch: int, x64: bool):
    """``engines.py``'s random masses and frictions, in the setting's precision."""
    import numpy as np

    from engines import _params as engine_params

    dtype = np.float64 if x64 else np.float32
    return tuple(a.astype(dtype) for a in engine_params(batch))


def measure(setting: str, batch: int, seconds: float, repeats: int) -> tuple[dict, object]:
    """One row: time of ``batch`` rollouts under ``setting`` ("f64:20:10"), and their final poses."""
    import jax
    import numpy as np

    from galileo_jax.physics.simulate import PhysParams, rollout

    prec, it, ls = setting.split(":")
    x64 = prec == "f64"
    sim, n = _simulator(x64, int(it), int(ls), seconds)
    fn = jax.jit(jax.vmap(lambda m, k: rollout(sim, PhysParams(m, k), n).pose[-1]))
    mass, friction = _params(batch, x64)
    t = time.perf_counter()
    out = fn(mass, friction).block_until_ready()
    first = time.perf_counter() - t
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        fn(mass, friction).block_until_ready()
        best = min(best, time.perf_counter() - t)
    jax.config.update("jax_enable_x64", True)
    row = {"setting": setting, "batch": batch, "n_steps": n, "first_call_s": first, "run_s": best,
           "ms_per_step": 1e3 * best / n, "rollouts_per_s": batch / best,
           "finite": bool(np.isfinite(np.asarray(out)).all())}
    return row, np.asarray(out, np.float64)


def write(result: dict, out: str) -> None:
    from galileo_jax.report.results import atomic_path, write_json

    write_json(RESULTS / f"{out}.json", result)
    lines = [f"# MJX step time by precision and solver iterations ({result['backend']})", "",
             f"{result['machine']}. `{result['command']}`. Ramp_20 scene, {result['seconds']} s of simulated "
             "time a rollout (240 Hz); best of the repeats after a compiling call. 'from f64 20/10': final "
             "positions against the package's setting, same parameters, max / median over the batch.", "",
             "| setting (precision, it/ls) | batch | compile + first call (s) | ms / physics step | rollouts/s "
             "| from f64 20/10, max / median (m) |",
             "|---|---|---|---|---|---|"]
    for r in result["rows"]:
        prec, it, ls = r["setting"].split(":")
        dev = (f"{r['max_diff_m']:.1e} / {r['median_diff_m']:.1e}" if "max_diff_m" in r else "-")
        if not r["finite"]:
            dev = "non-finite"
        lines.append(f"| {prec}, {it}/{ls} | {r['batch']} | {r['first_call_s']:.1f} | {r['ms_per_step']:.3f} "
                     f"| {r['rollouts_per_s']:.1f} | {dev} |")
    with atomic_path(RESULTS / f"{out}.md") as tmp:
        tmp.write_text("\n".join(lines) + "\n")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batches", default="1,256,4096")
    ap.add_argument("--settings", default=DEFAULT_SETTINGS, help="comma-separated precision:iterations:ls_iterations")
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="mjx_step")
    args = ap.parse_args(argv)
    import jax
    import numpy as np

    settings = args.settings.split(",")
    result = {"machine": machine_line(), "backend": jax.default_backend(), "seconds": args.seconds,
              "command": "python benchmarks/mjx_step.py " + " ".join(argv if argv is not None else sys.argv[1:]),
              "rows": []}
    for b in (int(x) for x in args.batches.split(",")):
        ref = None
        for s in settings:
            row, final = measure(s, b, args.seconds, args.repeats)
            if s == "f64:20:10":
                ref = final
            elif ref is not None:
                d = np.abs(final[..., :2] - ref[..., :2]).max(axis=(1, 2))
                row["max_diff_m"], row["median_diff_m"] = float(d.max()), float(np.median(d))
            result["rows"].append(row)
            print(f"{s:10s} B={b:5d}: first {row['first_call_s']:6.1f} s, {row['ms_per_step']:7.3f} ms/step, "
                  f"{row['rollouts_per_s']:9.1f} rollouts/s, max |dx| {row.get('max_diff_m', 0):.1e} m", flush=True)
            write(result, args.out)


if __name__ == "__main__":
    main()
