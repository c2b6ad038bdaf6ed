"""What the command-line programs share: one-line argument errors, and finding the videos and their scenes.

Kept apart from the programs (``fit``, ``diagnose``, ``synth``) so that each stays thin:
parse, call one library function, print.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from galileo_jax.errors import GalileoError, SceneError, VideoError


class OneLineParser(argparse.ArgumentParser):
    """argparse that reports usage errors as one line through :class:`GalileoError`."""

    def error(self, message: str):  # noqa: D401 - argparse API
        raise GalileoError(f"{message} (see {self.prog} --help)")


def scene_path(video: Path, scene: str | None) -> Path:
    """The scene file of ``video``: ``scene`` if given, else the video's name with ``.yaml``.

    Raises:
        SceneError: no scene given and none next to the video.
    """
    if scene is not None:
        return Path(scene)
    path = video.with_suffix(".yaml")
    if not path.is_file():
        raise SceneError(f"no scene file for {video.name}: pass --scene FILE or put {path.name} next to the "
                         f"video (see scenes/ramp_20.yaml)")
    return path


def check_video(video: str | Path) -> Path:
    """``video`` as a Path that exists and is a file.

    Raises:
        VideoError: missing, or a folder.
    """
    video = Path(video)
    if not video.exists():
        raise VideoError(f"video {video} not found; check the path")
    if not video.is_file():
        raise VideoError(f"{video} is not a file; give a video file")
    return video


def videos_and_scenes(videos: list[str], scenes: list[str] | None) -> list[tuple[Path, "Scene"]]:  # noqa: F821
    """Check the videos and load their scenes: ``scenes`` is None (each video's own ``.yaml``),
    one file for all videos, or one file per video.

    Raises:
        VideoError, SceneError: as :func:`check_video`, :func:`scene_path` and ``load_scene``;
        GalileoError: a number of scene files that matches neither 1 nor the number of videos.
    """
    from galileo_jax.scene import load_scene

    if not videos:
        raise GalileoError("give at least one video file (see --help)")
    paths = [check_video(v) for v in videos]
    scenes = scenes or []
    if len(scenes) not in (0, 1, len(paths)):
        raise GalileoError(f"give one --scene for all videos or one per video: got {len(scenes)} scene files "
                           f"for {len(paths)} videos")
    if len(scenes) == 1:
        scenes = scenes * len(paths)
    loaded = {}
    out = []
    for j, video in enumerate(paths):
        path = scene_path(video, scenes[j] if scenes else None)
        if path not in loaded:
            loaded[path] = load_scene(path)
        out.append((video, loaded[path]))
    return out
