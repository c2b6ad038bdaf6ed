"""The report layer's files (galileo_jax.report.fit_files) from a typed report, without a fit.

A joint fit of several videos takes about a minute end to end, so its writer is checked here on
a :class:`~galileo_jax.fit_report.JointFitReport` built from synthetic profiles: one profile
figure per video, and a ``result.json`` whose per-video entries are the report's.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from galileo_jax.config import FitConfig
from galileo_jax.fit_report import JointFitReport
from galileo_jax.observation import Observation, profile_from_positions
from galileo_jax.report.fit_files import write_joint_fit
from galileo_jax.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
FPS = 30.0


def _observation(seed: int) -> tuple[Observation, np.ndarray]:
    """A 2 s observation of two objects (object 1 at constant acceleration 1 m/s^2 after 0.2 s,
    object 2 at rest) with 1 mm noise, and its noise-free profile (4, N-1) m/s."""
    rng = np.random.default_rng(seed)
    t = np.arange(61) / FPS
    pos = np.zeros((t.size, 2, 2))
    pos[:, 0, 0] = 0.5 * np.clip(t - 0.2, 0.0, None) ** 2
    pos[:, 1, 0] = 0.3
    clean = profile_from_positions(pos, t)
    noisy = pos + rng.normal(0.0, 0.001, pos.shape)
    obs = Observation(t, noisy, np.zeros_like(noisy), profile_from_positions(noisy, t), np.full(4, 0.001),
                      t[1:] > 0.1, 0.2, FPS, np.array([True, False]))
    return obs, clean


def test_joint_fit_files_hold_every_video(tmp_path):
    scene = load_scene(ROOT / "scenes" / "ramp_20.yaml")
    pairs = [_observation(s) for s in (1, 2)]
    observations = [o for o, _ in pairs]
    simulated = [c for _, c in pairs]
    bands = [np.stack([c - 0.01, c + 0.01]) for c in simulated]
    rmse = [{"all": float(np.sqrt(np.mean((o.profile - c)[:, o.mask] ** 2)))} for o, c in pairs]
    report = JointFitReport([tmp_path / "a.mp4", tmp_path / "b.mp4"], [scene, scene], "grad", observations,
                            ("dt_release@1", "dt_release@2"), {"k1": {"best": 0.2}}, {"engine": "mujoco"},
                            simulated, bands, rmse, [-10.0, -12.5], timings={"observe_s": 1.0},
                            adequacy=[{"adequate": True}, {"adequate": False}])
    out = tmp_path / "fit"
    write_joint_fit(report, out, FitConfig(), 7, shared=["k1", "k2", "phi"])
    assert sorted(p.name for p in out.iterdir()) == ["profiles_1.png", "profiles_2.png", "result.json"]
    result = json.loads((out / "result.json").read_text())
    assert result["videos"] == [str(v) for v in report.videos] and result["shared"] == ["k1", "k2", "phi"]
    assert result["loglik_per_video"] == [-10.0, -12.5] and result["rmse_per_video_m_per_s"] == rmse
    assert [a["adequate"] for a in result["adequacy_per_video"]] == [True, False]
    assert [o["fit_samples"] for o in result["observations"]] == [int(o.mask.sum()) for o in observations]
    assert result["settings"]["seed"] == 7 and result["per_video"] == ["dt_release@1", "dt_release@2"]
    assert report.outputs["result"] == str(out / "result.json")
