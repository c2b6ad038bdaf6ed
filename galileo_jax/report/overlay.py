"""Overlay video: the simulated objects drawn on the real frames."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from galileo_jax.calibration import Calibration
from galileo_jax.report.results import atomic_path
from galileo_jax.scene import Scene

SIM_COLOUR = (0, 165, 255)  # BGR orange: simulated outline
OBS_COLOUR = (60, 220, 60)  # BGR green: tracked centre


def outline(scene: Scene, i: int, pose: np.ndarray) -> np.ndarray:
    """World outline of object ``i`` in the x / vertical plane.

    Args:
        scene: the scene (object shape and size).
        i: object index.
        pose: (3,) centre x (m), centre z (m), pitch about y (rad).

    Returns:
        (K, 2) world (x, y_up) points in m: a rectangle (box, cylinder side view) or a circle.
    """
    obj = scene.objects[i]
    x, z, pitch = pose
    if obj.shape == "sphere":
        a = np.linspace(0, 2 * math.pi, 24, endpoint=False)
        return np.stack([x + obj.size[0] * np.cos(a), z + obj.size[0] * np.sin(a)], axis=1)
    half_l, half_h = obj.length / 2, obj.height / 2
    local = np.array([[-half_l, -half_h], [half_l, -half_h], [half_l, half_h], [-half_l, half_h]])
    c, s = math.cos(pitch), math.sin(pitch)
    # rotation by pitch about +y: local x -> (cos, -sin) in (x, z); local z -> (sin, cos)
    wx = x + local[:, 0] * c + local[:, 1] * s
    wz = z - local[:, 0] * s + local[:, 1] * c
    return np.stack([wx, wz], axis=1)


def write_overlay(path: str | Path, frames: np.ndarray, fps: float, scene: Scene, calib: Calibration,
                  sim_poses: np.ndarray, observed_pixels: np.ndarray | None = None,
                  caption: str = "", progress: bool = True) -> None:
    """Draw simulated object outlines (orange) and tracked centres (green) on each frame.

    Args:
        path: output .mp4 path (written atomically).
        frames: (N, H, W, 3) uint8 BGR video frames.
        fps: frame rate of the output video.
        scene: the scene (shapes and sizes).
        calib: absolute world -> pixel calibration.
        sim_poses: (N, n_objects, 3) simulated poses at the frame times (x m, z m, pitch rad).
        observed_pixels: optional (N, n_objects, 2) tracked centres (u, v) in px.
        caption: text drawn in the top-left corner.
        progress: show a progress bar.
    """
    n, h, w = frames.shape[:3]
    with atomic_path(path) as tmp:
        writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (w, h))
        if not writer.isOpened():
            raise OSError(f"OpenCV cannot write {path}")
        try:
            for k in tqdm(range(n), desc="overlay video", unit="frame", disable=not progress, leave=False):
                img = frames[k].copy()
                for i in range(sim_poses.shape[1]):
                    px = calib.world_to_pixel(outline(scene, i, sim_poses[k, i]))
                    cv2.polylines(img, [np.round(px).astype(np.int32)], True, SIM_COLOUR, 2, cv2.LINE_AA)
                    if observed_pixels is not None and np.isfinite(observed_pixels[k, i]).all():
                        u, v = np.round(observed_pixels[k, i]).astype(int)
                        cv2.circle(img, (int(u), int(v)), 4, OBS_COLOUR, -1, cv2.LINE_AA)
                cv2.putText(img, f"{caption}  t={k / fps:5.2f}s", (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                            (255, 255, 255), 2, cv2.LINE_AA)
                cv2.putText(img, f"{caption}  t={k / fps:5.2f}s", (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                            (0, 0, 0), 1, cv2.LINE_AA)
                writer.write(img)
        finally:
            writer.release()
