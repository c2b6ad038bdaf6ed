"""Reading a video file into memory (the only I/O of the observation stage).

:func:`read_video` wraps :class:`cv2.VideoCapture` (dissertation 4.2.1) and checks what the
tracker needs: the file exists, decodes, has enough frames and a usable frame rate.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from galileo_jax.errors import VideoError

#: Fewest frames a clip must have: the release-time fit and the noise estimate need a few.
MIN_FRAMES = 5
#: Frame rates outside this range (frames per second) are taken to be missing or corrupt.
FPS_RANGE = (1.0, 10000.0)


class VideoClip(NamedTuple):
    """A decoded video.

    Attributes:
        frames: (N, H, W, 3) uint8 BGR frames.
        fps: frame rate in frames per second (the override when one was given).
        path: the file it came from ("" for clips built in memory).
        container_fps: the frame rate stored in the file (NaN if none or unreadable).
    """

    frames: np.ndarray
    fps: float
    path: str = ""
    container_fps: float = math.nan

    @property
    def n_frames(self) -> int:
        return int(self.frames.shape[0])

    @property
    def frame_times(self) -> np.ndarray:
        """(N,) frame times in s: frame k at k / fps."""
        return np.arange(self.n_frames) / self.fps

    def with_fps(self, fps: float) -> "VideoClip":
        """The same clip with another frame rate (e.g. a high-speed clip stored at 30 fps)."""
        return self._replace(fps=_check_fps(fps, self.path, "the fps override"))


def _check_fps(fps, path: str, what: str) -> float:
    """Return ``fps`` as a float, or raise :class:`VideoError` if it is not usable."""
    try:
        value = float(fps)
    except (TypeError, ValueError):
        value = math.nan
    if not (math.isfinite(value) and FPS_RANGE[0] <= value <= FPS_RANGE[1]):
        raise VideoError(f"video {path or '<clip>'}: {what} {fps!r} is not a usable frame rate; "
                         "set it in the scene file as video: {fps: ...} or pass --fps")
    return value


def _container_fps(cap: cv2.VideoCapture) -> float:
    """The frame rate the container declares (NaN when it declares none)."""
    value = cap.get(cv2.CAP_PROP_FPS)
    return float(value) if value and value > 0 else math.nan


def _decode_all(cap: cv2.VideoCapture) -> list[np.ndarray]:
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok or frame is None:
            break
        if frame.ndim == 2:
            frame = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
        frames.append(frame[..., :3])
    return frames


def read_video(path: str | Path, fps_override: float | None = None) -> VideoClip:
    """Decode every frame of a video file.

    Args:
        path: video file (anything OpenCV's FFmpeg backend reads: mp4, avi, mov, ...).
        fps_override: frame rate to use instead of the container's (frames per second);
            needed when the file stores none, or a wrong one (high-speed clips).

    Returns:
        :class:`VideoClip` with (N, H, W, 3) uint8 BGR frames.

    Raises:
        VideoError: the file is missing, is not a decodable video, has fewer than
            :data:`MIN_FRAMES` frames, or has no usable frame rate and no override.
    """
    path = Path(path)
    if not path.is_file():
        raise VideoError(f"video file {path} not found; check the path")
    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise VideoError(f"{path} is not a readable video (OpenCV cannot open it); "
                             "convert it to mp4 (H.264), e.g. ffmpeg -i IN -c:v libx264 OUT.mp4")
        container_fps = _container_fps(cap)
        frames = _decode_all(cap)
    finally:
        cap.release()
    if not frames:
        raise VideoError(f"{path} has no decodable frames (not a video, or corrupt); "
                         "convert it to mp4 (H.264), e.g. ffmpeg -i IN -c:v libx264 OUT.mp4")
    if len(frames) < MIN_FRAMES:
        raise VideoError(f"{path} has only {len(frames)} frames; at least {MIN_FRAMES} are needed "
                         "to measure motion, use a longer clip")
    if len({f.shape for f in frames}) > 1:
        raise VideoError(f"{path}: frame size changes within the video; re-encode it at one size")
    fps = fps_override if fps_override is not None else container_fps
    what = "the fps override" if fps_override is not None else "the stored frame rate"
    fps = _check_fps(fps, str(path), what)
    return VideoClip(np.stack(frames), fps, str(path), container_fps)


def clip_from_frames(frames: np.ndarray, fps: float) -> VideoClip:
    """Build a :class:`VideoClip` from (N, H, W, 3) or (N, H, W) uint8 frames in memory.

    Raises:
        VideoError: too few frames or an unusable frame rate.
    """
    frames = np.asarray(frames)
    if frames.ndim == 3:
        frames = np.repeat(frames[..., None], 3, axis=-1)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
        raise VideoError(f"frames must be an (N, H, W, 3) uint8 array, got {frames.shape} {frames.dtype}")
    if frames.shape[0] < MIN_FRAMES:
        raise VideoError(f"clip has only {frames.shape[0]} frames; at least {MIN_FRAMES} are needed")
    return VideoClip(frames, _check_fps(fps, "", "the frame rate"), "", float(fps))
