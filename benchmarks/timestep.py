"""Choose the physics timestep by measurement: velocity-profile error vs a fine reference.

Usage: python benchmarks/timestep.py

For the 20 degree two-object scene (30 fps video, 2.5 s), simulates a few parameter sets at
1, 2, 4, 8 and 16 physics steps per frame and compares each velocity profile with the one at
64 steps per frame (1/1920 s). Writes benchmarks/results/timestep.{md,json}.
"""

from __future__ import annotations

import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _common import machine_line, write_atomic  # noqa: E402
from galileo_jax.report.results import write_json  # noqa: E402

from galileo_jax.physics.simulate import PhysParams, make_simulator, steps_needed, velocity_profile
from galileo_jax.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
PARAMS = PhysParams(jnp.array([[0.6, 0.3], [0.3, 0.6], [0.5, 0.5], [0.8, 0.2]]),
                    jnp.array([[0.2, 0.25], [0.1, 0.4], [0.25, 0.15], [0.15, 0.3]]))


def profiles(substeps: int, frame_times) -> tuple[np.ndarray, float]:
    scene = load_scene(ROOT / "scenes" / "ramp_20.yaml")
    scene = scene.model_copy(update={"simulation": scene.simulation.model_copy(update={"substeps": substeps})})
    sim = make_simulator(scene, 30.0)
    n = steps_needed(sim, float(frame_times[-1]))
    fn = jax.jit(jax.vmap(lambda p: velocity_profile(sim, p, frame_times, 0.0, n)))
    out = fn(PARAMS).block_until_ready()
    t = time.perf_counter()
    out = np.asarray(fn(PARAMS).block_until_ready())
    return out, (time.perf_counter() - t) / len(PARAMS.mass)


def main() -> None:
    frame_times = jnp.arange(76) / 30.0
    ref, _ = profiles(64, frame_times)
    rows = []
    for sub in (1, 2, 4, 8, 16):
        prof, sec = profiles(sub, frame_times)
        rms = float(np.sqrt(np.mean((prof - ref) ** 2)))
        worst = float(np.abs(prof - ref).max())
        rows.append({"substeps": sub, "dt_s": 1 / (30 * sub), "rms_vs_1_1920_m_per_s": round(rms, 4),
                     "max_abs_m_per_s": round(worst, 3), "seconds_per_rollout_batch4": round(sec, 4)})
        print(rows[-1], flush=True)
    machine = machine_line()
    res = ROOT / "benchmarks" / "results"
    res.mkdir(parents=True, exist_ok=True)
    write_json(res / "timestep.json", {"machine": machine, "rows": rows})
    lines = ["# Physics timestep vs velocity-profile error (20 deg scene, 30 fps, 2.5 s, 4 parameter sets)", "",
             f"Machine: {machine}. Reference: 64 steps per frame (dt = 1/1920 s).", "",
             "| steps/frame | dt (s) | RMS error (m/s) | max error (m/s) | s per rollout (batch 4) |", "|---|---|---|---|---|"]
    lines += [f"| {r['substeps']} | 1/{int(round(1 / r['dt_s']))} | {r['rms_vs_1_1920_m_per_s']} | "
              f"{r['max_abs_m_per_s']} | {r['seconds_per_rollout_batch4']} |" for r in rows]
    write_atomic(res / "timestep.md", "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
