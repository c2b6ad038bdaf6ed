"""What the video says: the observed velocity profiles and their noise.

An :class:`Observation` is produced by :func:`galileo_jax.observe.observe` (tracking a
video) or by :func:`from_positions` (e.g. from simulated or hand-digitised positions), and
consumed by the likelihood and the inference methods.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


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
