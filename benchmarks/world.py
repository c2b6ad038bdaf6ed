"""Rendered ramp videos that look like the world, not like one renderer's default.

Shared by ``benchmarks/tracking.py`` (tracking error against the renderer's truth) and
``benchmarks/fit_world.py`` (fit accuracy on such videos). A *condition* fixes what a video
varies on purpose (the object's look, the camera's projection, the image size, motion blur);
everything else is drawn per video from a seeded generator: the ramp angle (10-30 degrees) and
length, cube sizes (objects 25-60 px across at 960x540, 10-15 px at 320x240: sized for the view
that frames the drawn motion), start positions,
masses and frictions (``synth.draw_informative_params``: object 1 slides and reaches object 2),
the objects' colours (one video in three in colours close to the backdrop's grey level), the
camera distance (perspective, 1.5-3 m), the direction of motion (left in every other video),
a cluttered backdrop (one in four), pixel noise (SD 1.5-3.5 grey levels) and the hand holding
object 1 before the release (a flag of the video).
"""

from __future__ import annotations

import itertools
import math
import os
from pathlib import Path
from typing import NamedTuple

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

#: Frame rate of the rendered videos (frames per second).
FPS = 30.0
#: Image sizes (width, height) in px by size class.
SIZES = {"960x540": (960, 540), "320x240": (320, 240)}
#: Sub-frames averaged per frame for motion blur ("on"), over half a frame interval. Poses between
#: physics steps are interpolated (``Motion.qpos_at``), so at the fastest objects here (about
#: 45 px a frame, 22 px over the exposure) the sub-frames lie under 1 px apart: a continuous
#: streak, as a camera's. (Earlier benchmark runs used 5 sub-frames at the nearest
#: physics step, which showed up to 5 copies of a fast object 4-5 px apart.)
BLUR_SUBFRAMES = 24


class Condition(NamedTuple):
    """What a benchmark video varies on purpose."""

    look: str  # "plain" | "checker"
    camera: str  # "orthographic" | "perspective"
    size: str  # "960x540" | "320x240"
    blur: bool

    @property
    def name(self) -> str:
        return f"{self.look}/{self.camera[:5]}/{self.size}/{'blur' if self.blur else 'sharp'}"


def conditions(looks=("plain", "checker"), cameras=("orthographic", "perspective"), sizes=tuple(SIZES),
               blurs=(False, True)) -> list[Condition]:
    """Every combination of the given settings."""
    return [Condition(*c) for c in itertools.product(looks, cameras, sizes, blurs)]


def _grey_like(rng: np.random.Generator) -> tuple[float, float, float]:
    """A colour whose grey level is within 10% of the backdrop's (about 0.78), hue random."""
    grey = rng.uniform(0.70, 0.86)
    hue = rng.normal(0.0, 1.0, 3)
    hue -= hue.mean()
    rgb = grey + 0.18 * hue / max(np.abs(hue).max(), 1e-6)
    weights = np.array([0.299, 0.587, 0.114])
    rgb += grey - rgb @ weights  # back to the grey level
    return tuple(float(c) for c in np.clip(rgb, 0.05, 0.95))


def _colour(rng: np.random.Generator) -> tuple[float, float, float]:
    """A saturated colour of random hue."""
    import colorsys

    return tuple(float(c) for c in colorsys.hsv_to_rgb(rng.uniform(), rng.uniform(0.5, 0.9), rng.uniform(0.35, 0.9)))


#: Object sizes in px (across) drawn per image size class.
OBJECT_PX = {"960x540": (25.0, 60.0), "320x240": (10.0, 15.0)}


def world_scene(rng: np.random.Generator, size: str, cube: float = 0.06) -> dict:
    """A two-cube ramp scene (dict for ``scene_from_dict``) drawn for an image size class."""
    angle = float(rng.uniform(10.0, 30.0))
    length = float(rng.uniform(0.7, 1.1))
    return {
        "name": "world",
        "ramp": {"angle_deg": round(angle, 2), "length": round(length, 3), "width": 0.3},
        "floor": {"length": 0.8},
        "objects": [
            {"name": "object 1", "shape": "box", "size": [cube] * 3, "start": round(length - cube, 3)},
            {"name": "object 2", "shape": "box", "size": [cube] * 3, "start": round(float(rng.uniform(0.12, 0.3)), 3)},
        ],
        "camera": {"pixels_per_metre": 500.0},
    }


def render_world(path: Path, condition: Condition, hand: bool, seed: int) -> dict:
    """Render one benchmark video (with its calibrated scene and truth beside it) unless it
    exists; returns the truth record, plus the ``condition`` and the draws it was made with."""
    import json

    from galileo_jax.render import frame_view
    from galileo_jax.scene import scene_from_dict
    from galileo_jax.synth import draw_informative_params, render_video, resolve_params, simulate_motion

    truth_path = path.with_suffix(".truth.json")
    from _common import rendered

    if rendered(path):
        return json.loads(truth_path.read_text())
    rng = np.random.default_rng(seed)
    layout = world_scene(rng, condition.size)
    rest_frames = int(rng.integers(6, 12))
    width, height = SIZES[condition.size]
    target_px = float(rng.uniform(*OBJECT_PX[condition.size]))
    scene = scene_from_dict(layout)
    params = draw_informative_params(scene, rng, (), fps=FPS, rest_frames=rest_frames, n_frames=None)
    # the cubes' size for the drawn image size: the view fits the motion, so frame it once
    motion = simulate_motion(scene, resolve_params(scene, params), FPS, rest_frames)
    scale = frame_view(scene, motion.positions, width, height).scale
    cube = float(np.clip(target_px / scale, 0.02, 0.15))
    for obj in layout["objects"]:
        obj["size"] = [cube] * 3
    layout["objects"][0]["start"] = round(layout["ramp"]["length"] - cube, 3)
    scene = scene_from_dict(layout)
    close = rng.uniform() < 1 / 3
    colours = [_grey_like(rng) if close else _colour(rng) for _ in range(2)]
    style = dict(look=condition.look, colours=colours, camera=condition.camera,
                 camera_distance=float(rng.uniform(1.5, 3.0)), direction="left" if seed % 2 else "right",
                 blur=BLUR_SUBFRAMES if condition.blur else 0, backdrop="clutter" if rng.uniform() < 0.25 else "plain")
    truth = render_video(scene, params, path, fps=FPS, width=width, height=height,
                         noise_sd=float(rng.uniform(1.5, 3.5)), hand=hand, rest_frames=rest_frames,
                         seed=seed, progress=False, **style)
    truth.update(condition=condition._asdict(), grey_like=bool(close))
    truth_path.write_text(json.dumps(truth))
    return truth


def cached_record(video: Path, make, rerun: bool = False) -> dict:
    """The benchmark record of ``video``: read from ``<video>.json``, or (missing, or
    ``rerun``) made by ``make(video)`` and written there, so that a run resumes."""
    import json

    path = video.with_suffix(".json")
    if path.exists() and not rerun:
        return json.loads(path.read_text())
    rec = make(video)
    path.write_text(json.dumps(rec))
    return rec


def hand_frames(truth: dict) -> int:
    """Frames (from the first) in which the rendered hand may cover or touch object 1: until it
    has left the image (``render.HAND_EXIT_TIME`` after the release), 0 without a hand."""
    from galileo_jax.render import HAND_EXIT_TIME

    if not truth.get("hand"):
        return 0
    return int(truth["release_frame"] + math.ceil(HAND_EXIT_TIME * truth["fps"]) + 1)
