"""The synthetic video's physics: the scene simulated in C MuJoCo, step by step, with the
hidden effects' hooks (:func:`simulate_motion` -> :class:`Motion`), and the frame and exposure
times it is sampled at (:func:`exposure_times`). Package docstring: the timeline.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import NamedTuple

import mujoco
import numpy as np

from galileo_jax.effects import check_applicable
from galileo_jax.effects.runtime import (
    apply_c_model,
    c_step,
    effect_param_names,
    has_step_hooks,
    make_context,
    neutral_values,
    surface_frictions,
)
from galileo_jax.errors import GalileoError
from galileo_jax.physics.model import ModelIndex, WorldPhysics, build_model, set_physics
from galileo_jax.physics.simulate import PhysParams, physics_timestep, scene_effects
from galileo_jax.scene import Scene

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
