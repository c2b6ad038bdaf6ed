"""What the video says: the observed velocity profiles and their noise.

An :class:`Observation` is produced by :func:`galileo_jax.observe.observe` (tracking a
video) or by :func:`from_positions` (e.g. from simulated or hand-digitised positions), and
consumed by the likelihood and the inference methods.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class TrackingInfo(NamedTuple):
    """How the objects were followed in the video (:func:`galileo_jax.observe.observe`).

    Attributes:
        methods: per object "features" (KLT), "colour" (colour matte) or "outline".
        quality: (N, n_objects) quality in [0, 1] of each frame's measurement (0: none).
        measured: (N, n_objects) bool, frames whose measurement is used (quality at least
            :data:`galileo_jax.observe.tracks.QUALITY_MIN`); the others are left out of the fit.
        start_frame: frame in which the objects were found at rest and tracking started.
        cross_check_px: (n_objects,) median distance (px) between an object's KLT track and
            its colour track (NaN where only one method followed it).
        quality_min: the quality below which a measurement is left out.
    """

    methods: tuple[str, ...]
    quality: np.ndarray
    measured: np.ndarray
    start_frame: int
    cross_check_px: np.ndarray
    quality_min: float = 0.5

    def counts(self) -> list[dict]:
        """Per object: frames ``measured``; ``dropped``, unmeasured frames between the first
        and the last measured one (occluded, blurred away, or rejected by the quality
        threshold or the cross-check); ``unseen``, frames before the first or after the last
        measured one (covered from the start, or out of the image)."""
        out = []
        for i in range(self.measured.shape[1]):
            m = self.measured[:, i]
            idx = np.flatnonzero(m)
            inside = (idx[-1] - idx[0] + 1) if len(idx) else 0
            out.append({"measured": int(m.sum()), "dropped": int(inside - m.sum()),
                        "unseen": int(len(m) - inside)})
        return out

    def summary(self) -> dict:
        """What ``result.json`` records of the tracking: per object its method, frame counts
        (:meth:`counts`), median quality of the measured frames and the cross-check distance
        (px, None where there was none); the quality threshold and the start frame."""
        objects = []
        for i, c in enumerate(self.counts()):
            q = self.quality[self.measured[:, i], i]
            x = float(self.cross_check_px[i])
            objects.append({"object": i + 1, "method": self.methods[i], **c,
                            "median_quality": float(np.median(q)) if len(q) else None,
                            "cross_check_px": None if not np.isfinite(x) else x})
        return {"objects": objects, "quality_min": float(self.quality_min), "start_frame": int(self.start_frame)}


class Observation(NamedTuple):
    """Observed motion of the scene's objects.

    Attributes:
        frame_times: (N,) frame times in s (frame k at k / fps).
        positions: (N, n_objects, 2) world x and vertical (up) position of each object's
            centre in m (start position from the scene plus tracked displacement).
        pixels: (N, n_objects, 2) tracked image position (u, v) of each object's centre.
        profile: (2 * n_objects, N - 1) velocity profile in m/s, rows (obj1 x, obj1 y,
            obj2 x, obj2 y): V[k] = (p[k+1] - p[k]) / (t[k+1] - t[k]) (dissertation 4.2.3).
        position_sd: (2 * n_objects,) tracking noise SD of each position trace in m,
            estimated from the data.
        mask: (N - 1,) bool, True for velocity samples used in the fit (the fit window).
        release_time: video time in s at which object 1 starts to move (from the track).
        fps: frame rate in frames per second.
        moved: (n_objects,) bool, whether each object moved during the video.
        tracking: how the video was tracked (:class:`TrackingInfo`), None for observations
            not made from a video.
    """

    frame_times: np.ndarray
    positions: np.ndarray
    pixels: np.ndarray
    profile: np.ndarray
    position_sd: np.ndarray
    mask: np.ndarray
    release_time: float
    fps: float
    moved: np.ndarray
    tracking: TrackingInfo | None = None

    @property
    def n_objects(self) -> int:
        return self.positions.shape[1]

    @property
    def velocity_sd(self) -> np.ndarray:
        """(2 * n_objects,) SD of a velocity sample in m/s: sqrt(2) * position_sd * fps
        (difference of two independent position errors over one frame)."""
        return np.sqrt(2.0) * self.position_sd * self.fps


def profile_from_positions(positions: np.ndarray, frame_times: np.ndarray) -> np.ndarray:
    """(N, n, 2) positions in m and (N,) times in s -> (2n, N-1) velocity profile in m/s."""
    v = np.diff(positions, axis=0) / np.diff(frame_times)[:, None, None]
    return v.reshape(v.shape[0], -1).T


def trace_names(n_objects: int) -> list[str]:
    """Names of a velocity profile's rows: "object 1 x", "object 1 y", ... (y is vertical, up)."""
    return [f"object {i + 1} {axis}" for i in range(n_objects) for axis in ("x", "y")]
