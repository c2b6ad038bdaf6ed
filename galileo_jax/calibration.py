"""Camera calibration: image pixels <-> the world x / vertical plane of motion.

Image axes: u to the right, v down (OpenCV). World: x horizontal, positive in the direction
object 1 moves down the ramp; y_up vertical, positive up (the profile's "y" traces).

A world displacement (dx, dy_up) in m maps to an image displacement by
``(du', dv') = (d s dx, -s dy_up)`` with s the scale in px/m and d = +1 if the ramp points
right in the image, -1 if left, then a rotation by the camera roll rho (counter-clockwise as
seen in the image): ``du = du' cos rho + dv' sin rho``, ``dv = -du' sin rho + dv' cos rho``.
Absolute positions need an anchor: a pixel whose world position is known (the ramp foot,
``camera.foot_pixel``, or an object's start pixel and its start position from the scene).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from galileo_jax.scene import Camera


class Calibration(NamedTuple):
    """Affine map between world (x, y_up) in m and pixels (u, v).

    Attributes:
        scale: pixels per metre.
        direction: +1 if world +x points right in the image, -1 if left.
        roll: camera roll in rad (counter-clockwise in the image).
        anchor_px: (2,) pixel of the anchor point.
        anchor_world: (2,) world (x, y_up) of the anchor point in m.
    """

    scale: float
    direction: float
    roll: float
    anchor_px: np.ndarray
    anchor_world: np.ndarray

    def _matrix(self) -> np.ndarray:
        """2x2 matrix A with pixel displacement = A @ world displacement."""
        c, s = math.cos(self.roll), math.sin(self.roll)
        rot = np.array([[c, s], [-s, c]])
        return rot @ np.diag([self.direction * self.scale, -self.scale])

    def world_to_pixel(self, xy: np.ndarray) -> np.ndarray:
        """(..., 2) world (x, y_up) in m -> (..., 2) pixels (u, v)."""
        xy = np.asarray(xy, dtype=float)
        return (xy - self.anchor_world) @ self._matrix().T + self.anchor_px

    def pixel_to_world(self, uv: np.ndarray) -> np.ndarray:
        """(..., 2) pixels (u, v) -> (..., 2) world (x, y_up) in m."""
        uv = np.asarray(uv, dtype=float)
        return (uv - self.anchor_px) @ np.linalg.inv(self._matrix()).T + self.anchor_world

    def displacement_to_world(self, duv: np.ndarray) -> np.ndarray:
        """(..., 2) pixel displacements -> (..., 2) world displacements in m."""
        return np.asarray(duv, dtype=float) @ np.linalg.inv(self._matrix()).T


def calibration(camera: Camera, anchor_px=None, anchor_world=(0.0, 0.0)) -> Calibration:
    """Build the :class:`Calibration` of a scene's camera.

    Args:
        camera: the scene's camera block.
        anchor_px: pixel of a point with known world position; defaults to
            ``camera.foot_pixel`` (the world origin), else (0, 0) (displacements only).
        anchor_world: world (x, y_up) in m of ``anchor_px``.
    """
    if anchor_px is None:
        anchor_px = camera.foot_pixel if camera.foot_pixel is not None else (0.0, 0.0)
        anchor_world = (0.0, 0.0)
    return Calibration(
        scale=camera.scale,
        direction=1.0 if camera.ramp_direction == "right" else -1.0,
        roll=math.radians(camera.roll_deg),
        anchor_px=np.asarray(anchor_px, dtype=float),
        anchor_world=np.asarray(anchor_world, dtype=float),
    )
