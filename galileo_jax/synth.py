"""Synthetic ramp videos with exact ground truth, rendered with MuJoCo.

:func:`render_video` simulates a scene in C MuJoCo for given masses and friction coefficients
(and optionally hidden physical effects, see below) and renders it through a front camera
(:mod:`galileo_jax.render`): orthographic by default, so the pixel scale is exact at any
depth, or perspective, exact in the plane of motion; it writes three files next to each other
(each atomically):

* ``<stem>.mp4``: the video (mp4v), ``width`` x ``height``, ``fps`` frames per second, with
  Gaussian pixel noise of SD ``noise_sd`` grey levels (before compression).
* ``<stem>.yaml``: the input scene with its ``camera`` block replaced by the exact
  calibration (``pixels_per_metre`` in the plane of motion, ``foot_pixel`` = pixel of the
  world origin, i.e. the ramp foot in the plane of motion, ``ramp_direction: right`` or
  ``left``, ``roll_deg: 0``), and ``video.fps`` only when the container's frame rate differs
  from ``fps``.
* ``<stem>.truth.json``: the ground truth (see :func:`truth_record`).

Timeline: frame k is shown at t_k = k / fps, k = 0..N-1. The objects rest at their start
poses (optionally held by a hand) for ``rest_frames`` frames and are released at
``release_time = rest_frames / fps``; frame k >= rest_frames shows the state after
(k - rest_frames) * substeps physics steps of dt = 1 / (fps * substeps), the timestep of
:func:`galileo_jax.physics.simulate.physics_timestep`. This is the sampling of
:func:`galileo_jax.physics.simulate.velocity_profile` with the same ``frame_times`` and
``release_time``, so the MJX simulator and the video can be compared sample by sample.

Masses and frictions are set as :func:`galileo_jax.physics.simulate.apply_params` sets them in MJX:
``body_mass``, ``body_inertia`` scaled with the mass, ``pair_friction[:, 0:2]`` of each
object's pairs with the ramp and floor, then ``mj_setConst`` recomputes ``invweight0``.

Rendering needs an OpenGL context: ``MUJOCO_GL=egl`` (set by default on importing galileo_jax) with Mesa's
software EGL works without a GPU; on Debian/Ubuntu install
``libegl1 libegl-mesa0 libopengl0 libgl1-mesa-dri``.

CLI::

    python -m galileo_jax.synth --scene scenes/ramp_20.yaml --m1 0.6 --k1 0.15 --m2 0.3 \\
        --k2 0.25 --out out/ [--fps 30] [--duration S] [--noise 2] [--hand] [--seed 0] \\
        [--random N] [--effect NAME[=VALUE] ...] [--width 640] [--height 360] [--rest 0.3] \\
        [--look checker|plain] [--colour R,G,B ...] [--camera orthographic|perspective] \\
        [--distance 2.2] [--left | --direction right|left] [--blur N] [--shutter 0.5] \\
        [--backdrop plain|clutter]

``--out`` is a ``.mp4`` path or a folder (``<scene name>.mp4``, or ``<scene name>_NNN.mp4``
with ``--random N``).

How the video looks (:func:`render_video`; the defaults give the original look):

* ``--look plain``: each object one flat colour instead of the checker texture;
  ``--colour R,G,B`` (0..1, once per object) sets the base colours of either look.
* ``--camera perspective [--distance D]``: a pinhole D m (default 2.2) from the plane of
  motion, looking straight at it, with fovy = 2 atan((H/2) / (scale D)): the written
  ``pixels_per_metre`` and ``foot_pixel`` are exact in the plane of the objects' centres,
  nearer surfaces (an object's front face) look slightly larger.
* ``--left``: object 1 moves to the left of the image (the scene seen from its other side;
  the scene file says ``ramp_direction: left``).
* ``--blur N [--shutter S]``: motion blur, the average of N sub-frames spread over the
  fraction S (default 0.5) of the frame interval around each frame time, each showing the
  state interpolated between the physics steps around it (dt = 1 / (fps substeps)). A camera's
  blur is a continuous streak: give enough sub-frames that they lie about 1 px apart at the
  fastest object (a 40 px/frame object with S = 0.5 needs about 20).
* ``--backdrop clutter``: a backdrop wall with posters, shelves, cables and blobs (seeded by
  ``--seed``) instead of the plain grey one.
* Low resolutions (e.g. ``--width 320 --height 240``) work with all of these.

The truth JSON then also records ``pixels_front`` (the projected centre of each object's face
toward the camera) and with blur ``pixels_exposure`` (the mean projected centre over each
frame's exposure); see :func:`truth_record`::

    python -m galileo_jax.synth --scene scenes/ramp_20.yaml --m1 0.6 --k1 0.2 --m2 0.3 --k2 0.25 \\
        --camera perspective --look plain --left --blur 20 --backdrop clutter --out out/world.mp4

Hidden effects: ``--effect NAME=VALUE`` (repeatable) simulates a physical effect of
:mod:`galileo_jax.effects` that the base model lacks, e.g. ``--effect quadratic_drag=0.9``
(``NAME=V1,V2`` for an effect with several parameters; ``NAME`` alone for one without, such as
``rolling``, or with ``--random`` to draw the value uniformly from the parameter's
``synth_range``; ``--effect none``: no effect). The effect acts in the C MuJoCo simulation
through the same hooks as in the MJX fit (:func:`simulate_motion`), its values go into the
truth JSON (``effects``, ``hidden_effects`` and each parameter by name at top level), and the
written scene YAML does not mention it (the scene's own ``effects`` are kept)::

    python -m galileo_jax.synth --scene scenes/ramp_20.yaml --random 5 --effect quadratic_drag --out out/

With ``--random`` and effects, each draw must give an informative video
(:func:`draw_informative_params`): object 1's friction on the ramp after the effects (k1 +
dk_ramp for ``ramp_friction``) below tan(theta) - 0.05, and in the simulated motion object 1
reaches object 2 and moves it (one object: reaches the floor) within the video; otherwise
everything is drawn again, at most 20 times. Without effects the draws are unchanged.

The shipped example was made with::

    python -m galileo_jax.synth --scene scenes/ramp_20.yaml --m1 0.6 --k1 0.2 --m2 0.3 \
        --k2 0.25 --hand --noise 2 --rest 0.5 --duration 3.0 --seed 0 \
        --out examples/ramp20_example.mp4
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys

try:  # MuJoCo loads its OpenGL backend (MUJOCO_GL) on import: a missing libEGL fails here.
    import mujoco
except Exception as _err:  # noqa: BLE001
    if __name__ != "__main__":
        raise
    print(f"error: cannot load MuJoCo with MUJOCO_GL={os.environ['MUJOCO_GL']} ({type(_err).__name__}: {_err}); "
          f"install libegl1 libegl-mesa0 libopengl0 libgl1-mesa-dri, or set MUJOCO_GL to a working backend",
          file=sys.stderr)
    raise SystemExit(2) from None

import tempfile  # noqa: E402
from collections.abc import Iterator, Mapping  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import NamedTuple  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from galileo_jax import render  # noqa: E402
from galileo_jax.effects import BodyState, Effect, available_effects, check_applicable, get_effect  # noqa: E402
from galileo_jax.effects.runtime import (apply_c_model, c_step, effect_param_names, frictions,  # noqa: E402
                                         has_step_hooks, make_context, neutral_values, split_values,
                                         surface_frictions)
from galileo_jax.cli import OneLineParser  # noqa: E402
from galileo_jax.errors import GalileoError, SceneError, cli_entry  # noqa: E402
from galileo_jax.physics.model import ModelIndex, WorldPhysics, build_model, object_start_pose, set_physics  # noqa: E402
from galileo_jax.scene import Scene, Video, load_scene, save_scene  # noqa: E402
from galileo_jax.physics.simulate import PhysParams, physics_timestep, scene_effects  # noqa: E402

#: Default seconds at rest (held) before release.
REST_SECONDS = 0.3
#: Seconds all objects must stay at rest before an automatic-length video ends.
SETTLE_SECONDS = 0.5
#: Longest automatic video (s, rest frames included).
MAX_SECONDS = 4.0
#: An object is at rest when its centre moves less than this speed (m/s) over a frame.
REST_SPEED = 2e-3
#: Margin (dimensionless) below tan(theta) for k1 in random draws, so object 1 slides.
SLIDE_MARGIN = 0.05
#: Smallest friction coefficient at rest that the effects may lower a random draw's friction to
#: (e.g. k - s v_ref of the centred ``velocity_friction``; a base coefficient already below it
#: is kept). Near zero, objects that should have stopped
#: drift on MuJoCo's soft contacts, and the C renderer and MJX part ways (measured: a draw with
#: k - s v_ref < 0 left object 1 sliding backwards at 0.14 m/s in MJX and at rest in C MuJoCo).
MIN_REST_FRICTION = 0.05
#: Range of random friction draws (intersected with the scene's prior).
RANDOM_FRICTION = (0.02, 0.6)
#: Range of random mass draws in kg (intersected with the scene's prior).
RANDOM_MASS = (0.05, 1.0)
#: Random draws with effects: how far (m) object 2 (or a lone object starting on the floor)
#: must move for the video to count as informative.
REACH_DISTANCE = 0.005
#: Random draws with effects: draws tried before giving up.
MAX_REDRAWS = 20
#: Most sub-frames per frame of a motion-blurred video.
MAX_BLUR = 64


class Motion(NamedTuple):
    """The simulated motion at the video's frames and at every physics step.

    Attributes:
        qpos: (N, nq) generalised positions at each frame (world frame, m and quaternions).
        positions: (N, n_objects, 2) world x and vertical z of each object's centre in m.
        release_frame: frames before release (objects at their start poses).
        fps: frames per second.
        steps: (M, nq) generalised positions at every physics step from the release: row j
            after j steps of dt = 1 / (fps * substeps) (row 0: the start pose), so frame
            k >= ``release_frame`` is row (k - release_frame) * substeps; the rows run one
            frame past the last frame (for exposures that end after it).
        substeps: physics steps per frame.
        qpos_adr: (n_objects,) each object's free-joint address in ``qpos``.
    """

    qpos: np.ndarray
    positions: np.ndarray
    release_frame: int
    fps: float
    steps: np.ndarray
    substeps: int
    qpos_adr: tuple[int, ...]

    @property
    def n_frames(self) -> int:
        return self.qpos.shape[0]

    @property
    def release_time(self) -> float:
        """Video time of release in s."""
        return self.release_frame / self.fps

    @property
    def frame_times(self) -> np.ndarray:
        """(N,) frame times in s."""
        return np.arange(self.n_frames) / self.fps

    def qpos_at(self, times) -> np.ndarray:
        """(...) video times in s -> (..., nq) generalised positions, interpolated between physics steps.

        Positions are interpolated linearly between the two physics steps around each time,
        orientations by normalised linear interpolation of the quaternions (nlerp: at 240
        steps/s an object turns far less than a degree between steps). So sub-frames finer
        than the physics steps show distinct poses, and a blurred frame is a continuous streak,
        as a camera's, rather than a few copies of the object. Times before the release give
        the start pose, times past the simulated steps the last step's; at the frame times
        (whole steps) this is exactly ``qpos``.
        """
        j = (np.asarray(times, dtype=float) - self.release_time) * self.fps * self.substeps
        j = np.clip(j, 0.0, self.steps.shape[0] - 1)
        nearest = np.rint(j)
        j = np.where(np.abs(j - nearest) < 1e-9, nearest, j)  # frame times land exactly on their step
        lo = np.floor(j).astype(int)
        hi = np.minimum(lo + 1, self.steps.shape[0] - 1)
        w = (j - lo)[..., None]
        a, b = self.steps[lo], self.steps[hi]
        out = (1.0 - w) * a + w * b
        for adr in self.qpos_adr:  # each free joint: x, y, z, then the quaternion
            qa, qb = a[..., adr + 3:adr + 7], b[..., adr + 3:adr + 7]
            qb = np.where(np.sum(qa * qb, axis=-1, keepdims=True) < 0, -qb, qb)  # the shorter way round
            q = (1.0 - w) * qa + w * qb
            out[..., adr + 3:adr + 7] = q / np.linalg.norm(q, axis=-1, keepdims=True)
        return np.where(w == 0.0, a, out)


def exposure_times(n_frames: int, fps: float, blur: int = 0, shutter: float = 0.5) -> np.ndarray:
    """Sub-frame times of a motion-blurred video.

    Frame k is exposed over [t_k - shutter / (2 fps), t_k + shutter / (2 fps)] (t_k = k / fps),
    sampled at the midpoints of ``blur`` equal parts of that interval (its mean time is t_k).

    Args:
        n_frames: N frames.
        fps: frames per second.
        blur: sub-frames per frame; 0 or 1: none (the frame times).
        shutter: exposure as a fraction of the frame interval, in (0, 1].

    Returns:
        (N, max(blur, 1)) video times in s.
    """
    s = max(int(blur), 1)
    offsets = shutter * ((np.arange(s) + 0.5) / s - 0.5) / fps
    return np.arange(n_frames)[:, None] / fps + offsets


# --------------------------------------------------------------------------- parameters


def resolve_params(scene: Scene, params, effects=()) -> PhysParams:
    """Masses, frictions and effect parameters, from a dict or :class:`PhysParams`.

    Args:
        scene: the scene; its known masses/frictions fill values the dict leaves out.
        params: ``{"m1", "k1", "m2", "k2", <effect parameters>}`` (any subset of the masses
            and frictions that, with the scene's known values, gives every object a mass in kg
            and a friction coefficient; every parameter of the simulated effects, by its name,
            e.g. ``"drag_quadratic"``) or a :class:`PhysParams` with (n_objects,) arrays and,
            when the effects have parameters, ``effects`` in the order of their names.
        effects: extra effects (names or :class:`~galileo_jax.effects.Effect`) simulated on
            top of the scene's own ``scene.effects`` (see :func:`simulate.scene_effects`).

    Returns:
        :class:`PhysParams` of numpy float arrays, shapes (n_objects,); ``effects`` is the
        (n_effect_params,) vector of the effects' values (ordered as
        :func:`~galileo_jax.effects.runtime.effect_param_names`), or None when no effect is
        simulated.

    Raises:
        GalileoError: a value is missing, unknown, non-finite, out of range, or contradicts
            a value the scene fixes; an unknown effect.
    """
    n = scene.n_objects
    effs = scene_effects(scene, effects)
    names = effect_param_names(effs)
    values = None
    if isinstance(params, PhysParams):
        mass = np.asarray(params.mass, dtype=float).reshape(-1)
        friction = np.asarray(params.friction, dtype=float).reshape(-1)
        if mass.shape != (n,) or friction.shape != (n,):
            raise GalileoError(f"PhysParams must have {n} masses and {n} frictions for this scene")
        if params.effects is not None:
            values = np.asarray(params.effects, dtype=float).reshape(-1)
            if values.shape != (len(names),):
                raise GalileoError(f"PhysParams.effects has {values.size} values but the effects take "
                                   f"{len(names)} ({', '.join(names) or 'none'})")
        elif names:
            raise GalileoError(f"PhysParams.effects is None but the effects need values for {', '.join(names)}")
    elif isinstance(params, Mapping):
        base = {f"{p}{i + 1}" for i in range(n) for p in "mk"}
        allowed = base | set(names)
        unknown = sorted(set(params) - allowed)
        if unknown:
            owner = _effect_of_param(unknown[0])
            if owner is not None and unknown[0] not in base:
                raise GalileoError(f"{unknown[0]} is a parameter of effect {owner.name!r}, which is not simulated; "
                                   f"add the effect (effects=[{owner.name!r}], CLI --effect {owner.name}=VALUE)")
            raise GalileoError(f"unknown parameter {unknown[0]!r}; this scene takes {', '.join(sorted(base))}"
                               + (f" and the effects' {', '.join(names)}" if names else ""))
        mass, friction = np.zeros(n), np.zeros(n)
        for i, obj in enumerate(scene.objects):
            for key, known, out in ((f"m{i + 1}", obj.mass, mass), (f"k{i + 1}", obj.friction, friction)):
                given = params.get(key)
                if given is None and known is None:
                    flag = "--" + key
                    raise GalileoError(f"{key} is free in the scene; give its value ({flag})")
                if given is not None and known is not None and not math.isclose(float(given), known, rel_tol=1e-9):
                    raise GalileoError(f"{key} = {given} contradicts the scene, which fixes {key} = {known}; "
                                       f"leave it out or edit the scene")
                out[i] = float(given if given is not None else known)
        if effs:
            values = np.zeros(len(names))
            j = 0
            for e in effs:
                for p in e.params:
                    if params.get(p.name) is None:
                        raise GalileoError(f"effect {e.name!r} needs a value of {p.name} ({p.doc or p.unit}); "
                                           f"give it (CLI: --effect {e.name}=VALUE, e.g. {p.synth_range[0]:g})")
                    values[j] = float(params[p.name])
                    j += 1
    else:
        raise GalileoError("params must be a dict {m1, k1, m2, k2, <effect parameters>} or a PhysParams")
    for i in range(n):
        if not (math.isfinite(mass[i]) and 0 < mass[i] <= 1e3):
            raise GalileoError(f"m{i + 1} = {mass[i]} must be a mass in kg in (0, 1000]")
        if not (math.isfinite(friction[i]) and 0 <= friction[i] <= 10):
            raise GalileoError(f"k{i + 1} = {friction[i]} must be a friction coefficient in [0, 10]")
    if not effs:
        return PhysParams(mass, friction)
    if values is None:  # PhysParams with effects=None and parameterless effects only
        values = np.zeros(0)
    p_list = [p for e in effs for p in e.params]
    for p, v in zip(p_list, values):
        if not (math.isfinite(v) and p.lower <= v <= p.upper):
            raise GalileoError(f"{p.name} = {v:g} is outside the effect's range [{p.lower:g}, {p.upper:g}] {p.unit}".rstrip())
    return PhysParams(mass, friction, values)


def _effect_of_param(name: str) -> Effect | None:
    """The registered effect that has a parameter called ``name``, or None."""
    for e in available_effects().values():
        if name in e.param_names:
            return e
    return None


def effect_value_dict(effects, values) -> dict[str, dict[str, float]]:
    """``{effect name: {parameter: value}}`` of a flat effect-parameter vector (empty dicts for
    effects without parameters)."""
    vals = split_values(effects, np.asarray(values if values is not None else neutral_values(effects), float))
    return {e.name: {p.name: float(x) for p, x in zip(e.params, v if v is not None else [])}
            for e, v in zip(effects, vals)}


def param_dict(params: PhysParams) -> dict[str, float]:
    """``{"m1", "k1", ...}`` of :class:`PhysParams` (plus nothing else)."""
    out = {}
    for i, (m, k) in enumerate(zip(np.asarray(params.mass), np.asarray(params.friction)), start=1):
        out[f"m{i}"] = float(m)
        out[f"k{i}"] = float(k)
    return out


def draw_random_params(scene: Scene, rng: np.random.Generator, margin: float = SLIDE_MARGIN,
                       fixed: Mapping[str, float] | None = None) -> dict[str, float]:
    """Draw the scene's free parameters uniformly, with object 1 sure to slide.

    Masses: uniform on ``RANDOM_MASS`` intersected with ``priors.mass``; frictions uniform on
    ``RANDOM_FRICTION`` intersected with ``priors.friction``; k1 also below
    tan(theta) - ``margin``. Values in ``fixed`` are kept.

    Raises:
        GalileoError: no friction range leaves object 1 sliding (ramp too shallow).
    """
    fixed = dict(fixed or {})
    out = {}
    ma, mb = max(RANDOM_MASS[0], scene.priors.mass[0]), min(RANDOM_MASS[1], scene.priors.mass[1])
    fa, fb = max(RANDOM_FRICTION[0], scene.priors.friction[0]), min(RANDOM_FRICTION[1], scene.priors.friction[1])
    for name in scene.free_parameters():
        if name in fixed:
            continue
        if name.startswith("m"):
            out[name] = float(rng.uniform(ma, mb))
            continue
        hi = min(fb, math.tan(scene.ramp.angle) - margin) if name == "k1" else fb
        if hi <= fa:
            raise GalileoError(f"no friction in [{fa}, {hi:.3g}] lets object 1 slide on a "
                               f"{scene.ramp.angle_deg} degree ramp; use a steeper ramp or widen priors.friction")
        out[name] = float(rng.uniform(fa, hi))
    out.update({k: float(v) for k, v in fixed.items() if v is not None})
    return out


def draw_effect_values(effects, rng: np.random.Generator, fixed: Mapping[str, float] | None = None) -> dict[str, float]:
    """Draw each effect parameter not in ``fixed`` uniformly on its ``synth_range``; keep ``fixed``.

    Returns:
        ``{parameter name: value}`` for every parameter of ``effects`` (in their order).
    """
    fixed = dict(fixed or {})
    out = {}
    for e in effects:
        for p in e.params:
            out[p.name] = float(fixed[p.name]) if p.name in fixed else float(rng.uniform(*p.synth_range))
    return out


def ramp_friction_at_rest(scene: Scene, effects, values: Mapping[str, float], friction) -> float:
    """Object 1's friction coefficient on the ramp at rest after the effects' ``friction`` hooks
    (``k1 + dk_ramp`` for ``ramp_friction``; ``k1`` when no hook changes it).

    Args:
        scene: the scene.
        effects: the simulated effects (Effect objects).
        values: their parameter values by name.
        friction: (n_objects,) base friction coefficients.
    """
    return float(frictions_at_rest(scene, effects, values, friction)[0, 0])


def frictions_at_rest(scene: Scene, effects, values: Mapping[str, float], friction) -> np.ndarray:
    """(n_objects, 2) friction coefficients at rest (on the ramp, on the floor) after the
    effects' ``model`` hooks (e.g. ``ramp_friction``) and ``friction`` hooks (arguments as
    :func:`ramp_friction_at_rest`)."""
    effects = tuple(effects)
    friction = np.asarray(friction, dtype=float).reshape(-1)
    if not any(e.friction is not None or e.model is not None for e in effects):
        return np.repeat(friction[:, None], 2, axis=1)
    n = scene.n_objects
    model, index = build_model(scene, effects=effects)
    data = mujoco.MjData(model)
    set_physics(model, data, index, np.asarray(model.body_mass[list(index.body)]), friction)
    ctx = make_context(scene, index, 1.0 / 240.0)
    flat = np.asarray([values[p] for p in effect_param_names(effects)], dtype=float)
    apply_c_model(effects, flat, model, data, index, ctx)
    k = surface_frictions(model.pair_friction, ctx, friction)
    pos = np.stack([object_start_pose(scene, i)[0] for i in range(n)])
    state = BodyState(pos, np.zeros((n, 3)), np.ones(n))
    out = frictions(effects, split_values(effects, flat), k, state, ctx)
    return np.asarray(k if out is None else out, dtype=float)


def degenerate_motion(scene: Scene, motion: Motion) -> str | None:
    """Why ``motion`` would make an uninformative video, or None if it is informative.

    Informative: with two objects, object 1 reaches object 2 and moves it (more than
    :data:`REACH_DISTANCE`); with one object starting on the ramp, its centre passes the ramp's
    foot (it reaches the floor); with one object starting on the floor, it moves more than
    :data:`REACH_DISTANCE`. All within the video.
    """
    pos = motion.positions
    travel = np.linalg.norm(pos - pos[0], axis=-1).max(axis=0)
    if scene.n_objects == 2:
        if travel[1] <= REACH_DISTANCE:
            return "object 1 does not reach object 2 within the video"
        return None
    if scene.placement(0) == "ramp":
        if pos[:, 0, 0].max() <= 0.0:
            return "object 1 does not reach the floor within the video"
        return None
    if travel[0] <= REACH_DISTANCE:
        return "object 1 does not move"
    return None


def draw_informative_params(scene: Scene, rng: np.random.Generator, effects, *, fps: float, rest_frames: int,
                            n_frames: int | None = None, fixed: Mapping[str, float] | None = None,
                            fixed_effects: Mapping[str, float] | None = None,
                            attempts: int = MAX_REDRAWS) -> dict[str, float]:
    """Random free parameters and effect values that give an informative video.

    Rule (documented in the CLI help): the effect parameters not in ``fixed_effects`` are drawn
    uniformly on their ``synth_range``; then the scene's free masses and frictions as
    :func:`draw_random_params` draws them, with object 1's friction on the ramp *after the
    effects* (e.g. ``k1 + dk_ramp`` for ``ramp_friction``, see :func:`ramp_friction_at_rest`)
    below tan(theta) - :data:`SLIDE_MARGIN`, and no friction at rest lowered by the effects
    below :data:`MIN_REST_FRICTION` (:func:`frictions_at_rest`); then the motion is simulated in C MuJoCo for the
    video's length and must pass :func:`degenerate_motion` (object 1 reaches object 2, or the
    floor). A draw that breaks a rule is thrown away and everything is drawn again, at most
    ``attempts`` times.

    Args:
        scene: the scene.
        rng: random generator.
        effects: the simulated effects (names or Effects; the scene's own are added).
        fps, rest_frames, n_frames: the video's timing (``n_frames`` None: automatic length).
        fixed: base parameters to keep (``m1``, ...).
        fixed_effects: effect parameter values to keep, by parameter name.
        attempts: draws before giving up.

    Returns:
        ``{"m1", "k1", ..., <effect parameters>}``, ready for :func:`render_video`.

    Raises:
        GalileoError: no draw in ``attempts`` gave an informative video (the message says why
            the last one failed).
    """
    effs = scene_effects(scene, effects)
    check_applicable(effs, scene)
    fixed = dict(fixed or {})
    limit = math.tan(scene.ramp.angle) - SLIDE_MARGIN
    on_ramp = scene.placement(0) == "ramp"
    reason = "no draw was tried"
    for _ in range(max(1, attempts)):
        values = draw_effect_values(effs, rng, fixed_effects)
        probe = np.full(scene.n_objects, max(limit, 0.0))
        offset = max(0.0, ramp_friction_at_rest(scene, effs, values, probe) - probe[0]) if on_ramp else 0.0
        try:
            base = draw_random_params(scene, rng, margin=SLIDE_MARGIN + offset, fixed=fixed)
        except GalileoError as err:
            reason = str(err).split(";")[0]
            continue
        params = {**base, **values}
        phys = resolve_params(scene, params, effs)
        k_rest = frictions_at_rest(scene, effs, values, phys.friction)  # (n_objects, ramp / floor)
        if on_ramp:
            k_ramp = float(k_rest[0, 0])
            if k_ramp >= limit:
                reason = (f"object 1's friction on the ramp {k_ramp:.3g} is not below "
                          f"tan(theta) - {SLIDE_MARGIN} = {limit:.3g}")
                continue
        floor = np.minimum(MIN_REST_FRICTION, np.asarray(phys.friction, dtype=float))[:, None]
        if np.any(k_rest < floor - 1e-12):
            reason = (f"the effects lower a friction coefficient at rest to {k_rest.min():.3g}, below "
                      f"{MIN_REST_FRICTION}: a resting object would drift")
            continue
        motion = simulate_motion(scene, phys, fps, rest_frames, n_frames, effects=effs)
        reason = degenerate_motion(scene, motion)
        if reason is None:
            return params
    names = ", ".join(e.name for e in effs)
    raise GalileoError(f"no random draw in {attempts} tries gives an informative video with effect(s) {names} "
                       f"(last: {reason}); fix fewer values, lengthen --duration or use a steeper ramp")


# --------------------------------------------------------------------------- physics


def _centres(qpos: np.ndarray, index: ModelIndex) -> np.ndarray:
    """(..., nq) -> (..., n_objects, 2) world (x, z) of the object centres in m."""
    return np.stack([qpos[..., [a, a + 2]] for a in index.qpos], axis=-2)


def simulate_motion(scene: Scene, params: PhysParams, fps: float, rest_frames: int,
                    n_frames: int | None = None, max_seconds: float = MAX_SECONDS,
                    settle_seconds: float = SETTLE_SECONDS, effects=(), effect_values=None,
                    world: WorldPhysics | None = None) -> Motion:
    """Simulate the scene in C MuJoCo and sample it at the video's frames.

    Args:
        scene: the scene (its ``simulation.substeps`` sets the timestep).
        params: masses and frictions, (n_objects,) each (and optionally ``effects``, the
            effect parameter values).
        fps: frames per second.
        rest_frames: frames before release.
        n_frames: total frames; ``None``: until every object has been at rest (slower than
            :data:`REST_SPEED`) for ``settle_seconds``, at most ``max_seconds`` of video.
        max_seconds: cap of the automatic length in s.
        settle_seconds: rest time that ends an automatic-length video, in s.
        effects: extra effects (names or Effects) simulated on top of the scene's own
            ``scene.effects``. With no effect at all, the base model is stepped with
            ``mj_step``, ``substeps`` times per frame.
        effect_values: the effects' parameter values: a flat vector ordered as
            :func:`~galileo_jax.effects.runtime.effect_param_names`, or a dict by parameter
            name; ``None``: ``params.effects``, else the neutral values.
        world: physics the fitted model does not have (:class:`~galileo_jax.physics.model.WorldPhysics`:
            elliptic friction cones, a ramp board with an edge); ``None``: the model's own.

    With effects, the model is built with their ``build`` hooks, masses and frictions are set
    as without, and at release the effects' model updates and release velocities are applied
    (:func:`~galileo_jax.effects.runtime.apply_c_model`); then every physics step goes through
    :func:`~galileo_jax.effects.runtime.c_step` (forces through ``xfrc_applied``, per-step
    friction), the physics of the MJX rollout (:func:`galileo_jax.physics.simulate.rollout`).

    Returns:
        :class:`Motion`, with the state after every physics step in ``steps`` (for motion
        blur: :meth:`Motion.qpos_at`).

    Raises:
        GalileoError: the simulation diverged, an effect does not apply to the scene, or the
            effect values do not fit the effects.
    """
    effs = scene_effects(scene, effects)
    check_applicable(effs, scene)
    values = _effect_vector(effs, params, effect_values)
    substeps = scene.simulation.substeps
    dt = physics_timestep(fps, substeps)
    model, index = build_model(scene, timestep=dt, effects=effs, world=world)
    data = mujoco.MjData(model)
    set_physics(model, data, index, params.mass, params.friction)
    mujoco.mj_forward(model, data)
    ctx = make_context(scene, index, dt)
    k_base = np.asarray(params.friction, dtype=np.float64).reshape(-1)
    limit = n_frames if n_frames is not None else max(rest_frames + 2, int(round(max_seconds * fps)))
    settle = max(1, int(round(settle_seconds * fps)))
    frames = [data.qpos.copy()] * (rest_frames + 1)
    apply_c_model(effs, values, model, data, index, ctx)  # release
    k_surface = np.asarray(surface_frictions(model.pair_friction, ctx, k_base))
    step = _physics_step(effs, values, model, data, index, ctx, k_surface)
    steps = [data.qpos.copy()]
    still = 0
    while len(frames) < limit:
        _advance(step, substeps, data, steps, bool(effs))
        frames.append(steps[-1])
        moved = np.linalg.norm(_centres(frames[-1], index) - _centres(frames[-2], index), axis=-1)
        still = still + 1 if np.all(moved < REST_SPEED / fps) else 0
        if n_frames is None and still >= settle:
            break
    _advance(step, substeps, data, steps, bool(effs))  # one frame more, for exposures past the last frame
    qpos = np.stack(frames)
    return Motion(qpos, _centres(qpos, index), rest_frames, fps, np.stack(steps), substeps, index.qpos)


def _physics_step(effects, values, model, data, index, ctx, k_surface):
    """A function doing one physics step: :func:`~galileo_jax.effects.runtime.c_step` with the
    effects' per-step hooks, else a plain ``mj_step`` (c_step without hooks)."""
    if has_step_hooks(effects):
        return lambda: c_step(effects, values, model, data, index, ctx, k_surface)
    return lambda: mujoco.mj_step(model, data)


def _advance(step, n: int, data: mujoco.MjData, out: list, effects: bool) -> None:
    """Do ``n`` physics steps, appending a copy of ``qpos`` after each to ``out``.

    Raises:
        GalileoError: the state became non-finite.
    """
    for _ in range(n):
        step()
        out.append(data.qpos.copy())
    if not np.all(np.isfinite(data.qpos)):
        raise GalileoError("the simulation diverged (non-finite state); check the masses"
                           + (", frictions and effect values" if effects else " and frictions"))


def _effect_vector(effects, params: PhysParams, effect_values) -> np.ndarray:
    """The flat (n_effect_params,) values of ``effects`` from ``effect_values`` / ``params.effects``."""
    names = effect_param_names(effects)
    if effect_values is None:
        effect_values = params.effects if params.effects is not None else neutral_values(effects)
    if isinstance(effect_values, Mapping):
        missing = [n for n in names if n not in effect_values]
        extra = sorted(set(effect_values) - set(names))
        if missing or extra:
            what = f"no value of {missing[0]}" if missing else f"unknown effect parameter {extra[0]!r}"
            raise GalileoError(f"effect values: {what}; the effects take {', '.join(names) or 'none'}")
        return np.asarray([float(effect_values[n]) for n in names], dtype=np.float64)
    values = np.asarray(effect_values, dtype=np.float64).reshape(-1)
    if values.shape != (len(names),):
        raise GalileoError(f"{values.size} effect values given but the effects take {len(names)} "
                           f"({', '.join(names) or 'none'})")
    return values


# --------------------------------------------------------------------------- rendering


def _renderer(model: mujoco.MjModel, view: render.View) -> mujoco.Renderer:
    try:
        return mujoco.Renderer(model, view.height, view.width)
    except Exception as err:  # noqa: BLE001 - any GL failure becomes one user-facing line
        backend = os.environ.get("MUJOCO_GL", "")
        raise GalileoError(f"cannot create an OpenGL context for rendering (MUJOCO_GL={backend}: "
                           f"{str(err).splitlines()[0] if str(err) else type(err).__name__}); install "
                           f"libegl1 libegl-mesa0 libopengl0 libgl1-mesa-dri, or set MUJOCO_GL=osmesa") from None


def render_frames(model: mujoco.MjModel, view: render.View, qpos: np.ndarray, hand_pos: np.ndarray | None = None,
                  hand_quat: np.ndarray | None = None, noise_sd: float = 0.0,
                  rng: np.random.Generator | None = None) -> Iterator[np.ndarray]:
    """Render frames of the front camera, optionally motion-blurred.

    Args:
        model: render model from :func:`galileo_jax.render.build_render_model`.
        view: its view (image size).
        qpos: (N, nq) generalised positions, one row per frame; or (N, S, nq), S sub-frames
            per frame whose renders are averaged (in float, before the noise and the rounding
            to 8 bits): motion blur (:func:`exposure_times`, :meth:`Motion.qpos_at`).
        hand_pos: (N, 3) or (N, S, 3) (as ``qpos``) hand mocap position in m, or None (no hand).
        hand_quat: (4,) hand orientation.
        noise_sd: SD of Gaussian pixel noise in grey levels (0..255), independent per pixel
            and channel.
        rng: noise generator.

    Yields:
        (H, W, 3) uint8 BGR frames.
    """
    rng = rng if rng is not None else np.random.default_rng(0)
    qpos = np.asarray(qpos)
    subs = qpos if qpos.ndim == 3 else qpos[:, None]
    hands = None if hand_pos is None else np.asarray(hand_pos).reshape(subs.shape[:2] + (3,))
    data = mujoco.MjData(model)
    renderer = _renderer(model, view)
    try:
        for k in range(subs.shape[0]):
            images = [_render_state(renderer, model, data, subs[k, j], None if hands is None else hands[k, j],
                                    hand_quat) for j in range(subs.shape[1])]
            rgb = images[0] if len(images) == 1 else np.mean(images, axis=0, dtype=np.float32)
            yield np.ascontiguousarray(_to_uint8(rgb, noise_sd, rng)[:, :, ::-1])
    finally:
        renderer.close()


def _render_state(renderer: mujoco.Renderer, model: mujoco.MjModel, data: mujoco.MjData, qpos: np.ndarray,
                  hand_pos: np.ndarray | None, hand_quat: np.ndarray | None) -> np.ndarray:
    """(H, W, 3) uint8 RGB render of the front camera at one state."""
    data.qpos[:] = qpos
    if hand_pos is not None:
        data.mocap_pos[0] = hand_pos
        data.mocap_quat[0] = hand_quat
    mujoco.mj_kinematics(model, data)
    mujoco.mj_camlight(model, data)
    renderer.update_scene(data, camera=render.CAMERA)
    return renderer.render()


def _to_uint8(rgb: np.ndarray, noise_sd: float, rng: np.random.Generator) -> np.ndarray:
    """An image (uint8 or float 0..255) plus Gaussian noise of SD ``noise_sd``, rounded to uint8."""
    if noise_sd > 0:
        noisy = rng.standard_normal(rgb.shape, dtype=np.float32)
        noisy *= np.float32(noise_sd)
        noisy += rgb
        rgb = noisy
    if rgb.dtype == np.uint8:
        return rgb
    return np.clip(np.rint(rgb, out=rgb), 0, 255, out=rgb).astype(np.uint8)


def _temp_path(path: Path) -> Path:
    """A new empty file beside ``path`` (same suffix), with the usual permissions (umask)."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix or ".tmp", dir=path.parent)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    return Path(tmp)


def _json_text(record: dict) -> str:
    """JSON with one top-level key per line and one frame per line for per-frame arrays."""
    lines = []
    for key, value in record.items():
        if isinstance(value, list) and value and isinstance(value[0], list):
            rows = ",\n  ".join(json.dumps(row) for row in value)
            lines.append(f" {json.dumps(key)}: [\n  {rows}\n ]")
        else:
            lines.append(f" {json.dumps(key)}: {json.dumps(value)}")
    return "{\n" + ",\n".join(lines) + "\n}\n"


def _atomic_write_text(path: Path, text: str) -> None:
    tmp = _temp_path(path)
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_video(path: Path, frames: Iterator[np.ndarray], fps: float, size: tuple[int, int], n_frames: int,
                progress: bool = True) -> float:
    """Write BGR frames to an mp4 (mp4v) atomically; returns the container's frame rate.

    Args:
        path: output ``.mp4``.
        frames: iterator of (H, W, 3) uint8 BGR frames.
        fps: frames per second.
        size: (width, height) in px.
        n_frames: number of frames (for the progress bar).
        progress: show a tqdm bar.
    """
    tmp = _temp_path(path)
    try:
        writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
        if not writer.isOpened():
            raise GalileoError(f"cannot write video {path} (OpenCV has no mp4v encoder?)")
        try:
            for frame in tqdm(frames, total=n_frames, desc=f"rendering {path.name}", unit="frame",
                              disable=not progress, leave=False):
                writer.write(frame)
        finally:
            writer.release()
        cap = cv2.VideoCapture(str(tmp))
        container_fps = float(cap.get(cv2.CAP_PROP_FPS))
        cap.release()
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return container_fps


# --------------------------------------------------------------------------- truth and files


def truth_record(scene: Scene, params: PhysParams, motion: Motion, view: render.View, *, noise_sd: float,
                 hand: bool, seed: int, video: str, effects=(), look: str = "checker", colours=None, blur: int = 0,
                 shutter: float = 0.5, backdrop: str = "plain", world: WorldPhysics | None = None) -> dict:
    """The ground-truth JSON record of a rendered video.

    Keys: ``video`` (file name), ``scene`` (scene name), ``m1, k1, m2, k2`` (those of the
    scene's objects; kg and dimensionless), ``phi`` = (m1 - m2) / (m1 + m2) (two objects),
    then, when effects were simulated, each effect parameter by its name (e.g.
    ``drag_quadratic``; units in the effect's :class:`~galileo_jax.effects.EffectParam`),
    ``effects`` ({effect name: {parameter: value}}: every simulated effect, the scene's own
    and the hidden ones; ``{}`` for the base model), ``hidden_effects`` (names of the
    simulated effects that the written scene file does not list), ``fps``, ``release_time``
    (s), ``release_frame``, ``n_frames``, ``width``, ``height`` (px), ``noise_sd`` (grey
    levels), ``hand``, ``seed``, ``substeps``, ``pixels_per_metre`` (in the plane of motion),
    ``foot_pixel`` ([u, v]), ``moved`` (per object, whether it moved more than 1 mm),
    ``pixels`` (N x n_objects x [u, v]: each object's centre projected into the image at the
    frame time, px), ``positions`` (N x n_objects x [x, z]: world x and vertical of each
    centre, m), ``look``, ``colours`` (n_objects x [r, g, b], 0..1: each object's base colour),
    ``camera`` ({``projection``, ``distance_m`` (null when orthographic), ``fovy_deg`` (null
    when orthographic), ``direction``}), ``blur`` (sub-frames per frame, 0: none), ``shutter``
    (exposure / frame interval), ``backdrop``, ``pixels_front`` (N x n_objects x [u, v]: the
    centre of each object's face toward the camera, offset from its centre by half its width
    (radius for cylinders and spheres) along the body's y axis, projected; equal to ``pixels``
    in orthographic views) and, when ``blur`` >= 2, ``pixels_exposure`` (N x n_objects x
    [u, v]: the mean over each frame's sub-frames of the projected centre, what the centroid
    of a blurred image sees), ``world`` ({``cone``, ``ramp_thickness`` (m)}: the physics the
    fitted model does not have, :class:`~galileo_jax.physics.model.WorldPhysics`).

    ``effects``: the simulated effects (names or Effects, the scene's own included), in the
    order of ``params.effects``. ``colours``: as :func:`galileo_jax.render.object_colours`.
    """
    effects = scene_effects(scene, effects)
    rec = {"video": video, "scene": scene.name}
    rec.update(param_dict(params))
    if scene.n_objects == 2:
        m1, m2 = (float(m) for m in params.mass)
        rec["phi"] = (m1 - m2) / (m1 + m2)
    by_effect = effect_value_dict(effects, params.effects) if effects else {}
    for values in by_effect.values():
        rec.update(values)
    rec["effects"] = by_effect
    rec["hidden_effects"] = [e.name for e in effects if e.name not in scene.effects]
    travel = np.linalg.norm(motion.positions - motion.positions[0], axis=-1).max(axis=0)
    centres = np.zeros((scene.n_objects, 3))
    rec.update({
        "fps": motion.fps, "release_time": motion.release_time, "release_frame": motion.release_frame,
        "n_frames": motion.n_frames, "width": view.width, "height": view.height, "noise_sd": noise_sd,
        "hand": hand, "seed": seed, "substeps": scene.simulation.substeps,
        "pixels_per_metre": view.scale, "foot_pixel": list(view.foot_pixel),
        "moved": [bool(d > 1e-3) for d in travel],
        "pixels": _pixels(view, motion.qpos, motion.qpos_adr, centres),
        "positions": np.round(motion.positions, 7).tolist(),
        "look": look, "colours": [list(c) for c in render.object_colours(scene, colours)],
        "camera": {"projection": view.projection, "distance_m": view.distance if view.perspective else None,
                   "fovy_deg": view.fovy if view.perspective else None, "direction": view.direction},
        "blur": blur, "shutter": shutter, "backdrop": backdrop,
        "world": dataclasses.asdict(world or WorldPhysics()),
        "pixels_front": _pixels(view, motion.qpos, motion.qpos_adr, render.front_offsets(scene, view)),
    })
    if blur >= 2:
        sub = motion.qpos_at(exposure_times(motion.n_frames, motion.fps, blur, shutter))
        rec["pixels_exposure"] = _pixels(view, sub, motion.qpos_adr, centres, mean_axis=1)
    return rec


def _pixels(view: render.View, qpos: np.ndarray, qpos_adr, local: np.ndarray, mean_axis: int | None = None) -> list:
    """Projected body points (:func:`galileo_jax.render.body_points`) in px, rounded to 1e-4 px,
    as nested lists; ``mean_axis``: average over that axis of ``qpos`` first (sub-frames)."""
    px = view.project(render.body_points(qpos, qpos_adr, local))
    if mean_axis is not None:
        px = px.mean(axis=mean_axis)
    return np.round(px, 4).tolist()


def calibrated_scene(scene: Scene, view: render.View, container_fps: float, fps: float) -> Scene:
    """The scene with the exact camera calibration; ``video`` holds only ``fps``, and only when
    the container's frame rate differs from ``fps`` (an input ``video`` block described another
    video and is dropped)."""
    video = Video() if math.isclose(container_fps, fps, rel_tol=1e-4) else Video(fps=fps)
    return scene.model_copy(update={"camera": view.camera_block(), "video": video})


def _check_options(fps: float, duration: float | None, width: int, height: int, noise_sd: float,
                   rest_frames: int) -> None:
    if not (math.isfinite(fps) and 1 <= fps <= 1000):
        raise GalileoError(f"--fps {fps}: give a frame rate in [1, 1000] frames per second")
    if not (16 <= width <= 4096 and 16 <= height <= 4096 and width % 2 == 0 and height % 2 == 0):
        raise GalileoError(f"image size {width}x{height}: give even sizes in [16, 4096] px")
    if not (math.isfinite(noise_sd) and 0 <= noise_sd <= 100):
        raise GalileoError(f"--noise {noise_sd}: give a pixel noise SD in [0, 100] grey levels")
    if rest_frames < 1:
        raise GalileoError(f"rest_frames = {rest_frames}: need at least one frame before release")
    if duration is not None:
        if not (math.isfinite(duration) and 0 < duration <= 120):
            raise GalileoError(f"--duration {duration}: give a length in (0, 120] s")
        if int(round(duration * fps)) < rest_frames + 2:
            raise GalileoError(f"--duration {duration} s leaves no frames after the release at "
                               f"{rest_frames / fps:.3g} s; make it longer")


def _check_style(scene: Scene, look: str, colours, camera: str, camera_distance: float, direction: str, blur: int,
                 shutter: float, backdrop: str) -> None:
    """Check :func:`render_video`'s look, camera and blur options (one-line :class:`GalileoError`)."""
    render.check_choice(look, render.LOOKS, "look", "--look")
    render.check_choice(backdrop, render.BACKDROPS, "backdrop", "--backdrop")
    render.object_colours(scene, colours)
    render.check_camera(scene, camera, camera_distance, direction)
    if isinstance(blur, bool) or not isinstance(blur, (int, np.integer)) or not 0 <= blur <= MAX_BLUR:
        raise GalileoError(f"--blur {blur}: give 0 (no motion blur) or a whole number of sub-frames per frame "
                           f"in [2, {MAX_BLUR}]")
    if not (math.isfinite(shutter) and 0 < shutter <= 1):
        raise GalileoError(f"--shutter {shutter}: give the exposure as a fraction of the frame interval in (0, 1]")


def render_video(scene: Scene, params, out_path, *, fps: float = 30.0, duration: float | None = None,
                 width: int = 640, height: int = 360, noise_sd: float = 2.0, hand: bool = False,
                 rest_frames: int | None = None, seed: int = 0, progress: bool = True, effects=None,
                 look: str = "checker", colours=None, camera: str = "orthographic",
                 camera_distance: float = render.CAMERA_DISTANCE, direction: str = "right", blur: int = 0,
                 shutter: float = 0.5, backdrop: str = "plain", world: WorldPhysics | None = None) -> dict:
    """Simulate and render one ramp video with its calibrated scene file and ground truth.

    Args:
        scene: the scene (start positions, shapes; its camera block is replaced).
        params: ``{"m1", "k1", "m2", "k2"}`` plus the value of every effect parameter by name
            (e.g. ``"drag_quadratic"``), or :class:`PhysParams` (see :func:`resolve_params`).
        out_path: the ``.mp4`` to write; ``<stem>.yaml`` and ``<stem>.truth.json`` go beside it.
        fps: frames per second.
        duration: video length in s (rest frames included); ``None``: until all objects have
            rested for 0.5 s, at most 4 s.
        width, height: image size in px (even).
        noise_sd: SD of Gaussian pixel noise in grey levels.
        hand: show a hand holding object 1 until the release, then leaving the frame.
        rest_frames: frames at rest before release (default ``round(0.3 * fps)``).
        seed: seed of the pixel noise and of the cluttered backdrop.
        progress: show a progress bar.
        effects: hidden effects (names or :class:`~galileo_jax.effects.Effect`), simulated
            and drawn on top of the scene's own ``scene.effects``. They go into the truth
            (``effects``, ``hidden_effects`` and each parameter at top level), not into the
            written scene file, which describes only the setup (it keeps the scene's own
            ``effects``).
        look: ``"checker"`` (textured objects) or ``"plain"`` (one flat colour each).
        colours: (n_objects, 3) base RGB of the objects in [0, 1]; None: the scene's ``rgba``,
            else red and blue.
        camera: ``"orthographic"`` or ``"perspective"`` (a pinhole ``camera_distance`` m from the
            plane of motion whose scale there is the written ``pixels_per_metre``; nearer
            surfaces look larger). See :mod:`galileo_jax.render`.
        camera_distance: perspective camera's distance from the plane of motion in m.
        direction: ``"right"`` or ``"left"``: the image direction object 1 moves in (left: the
            scene seen from its other side; the scene file says ``ramp_direction: left``).
        blur: motion blur: render this many sub-frames per frame (>= 2) at
            :func:`exposure_times` (the state interpolated between physics steps,
            :meth:`Motion.qpos_at`) and average them; 0 (or 1): none.
        shutter: exposure time as a fraction of the frame interval (with ``blur``).
        backdrop: ``"plain"`` (grey wall) or ``"clutter"`` (posters, shelves, cables, blobs).
        world: physics the fitted model does not have (:class:`~galileo_jax.physics.model.WorldPhysics`:
            elliptic friction cones, a ramp board of some thickness with an edge at its foot),
            simulated and drawn; the written scene file does not know of it. ``None``: the
            model's own physics.

    Returns:
        The truth record (as written to ``<stem>.truth.json``; see :func:`truth_record`).

    Raises:
        GalileoError: bad parameters, effects or options, or rendering is unavailable.
    """
    out_path = Path(out_path)
    if out_path.suffix.lower() != ".mp4":
        raise GalileoError(f"output {out_path} must end in .mp4")
    if not out_path.parent.is_dir():
        raise GalileoError(f"output folder {out_path.parent} does not exist; create it first")
    rest_frames = max(1, int(round(REST_SECONDS * fps))) if rest_frames is None else int(rest_frames)
    _check_options(fps, duration, width, height, noise_sd, rest_frames)
    _check_style(scene, look, colours, camera, camera_distance, direction, blur, shutter, backdrop)
    effs = scene_effects(scene, effects or ())
    check_applicable(effs, scene)
    phys = resolve_params(scene, params, effs)
    n_frames = None if duration is None else int(round(duration * fps))
    motion = simulate_motion(scene, phys, fps, rest_frames, n_frames, effects=effs, world=world)
    if hand and n_frames is None:  # let the hand leave the frame before the video ends
        min_frames = rest_frames + int(math.ceil((render.HAND_EXIT_TIME + 0.1) * fps))
        if motion.n_frames < min_frames:
            motion = simulate_motion(scene, phys, fps, rest_frames, min_frames, effects=effs, world=world)
    view = render.frame_view(scene, motion.positions, width, height, projection=camera, distance=camera_distance,
                             direction=direction)
    model = render.build_render_model(scene, view, physics_timestep(fps, scene.simulation.substeps), hand=hand,
                                      effects=effs, look=look, colours=colours, backdrop=backdrop, seed=seed,
                                      world=world)
    times = exposure_times(motion.n_frames, fps, blur, shutter)
    hand_pos = hand_quat = None
    if hand:
        hand_quat = render.hand_rest_pose(scene)[1]
        hand_pos = np.array([[render.hand_position(scene, view, t, motion.release_time) for t in row] for row in times])
    frames = render_frames(model, view, motion.qpos_at(times), hand_pos, hand_quat, noise_sd,
                           np.random.default_rng(seed))
    container_fps = write_video(out_path, frames, fps, (width, height), motion.n_frames, progress)
    truth = truth_record(scene, phys, motion, view, noise_sd=noise_sd, hand=hand, seed=seed, video=out_path.name,
                         effects=effs, look=look, colours=colours, blur=blur, shutter=shutter, backdrop=backdrop,
                         world=world)
    yaml_path = out_path.with_suffix(".yaml")
    tmp = _temp_path(yaml_path)
    try:
        save_scene(calibrated_scene(scene, view, container_fps, fps), tmp)
        os.replace(tmp, yaml_path)
    finally:
        tmp.unlink(missing_ok=True)
    _atomic_write_text(out_path.with_suffix(".truth.json"), _json_text(truth))
    return truth


# --------------------------------------------------------------------------- CLI


def _parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="python -m galileo_jax.synth",
                description="Render a synthetic ramp video (mp4) with its calibrated scene (.yaml) and "
                            "ground truth (.truth.json).")
    p.add_argument("--scene", required=True, help="scene YAML file (e.g. scenes/ramp_20.yaml)")
    for name, what in (("m1", "mass of object 1 (kg)"), ("k1", "friction coefficient of object 1"),
                       ("m2", "mass of object 2 (kg)"), ("k2", "friction coefficient of object 2")):
        p.add_argument(f"--{name}", type=float, help=what)
    p.add_argument("--out", required=True, help="output .mp4 file, or a folder (created if missing)")
    p.add_argument("--fps", type=float, default=30.0, help="frames per second (default 30)")
    p.add_argument("--duration", type=float, help="video length in s (default: until at rest, at most 4 s)")
    p.add_argument("--noise", type=float, default=2.0, help="pixel noise SD in grey levels (default 2)")
    p.add_argument("--hand", action="store_true", help="show a hand holding object 1 until the release")
    p.add_argument("--seed", type=int, default=0, help="seed of the noise and of --random draws")
    p.add_argument("--random", type=int, metavar="N", help="render N videos with random free parameters "
                   "(k1 < tan(theta) - 0.05 so object 1 slides); given --m1 etc. are kept fixed")
    p.add_argument("--effect", action="append", metavar="NAME[=VALUE]",
                   help="simulate a hidden physical effect (repeatable): NAME=VALUE sets its parameter "
                        "(NAME=V1,V2 for several, in order), NAME alone with --random draws it uniformly from the "
                        "parameter's synth range, 'none' means no effect. The effect goes into the truth, not the "
                        "written scene file. With --random and effects, draws are redone (at most 20 times) "
                        "until object 1's friction on the ramp after the effects (k1 + dk_ramp) is below "
                        "tan(theta) - 0.05 and the simulated object 1 reaches object 2 (one object: the floor) "
                        f"within the video. Effects: {', '.join(sorted(available_effects()))}")
    p.add_argument("--width", type=int, default=640, help="image width in px (default 640)")
    p.add_argument("--height", type=int, default=360, help="image height in px (default 360)")
    p.add_argument("--rest", type=float, default=REST_SECONDS, help="seconds held at rest before release (default 0.3)")
    p.add_argument("--look", choices=render.LOOKS, default="checker",
                   help="objects: checker texture (default) or one plain colour")
    p.add_argument("--colour", action="append", type=_colour, metavar="R,G,B",
                   help="base colour of an object, components in [0, 1] (repeatable: once per object, in order; "
                        "default: the scene's rgba, else red and blue)")
    p.add_argument("--camera", choices=render.PROJECTIONS, default="orthographic",
                   help="orthographic (default: exact scale at any depth) or perspective (a pinhole --distance m "
                        "from the plane of motion, exact scale in that plane)")
    p.add_argument("--distance", type=float, default=render.CAMERA_DISTANCE,
                   help=f"perspective camera's distance from the plane of motion in m "
                        f"(default {render.CAMERA_DISTANCE})")
    p.add_argument("--direction", choices=render.DIRECTIONS,
                   help="image direction object 1 moves in: right (default) or left (the scene seen from behind)")
    p.add_argument("--left", action="store_true", help="same as --direction left")
    p.add_argument("--blur", type=int, default=0, metavar="N",
                   help="motion blur: average N >= 2 sub-frames per frame over the --shutter (default 0: none)")
    p.add_argument("--shutter", type=float, default=0.5,
                   help="exposure as a fraction of the frame interval, in (0, 1] (default 0.5; with --blur)")
    p.add_argument("--backdrop", choices=render.BACKDROPS, default="plain",
                   help="backdrop wall: plain grey (default) or clutter (posters, shelves, cables, blobs)")
    p.add_argument("--cone", choices=("pyramidal", "elliptic"), default="pyramidal",
                   help="friction cone of the simulated contacts: pyramidal (default, the fitted model's) or "
                        "elliptic (physics the model does not have, for testing on videos it cannot reproduce)")
    p.add_argument("--ramp-thickness", type=float, default=0.0, metavar="M",
                   help="simulate the ramp as a board this thick (m) whose foot edge rests on the floor, so objects "
                        "drop over an edge onto the floor; the written scene file does not know of it (default 0: "
                        "the fitted model's ramp plane)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def _colour(text: str) -> tuple[float, ...]:
    """argparse type of ``--colour R,G,B``: three numbers (their range is checked by render_video)."""
    try:
        rgb = tuple(float(t) for t in text.split(","))
    except ValueError:
        rgb = ()
    if len(rgb) != 3:
        raise argparse.ArgumentTypeError(f"{text!r} is not R,G,B (three numbers in [0, 1], e.g. 0.2,0.5,0.9)")
    return rgb


def _direction(args: argparse.Namespace) -> str:
    """The image direction from ``--direction`` and ``--left``.

    Raises:
        GalileoError: ``--left`` with ``--direction right``.
    """
    if args.left and args.direction == "right":
        raise GalileoError("--left contradicts --direction right; give one of them")
    return "left" if args.left else args.direction or "right"


def _outputs(out: str, stem: str, count: int, random: bool) -> list[Path]:
    path = Path(out)
    if path.suffix.lower() == ".mp4":
        if random:
            raise GalileoError(f"--random needs --out to be a folder, not {out}")
        if path.parent.exists() and not path.parent.is_dir():
            raise GalileoError(f"--out {out}: {path.parent} is a file, not a folder")
        path.parent.mkdir(parents=True, exist_ok=True)
        return [path]
    if path.exists() and not path.is_dir():
        raise GalileoError(f"--out {out} is a file; give a folder or a .mp4 path")
    path.mkdir(parents=True, exist_ok=True)
    if not random:
        return [path / f"{stem}.mp4"]
    return [path / f"{stem}_{i:03d}.mp4" for i in range(count)]


def parse_effect_options(items, random: bool) -> tuple[list[str], dict[str, float]]:
    """Parse ``--effect`` options into (effect names in order, {parameter: value}).

    ``NAME=VALUE`` (``NAME=V1,V2`` for an effect with several parameters, in their order) fixes
    the values; ``NAME`` alone is allowed for an effect without parameters, or with ``random``
    (its values are drawn); ``none`` means no effect.

    Raises:
        GalileoError: an unknown effect, a missing or malformed value, a repeated effect, or
            ``none`` given with other effects.
    """
    names: list[str] = []
    values: dict[str, float] = {}
    items = list(items or [])
    if any(i.strip().lower() == "none" for i in items):
        if len(items) > 1:
            raise GalileoError("--effect none means no effect; do not combine it with other --effect options")
        return [], {}
    for item in items:
        name, sep, text = item.partition("=")
        name = name.strip()
        effect = get_effect(name)
        if effect.name in names:
            raise GalileoError(f"--effect {effect.name} is given twice; give each effect once")
        names.append(effect.name)
        if not sep:
            if effect.params and not random:
                p = effect.params[0]
                raise GalileoError(f"--effect {name} needs a value: --effect {name}=VALUE ({p.name}, {p.doc or p.unit}; "
                                   f"e.g. {p.synth_range[0]:g} to {p.synth_range[1]:g}), or use --random to draw it")
            continue
        if not effect.params:
            raise GalileoError(f"--effect {item}: effect {name} has no parameter; give --effect {name} alone")
        parts = [t.strip() for t in text.split(",")]
        if len(parts) != len(effect.params):
            raise GalileoError(f"--effect {item}: {name} takes {len(effect.params)} value(s) "
                               f"({', '.join(effect.param_names)}), got {len(parts)}")
        for p, t in zip(effect.params, parts):
            try:
                values[p.name] = float(t)
            except ValueError:
                raise GalileoError(f"--effect {item}: {t!r} is not a number") from None
    return names, values


@cli_entry
def main(argv: list[str] | None = None) -> int:
    """Command-line entry point (``python -m galileo_jax.synth``); returns the exit code."""
    args = _parser().parse_args(argv)
    scene = load_scene(args.scene)
    given = {k: getattr(args, k) for k in ("m1", "k1", "m2", "k2") if getattr(args, k) is not None}
    extra = [k for k in given if int(k[1]) > scene.n_objects]
    if extra:
        raise SceneError(f"--{extra[0]} given but scene {args.scene} has {scene.n_objects} object(s)")
    if args.random is not None and not 1 <= args.random <= 10000:
        raise GalileoError(f"--random {args.random}: give a count in [1, 10000]")
    if not math.isfinite(args.rest) or args.rest <= 0:
        raise GalileoError(f"--rest {args.rest}: give a positive time in s")
    effect_names, effect_values = parse_effect_options(args.effect, args.random is not None)
    effs = scene_effects(scene, effect_names)
    check_applicable(effs, scene)
    if args.random is None:  # every effect parameter needs a value (also those of the scene's own effects)
        missing = [(e, p) for e in effs for p in e.params if p.name not in effect_values]
        if missing:
            e, p = missing[0]
            raise GalileoError(f"effect {e.name!r} needs a value of {p.name}: give --effect {e.name}=VALUE "
                               f"(e.g. {p.synth_range[0]:g} to {p.synth_range[1]:g}) or use --random")
    count = args.random or 1
    paths = _outputs(args.out, scene.name.replace(" ", "_"), count, args.random is not None)
    rng = np.random.default_rng(args.seed)
    rest_frames = max(1, int(round(args.rest * args.fps)))
    n_frames = None if args.duration is None else int(round(args.duration * args.fps))
    names = ["m1", "k1", "m2", "k2"] + list(effect_param_names(effs))
    style = dict(look=args.look, colours=args.colour, camera=args.camera, camera_distance=args.distance,
                 direction=_direction(args), blur=args.blur, shutter=args.shutter, backdrop=args.backdrop)
    _check_style(scene, **style)
    try:
        world = WorldPhysics(cone=args.cone, ramp_thickness=args.ramp_thickness)
    except ValueError as err:
        raise GalileoError(f"{err} (--cone, --ramp-thickness)") from None
    if args.random and effs:  # the draws simulate the video: check its options first
        _check_options(args.fps, args.duration, args.width, args.height, args.noise, rest_frames)
    for i, path in enumerate(paths):
        if args.random and effs:
            params = draw_informative_params(scene, rng, effect_names, fps=args.fps, rest_frames=rest_frames,
                                             n_frames=n_frames, fixed=given, fixed_effects=effect_values)
        elif args.random:
            params = draw_random_params(scene, rng, fixed=given)
        else:
            params = {**given, **effect_values}
        truth = render_video(scene, params, path, fps=args.fps, duration=args.duration, width=args.width,
                             height=args.height, noise_sd=args.noise, hand=args.hand,
                             rest_frames=rest_frames, seed=args.seed + i,
                             progress=not args.quiet, effects=effect_names, world=world, **style)
        values = ", ".join(f"{k}={truth[k]:.4g}" for k in names if k in truth)
        hidden = f" (hidden: {', '.join(truth['hidden_effects'])})" if truth["hidden_effects"] else ""
        print(f"{path}: {truth['n_frames']} frames at {truth['fps']:g} fps, {values}{hidden}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
