"""A fit's files (:func:`write_fit`): ``profiles.png``, ``tracking.png``, ``posterior.nc``,
``overlay.mp4`` and ``result.json`` in the output folder, each written atomically, from the
:class:`~galileo_jax.fit_report.FitReport` that :func:`galileo_jax.pipeline.run_fit` returns.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from galileo_jax.calibration import calibration
from galileo_jax.config import FitConfig
from galileo_jax.fit_report import FitReport, JointFitReport, identifiability_statement
from galileo_jax.report.figures import profile_figure, tracking_figure
from galileo_jax.report.results import package_versions, write_json, write_netcdf


def _profiles_png(path: Path, obs, simulated: np.ndarray, band: np.ndarray, title: str) -> str:
    """The observed and simulated velocity profiles of ``obs`` (at the mid-times of its frame
    intervals) with the 90% band, as ``path``; returns its path."""
    times = 0.5 * (obs.frame_times[:-1] + obs.frame_times[1:])
    profile_figure(path, times, obs.profile, simulated, obs.velocity_sd, np.asarray(obs.mask, bool), band, title)
    return str(path)


def write_fit(report: FitReport, poses: np.ndarray, clip, out: Path, cfg: FitConfig, seed: int,
              overlay: bool, progress: bool) -> None:
    """Write a fit's files into ``out``; ``poses`` (N, n, 3): the simulated poses at the estimate
    (for the overlay)."""
    obs = report.observation
    out.mkdir(parents=True, exist_ok=True)
    report.outputs["figure"] = _profiles_png(out / "profiles.png", obs, report.simulated, report.band,
                                             f"{report.video.name}: {report.method} fit, scene {report.scene.name}")
    if obs.tracking is not None:
        from galileo_jax.observe.tracks import object_windows

        path = out / "tracking.png"
        windows = object_windows(report.scene, calibration(report.scene.camera))
        radius = [1.3 * float(np.hypot(*w.half)) for w in windows]
        tracking_figure(path, clip.frames, obs.pixels, obs.tracking.quality, obs.tracking.measured, radius, obs.fps,
                        obs.tracking.methods, obs.tracking.quality_min,
                        title=f"{report.video.name}: what the tracker saw")
        report.outputs["tracking_figure"] = str(path)
    if report.posterior is not None:
        from galileo_jax.inference.summary import inference_data

        post = report.posterior
        idata = inference_data(post.draws, obs, sample_stats=post.sample_stats,
                               attrs={"method": report.method, "draws_kind": post.kind, "video": str(report.video),
                                      "scene": report.scene.name, "seed": seed})
        path = out / "posterior.nc"
        write_netcdf(path, idata)
        report.outputs["posterior"] = str(path)
    if overlay:
        from galileo_jax.report.overlay import write_overlay

        calib = calibration(report.scene.camera, anchor_px=obs.pixels[0, 0], anchor_world=obs.positions[0, 0])
        path = out / "overlay.mp4"
        write_overlay(path, clip.frames, obs.fps, report.scene, calib, poses, obs.pixels,
                      caption=f"simulated ({report.method})", progress=progress)
        report.outputs["overlay"] = str(path)
    result = {
        "video": str(report.video),
        "scene": report.scene.model_dump(mode="json"),
        "method": report.method,
        "parameters": report.parameters,
        "identifiability": identifiability_statement(report.scene),
        "diagnostics": report.diagnostics,
        "rmse_per_trace_m_per_s": report.rmse,
        "adequacy": report.adequacy,
        "prediction": report.prediction,
        "observation": {
            "fps": obs.fps, "n_frames": int(len(obs.frame_times)), "release_time_s": obs.release_time,
            "position_sd_m": obs.position_sd, "velocity_sd_m_per_s": obs.velocity_sd,
            "moved": obs.moved, "fit_samples": int(np.sum(obs.mask)),
            "tracking": None if obs.tracking is None else obs.tracking.summary(),
        },
        "settings": {**cfg.model_dump(), "seed": seed},
        "timings_s": report.timings,
        "versions": package_versions(),
        "outputs": report.outputs,
    }
    path = out / "result.json"
    write_json(path, result)
    report.outputs["result"] = str(path)


def write_joint_fit(report: JointFitReport, out: Path, cfg: FitConfig, seed: int, *, shared) -> None:
    """Write a joint fit's files into ``out``: one ``profiles_<j>.png`` per video and
    ``result.json``; ``shared``: the names of the parameters the videos share."""
    out.mkdir(parents=True, exist_ok=True)
    for j, (obs, video) in enumerate(zip(report.observations, report.videos)):
        report.outputs[f"profiles_{j + 1}"] = _profiles_png(
            out / f"profiles_{j + 1}.png", obs, report.simulated[j], report.bands[j],
            f"{video.name}: joint {report.method} fit of {len(report.videos)} videos")
    result = {
        "videos": [str(v) for v in report.videos], "scenes": [s.model_dump(mode="json") for s in report.scenes],
        "method": report.method, "shared": list(shared), "per_video": list(report.per_video),
        "parameters": report.parameters, "identifiability": identifiability_statement(report.scenes[0]),
        "diagnostics": report.diagnostics, "rmse_per_video_m_per_s": report.rmse,
        "loglik_per_video": report.video_loglik, "adequacy_per_video": report.adequacy,
        "observations": [{"fps": o.fps, "n_frames": int(len(o.frame_times)), "release_time_s": o.release_time,
                          "velocity_sd_m_per_s": o.velocity_sd, "fit_samples": int(np.sum(o.mask)),
                          "tracking": None if o.tracking is None else o.tracking.summary()}
                         for o in report.observations],
        "settings": {**cfg.model_dump(), "seed": seed}, "timings_s": report.timings, "versions": package_versions(),
        "outputs": report.outputs,
    }
    path = out / "result.json"
    write_json(path, result)
    report.outputs["result"] = str(path)
