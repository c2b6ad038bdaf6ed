"""The simulator: physical parameters -> trajectories and velocity profiles, in pure JAX.

MuJoCo-MJX ``step`` runs under ``lax.scan``; everything is ``jit``-able and ``vmap``-able over
parameters. A rollout records each object's centre (world x, z in m) and pitch (rad, about
the world y axis) after every physics step; velocity profiles are then sampled at the video's
frame times by linear interpolation, so any frame rate (29.97 fps included) and any sub-frame
release time work with one physics timestep.

Velocity profile (dissertation 4.2.3, the seed's V(k)): for frame times t_0..t_N,
``V[k] = (p(t_{k+1}) - p(t_k)) / (t_{k+1} - t_k)``, k = 0..N-1, for each object's x and
vertical coordinate: shape (2 * n_objects, N) in m/s, rows (object 1 x, object 1 y,
object 2 x, object 2 y). Comparing 30 Hz position differences, not ``qvel``, avoids the
contact chatter of sliding boxes (0.04 m/s RMS in instantaneous velocity at dt = 1/240 s).

Masses: MJX takes ``body_mass`` as given, but contact softness depends on
``body_invweight0`` / ``dof_invweight0`` computed at compile time. :func:`apply_params`
rescales them with the mass (as ``mj_setConst`` does in C), which makes the dynamics
depend on the masses only through their ratio (tested in ``tests/test_physics.py``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
from dataclasses import dataclass, field
from functools import cached_property
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

# mujoco-mjx prints "Failed to import warp" when its optional Warp backend is absent; we use
# the JAX backend, so keep that line off the user's screen.
with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx

from galileo_jax.effects import BodyState, EffectContext, check_applicable, resolve_effects
from galileo_jax.effects.runtime import (effect_param_names, forces, frictions, has_step_hooks, initial_velocity,
                                         make_context, model_updates, neutral_values, split_values,
                                         surface_frictions)
from galileo_jax.physics import simulate_c
from galileo_jax.errors import GalileoError
from galileo_jax.physics.model import NOMINAL_FRICTION, NOMINAL_MASS, ModelIndex, build_model, object_poses
from galileo_jax.scene import Scene


class PhysParams(NamedTuple):
    """Physical parameters of the objects (a pytree; batch by giving leading axes).

    Attributes:
        mass: (..., n_objects) masses in kg.
        friction: (..., n_objects) sliding friction coefficients (dimensionless).
        effects: (..., n_effect_params) parameters of the simulator's effects, in the order of
            ``Simulator.effect_names`` (None: the neutral values, i.e. the base model).
    """

    mass: jax.Array
    friction: jax.Array
    effects: jax.Array | None = None


class SimArrays(NamedTuple):
    """The numbers of a scene's simulator, passed to compiled programs as data (a pytree).

    Two scenes of one structure (same objects, shapes and contact pairs; another ramp angle,
    ramp length, start position, object size or board thickness) have arrays of the same
    shapes, so one compiled program serves both: :meth:`Simulator.with_arrays` puts these
    (traced) arrays into the program's simulator. See :func:`structure_key`.

    Attributes:
        model: the MJX model (every array of it: geometry, masses, frictions, timestep).
        data0: the MJX data at rest at the start positions (forwarded on the MJX engine only).
        base: the objects' compile-time mass, inertia and inverse weights (``Simulator.base``).
        ramp_angle: () ramp angle in rad (:class:`~galileo_jax.effects.EffectContext`).
        gravity: () g in m/s^2.
        downhill: (3,) unit vector down the slope, world frame.
    """

    model: mjx.Model
    data0: mjx.Data
    base: dict
    ramp_angle: jax.Array
    gravity: jax.Array
    downhill: jax.Array


class Trajectory(NamedTuple):
    """A rollout sampled at every physics step.

    Attributes:
        pose: (n_steps + 1, n_objects, 3): centre x (m), centre z (m), pitch about y (rad).
        dt: physics timestep in s (a Python float, static).
    """

    pose: jax.Array
    dt: float


@dataclass(frozen=True, eq=False)
class Simulator:
    """A compiled scene ready to simulate (static configuration plus MJX model and data).

    Build with :func:`make_simulator`; use the pure functions :func:`rollout`,
    :func:`sample_positions` and :func:`velocity_profile`.
    """

    scene: Scene
    mj_model: mujoco.MjModel
    model: mjx.Model
    data0: mjx.Data
    index: ModelIndex
    dt: float
    base: dict = field(repr=False)
    effects: tuple = ()
    ctx: EffectContext | None = None
    engine: str = "mjx"
    ensemble: int = 1

    @cached_property
    def arrays(self) -> SimArrays:
        """This scene's numbers as a :class:`SimArrays` pytree (pass it into jitted functions)."""
        ctx = self.ctx
        return SimArrays(self.model, self.data0, {k: jnp.asarray(v) for k, v in self.base.items()},
                         jnp.asarray(ctx.ramp_angle, jnp.float64), jnp.asarray(ctx.gravity, jnp.float64),
                         jnp.asarray(ctx.downhill, jnp.float64))

    def with_arrays(self, arrays: SimArrays) -> "Simulator":
        """This simulator with the numbers ``arrays`` (traced inside a jitted function) in place
        of its own: the simulator of another scene of the same :func:`structure_key`."""
        ctx = dataclasses.replace(self.ctx, ramp_angle=arrays.ramp_angle, gravity=arrays.gravity,
                                  downhill=arrays.downhill)
        return dataclasses.replace(self, model=arrays.model, data0=arrays.data0, base=arrays.base, ctx=ctx)

    @property
    def effect_names(self) -> tuple[str, ...]:
        """Names of the effect parameters (layout of ``PhysParams.effects``)."""
        return effect_param_names(self.effects)

    @property
    def n_objects(self) -> int:
        return self.scene.n_objects

    def default_params(self) -> PhysParams:
        """Known values from the scene, nominal values for free ones."""
        m = [o.mass if o.mass is not None else NOMINAL_MASS for o in self.scene.objects]
        k = [o.friction if o.friction is not None else NOMINAL_FRICTION for o in self.scene.objects]
        return PhysParams(jnp.asarray(m), jnp.asarray(k))


def physics_timestep(fps: float, substeps: int) -> float:
    """Physics timestep (s) for ``substeps`` steps per video frame: 1 / (fps * substeps).

    At 29.97 fps and 8 substeps this is 1/239.76 s, the seed's 1/240 s aligned to frames.
    """
    return 1.0 / (fps * substeps)


_forward = jax.jit(mjx.forward)

#: ``mjx.step`` as a jitted function of its own. Every program that rolls out MJX (a batched
#: log-likelihood, an LM solve, a Jacobian, at each batch size) traces the step again; called
#: through ``jit``, its traced (and vmapped) form is cached, so a program whose step is batched
#: as an earlier one's reuses it. Measured on ``ramp_20``: a new vmapped rollout program of the
#: same batch size traced in 0.05 s instead of 1.7-2.1 s, of another batch size in 1.35-1.4 s
#: instead of 2.05 s, the same poses to the last bit; ``diagnose`` of a calibration video, warm
#: cache, 574 -> 457 s (``docs/simulation.md``). XLA may round the fits' programs differently
#: (the step is a call inside them), so MJX estimates can move within the likelihood's roughness.
_step = jax.jit(mjx.step)


def make_simulator(scene: Scene, fps: float, effects=(), engine: str = "mjx", ensemble: int = 1) -> Simulator:
    """Build the MuJoCo model of ``scene`` (with ``effects``) and move it to MJX.

    Args:
        scene: validated scene.
        fps: video frame rate in frames per second (sets the physics timestep).
        effects: :class:`~galileo_jax.effects.Effect` objects to simulate (the scene's own
            ``effects`` are NOT added here; see :func:`scene_effects`).
        engine: "mjx" (rollouts in JAX, differentiable) or "mujoco" (C MuJoCo's batched
            ``mujoco.rollout`` through a host callback: :mod:`galileo_jax.physics.simulate_c`).
        ensemble: rollouts averaged per parameter set (>= 1; :func:`ensemble_offsets`): 1 is
            one plain rollout.

    Returns:
        A :class:`Simulator`.

    Raises:
        GalileoError: an effect does not apply to the scene, an unknown engine, or an effect
            the C engine cannot simulate.
    """
    effects = tuple(effects)
    check_applicable(effects, scene)
    if engine not in simulate_c.ENGINES:
        raise GalileoError(f"unknown engine {engine!r}; choose one of {', '.join(simulate_c.ENGINES)}")
    if engine == "mujoco":
        simulate_c.check_supported(effects)
    dt = physics_timestep(fps, scene.simulation.substeps)
    mj_model, index = build_model(scene, timestep=dt, effects=effects, engine=engine)
    model = _shareable(mj_model, mjx.put_model(mj_model))
    data0 = mjx.make_data(model)
    if engine == "mjx":
        # Run forward once: gives consistent dtypes for the contact fields under scan (float64)
        # and fills derived quantities (one jitted function: compiled once per scene structure).
        # The C engine starts from the MjModel's own state and never reads data0: tracing MJX's
        # forward cost a CPU fit 4.6 s per process.
        data0 = _forward(model, data0)
    bodies = np.asarray(index.body)
    base = {
        "body_mass": np.asarray(mj_model.body_mass[bodies]),
        "body_inertia": np.asarray(mj_model.body_inertia[bodies]),
        "body_invweight0": np.asarray(mj_model.body_invweight0[bodies]),
        "dof_invweight0": np.stack([mj_model.dof_invweight0[d:d + 6] for d in index.dof]),
    }
    if int(ensemble) < 1:
        raise GalileoError(f"the rollout ensemble needs at least 1 member, got {ensemble}")
    return Simulator(scene, mj_model, model, data0, index, dt, base, effects, make_context(scene, index, dt), engine,
                     int(ensemble))


#: Speed (m/s) at which object 1's start offsets of the rollout ensemble (:func:`ensemble_offsets`)
#: span one physics step of travel: about the speed at which it reaches a collision on the
#: ramp scenes (1-3 m/s).
ENSEMBLE_SPEED = 2.0


def ensemble_offsets(sim: Simulator) -> jax.Array:
    """(K, n_objects, 3) start-position shifts (m) of the rollout ensemble (K = ``sim.ensemble``):
    object 1 moved along its path (down the ramp; along the floor where it starts there) by K
    offsets spread evenly and symmetrically over ``ENSEMBLE_SPEED * dt`` (one physics step of
    travel at that speed: 8.3 mm at 1/240 s), the other objects not at all.

    Why: where a simulated contact event (the impact, the foot of the ramp) begins inside a
    physics step depends on the parameters, so the simulated profile responds pseudo-randomly
    to small parameter changes (``galileo_jax/likelihood.py``, "Choice of default"). Shifting
    the start by a fraction of a step's travel moves the events through the step; the mean
    trajectory over the shifts is a smooth function of the parameters, the simulator's
    average over that phase. Measured on held-out world_41 (``docs/measurements.md``): with 8
    shifts the log-likelihood's roughness along k2 and phi fell from 4.3 and 2.9 nats to 1.1
    and 1.1, and every 90% interval of the grad fit held the truth (2 of 3 before)."""
    K = int(sim.ensemble)
    ctx = sim.ctx
    if ctx.on_ramp[0]:
        d = jnp.asarray(ctx.downhill, jnp.float64)
    else:
        d = jnp.array([jnp.sign(jnp.asarray(ctx.downhill, jnp.float64)[0]), 0.0, 0.0])
    along = (jnp.arange(K, dtype=jnp.float64) - (K - 1) / 2) / K * ENSEMBLE_SPEED * sim.dt
    return jnp.zeros((K, sim.n_objects, 3), jnp.float64).at[:, 0].set(along[:, None] * d[None])


def _shareable(mj_model: mujoco.MjModel, model: mjx.Model) -> mjx.Model:
    """The MJX model with the one size-dependent static field our scenes do not use made constant.

    MJX keeps ``geom_rbound_hfield`` (bounding radii, read only to collide with a height
    field) as static metadata of the model's pytree, so two scenes whose objects differ in size
    would have different pytree structures and never share a compiled program. Our scenes have
    no height field; the field is set to zeros there.
    """
    if mj_model.nhfield:
        return model
    impl = model._impl
    rbound = np.asarray(impl.geom_rbound_hfield)
    return model.replace(_impl=impl.replace(geom_rbound_hfield=np.zeros_like(rbound)))


def structure_key(sim: Simulator) -> tuple:
    """What a compiled program of ``sim`` depends on besides :attr:`Simulator.arrays`.

    Equal keys: the programs of one simulator serve the other with its own arrays
    (:meth:`Simulator.with_arrays`). The key holds the pytree structures of the MJX model and
    data (MJX keeps geom types, body tree and contact pairs there as static metadata), the
    object index, the effects' static context, the timestep and the engine. (The C MuJoCo
    engine reads the ``MjModel`` itself on the host; its problems are keyed by the scene:
    :func:`~galileo_jax.inference.problem.get_engine`.)
    """
    # every field of the effects' context but the numbers SimArrays carries into the program
    static_ctx = tuple(getattr(sim.ctx, f.name) for f in dataclasses.fields(sim.ctx) if f.name not in SimArrays._fields)
    structure = jax.tree_util.tree_structure((sim.model, sim.data0, sim.arrays.base))
    return ("structure", structure, sim.index, static_ctx, sim.effects, sim.dt, sim.engine)


def scene_effects(scene: Scene, extra=()) -> tuple:
    """The scene's own effects (``scene.effects``) followed by ``extra`` (names or Effects), de-duplicated.

    Raises:
        GalileoError: an unknown effect name.
    """
    return resolve_effects(list(scene.effects) + list(resolve_effects(extra)))


def apply_params(sim: Simulator, params: PhysParams) -> mjx.Model:
    """Return the MJX model with the objects' masses and friction coefficients set.

    Mass m_i rescales ``body_mass``, ``body_inertia`` (x m/m0), ``body_invweight0`` and
    ``dof_invweight0`` (x m0/m), as ``mj_setConst`` would. Friction k_i is written into both
    sliding columns of ``pair_friction`` of every pair object i has with the ramp and floor.

    Args:
        sim: the simulator.
        params: unbatched :class:`PhysParams` (shapes (n_objects,)).
    """
    m = sim.model
    bodies = np.asarray(sim.index.body)
    scale = params.mass / jnp.asarray(sim.base["body_mass"])
    body_mass = m.body_mass.at[bodies].set(params.mass)
    body_inertia = m.body_inertia.at[bodies].set(sim.base["body_inertia"] * scale[:, None])
    body_invweight0 = m.body_invweight0.at[bodies].set(sim.base["body_invweight0"] / scale[:, None])
    dof_invweight0 = m.dof_invweight0
    pair_friction = m.pair_friction
    for i in range(sim.n_objects):
        d = sim.index.dof[i]
        dof_invweight0 = dof_invweight0.at[d:d + 6].set(sim.base["dof_invweight0"][i] / scale[i])
        for pid in sim.index.pairs[i]:
            pair_friction = pair_friction.at[pid, 0:2].set(params.friction[i])
    return m.replace(body_mass=body_mass, body_inertia=body_inertia, body_invweight0=body_invweight0,
                     dof_invweight0=dof_invweight0, pair_friction=pair_friction)


def _pose(sim: Simulator, qpos: jax.Array) -> jax.Array:
    """(n_objects, 3) centre x, z (m) and pitch about y (rad) from ``qpos`` (:func:`~galileo_jax.physics.model.object_poses`)."""
    return object_poses(sim.index, qpos, jnp)


def rollout(sim: Simulator, params: PhysParams, n_steps: int, live_steps: jax.Array | None = None) -> Trajectory:
    """Simulate ``n_steps`` physics steps from rest at the scene's start positions.

    Pure and jittable for fixed ``n_steps``; ``vmap`` over ``params`` for a batch. The
    simulator's effects act as their hooks say (:mod:`galileo_jax.effects`): model fields
    once, release velocities at t = 0, frictions and forces (``xfrc_applied``) every step.
    On the C engine (``sim.engine == "mujoco"``) the rollout is a host callback
    (:func:`galileo_jax.physics.simulate_c.rollout_poses`): jittable and vmappable (a vmapped batch is
    one ``mujoco.rollout``), not differentiable.

    Args:
        sim: the simulator.
        params: unbatched :class:`PhysParams`.
        n_steps: number of physics steps (static).
        live_steps: optional () int, the steps whose poses the caller uses (traced, e.g. a
            fit window that ends before the rollout's static length). The C engine simulates
            only that many and holds the last pose after them (the same poses up to there,
            fewer steps); MJX's scan keeps its static length and skips the steps after them
            (:func:`_scan_steps`). None: all ``n_steps``.

    Returns:
        :class:`Trajectory` with ``pose`` of shape (n_steps + 1, n_objects, 3); with
        ``sim.ensemble`` K > 1 the mean pose of K rollouts from shifted starts
        (:func:`ensemble_offsets`; one batch of K rollouts).
    """
    if sim.ensemble > 1:
        poses = jax.vmap(lambda off: _rollout_poses(sim, params, n_steps, live_steps, off))(ensemble_offsets(sim))
        return Trajectory(jnp.mean(poses, axis=0), sim.dt)
    return Trajectory(_rollout_poses(sim, params, n_steps, live_steps, None), sim.dt)


def _rollout_poses(sim: Simulator, params: PhysParams, n_steps: int, live_steps, offset) -> jax.Array:
    """(n_steps + 1, n_objects, 3) poses of one rollout (:func:`rollout`), the objects' start
    positions shifted by ``offset`` ((n_objects, 3) m, or None)."""
    if sim.engine == "mujoco":  # the effects' once-per-rollout hooks here, in JAX; the host only writes them
        fields, velocity = {}, None
        if sim.effects:
            values = params.effects if params.effects is not None else jnp.asarray(neutral_values(sim.effects))
            vals = split_values(sim.effects, values)
            fields = model_updates(sim.effects, vals, apply_params(sim, params), sim.ctx, engine="mujoco")
            velocity = initial_velocity(sim.effects, vals, sim.ctx)
        return simulate_c.rollout_poses(sim, params.mass, params.friction, n_steps, fields, velocity, live_steps,
                                        offset)
    model = apply_params(sim, params)
    data0 = sim.data0
    if offset is not None:
        qpos = data0.qpos
        for i, q in enumerate(sim.index.qpos):
            qpos = qpos.at[q:q + 3].add(offset[i].astype(qpos.dtype))
        data0 = data0.replace(qpos=qpos)
    if sim.effects:
        return _rollout_effects(sim, model, params, n_steps, live_steps, data0).pose

    def step(d, _):
        d = _step(model, d)
        return d, _pose(sim, d.qpos)

    _, poses = _scan_steps(sim, step, data0, n_steps, live_steps)
    pose0 = _pose(sim, data0.qpos)[None]
    return jnp.concatenate([pose0, poses])


def _scan_steps(sim: Simulator, step, data0, n_steps: int, live_steps):
    """``lax.scan`` of ``step`` over ``n_steps`` steps; with ``live_steps`` the steps from there on
    keep the state (a ``lax.cond`` per step: skipped where ``live_steps`` is not batched, e.g.
    one video's rollouts under ``vmap``; computed and discarded where it is, a batch of videos)."""
    if live_steps is None:
        return jax.lax.scan(step, data0, None, length=n_steps)

    def held(d, _):
        return d, _pose(sim, d.qpos)

    def live_step(d, k):
        return jax.lax.cond(k < live_steps, step, held, d, None)

    return jax.lax.scan(live_step, data0, jnp.arange(n_steps))


def _rollout_effects(sim: Simulator, model: mjx.Model, params: PhysParams, n_steps: int, live_steps,
                     data0: mjx.Data) -> Trajectory:
    """:func:`rollout` with the simulator's effects (kept apart so the base model's program is
    unchanged), from ``data0``."""
    effects, ctx, index = sim.effects, sim.ctx, sim.index
    values = params.effects if params.effects is not None else jnp.asarray(neutral_values(effects), jnp.float64)
    vals = split_values(effects, values)
    updates = model_updates(effects, vals, model, ctx)
    if updates:
        model = model.replace(**updates)
    v0 = initial_velocity(effects, vals, ctx)
    qvel = data0.qvel
    for i, d in enumerate(index.dof):
        qvel = qvel.at[d:d + 3].add(v0[i].astype(qvel.dtype))
    data0 = data0.replace(qvel=qvel)
    bodies = np.asarray(index.body)
    step_hooks = has_step_hooks(effects)
    k_surface = surface_frictions(model.pair_friction, ctx, params.friction)

    def step(d, _):
        m = model
        if step_hooks:
            state = BodyState(jnp.stack([d.qpos[a:a + 3] for a in index.qpos]),
                              jnp.stack([d.qvel[q:q + 3] for q in index.dof]), params.mass)
            k = frictions(effects, vals, k_surface, state, ctx)
            if k is not None:
                pf = m.pair_friction
                for i in range(ctx.n_objects):
                    for col, pid in enumerate((index.ramp_pair[i], index.floor_pair[i])):
                        if pid >= 0:
                            pf = pf.at[pid, 0:2].set(k[i, col].astype(pf.dtype))
                m = m.replace(pair_friction=pf)
            f = forces(effects, vals, state, ctx)
            if f is not None:
                d = d.replace(xfrc_applied=d.xfrc_applied.at[bodies, 0:3].set(f.astype(d.xfrc_applied.dtype)))
        d = _step(m, d)
        return d, _pose(sim, d.qpos)

    _, poses = _scan_steps(sim, step, data0, n_steps, live_steps)
    pose0 = _pose(sim, data0.qpos)[None]
    return Trajectory(jnp.concatenate([pose0, poses]), sim.dt)


def sample_poses(traj: Trajectory, times: jax.Array) -> jax.Array:
    """Poses at arbitrary times after release, by linear interpolation between physics steps.

    Args:
        traj: a rollout.
        times: (N,) times in s since release; negative times give the start pose (at rest),
            times past the rollout give its last pose.

    Returns:
        (N, n_objects, 3) poses.
    """
    n = traj.pose.shape[0]
    s = jnp.clip(times / traj.dt, 0.0, n - 1.0)
    i0 = jnp.clip(jnp.floor(s).astype(jnp.int32), 0, n - 2)
    w = (s - i0)[:, None, None]
    return (1.0 - w) * traj.pose[i0] + w * traj.pose[i0 + 1]


def profile_from_positions(pos: jax.Array, frame_times: jax.Array) -> jax.Array:
    """Velocity profile from positions at frame times (the seed's V(k)).

    Args:
        pos: (N, n_objects, 2) x and vertical position in m at each frame.
        frame_times: (N,) frame times in s.

    Returns:
        (2 * n_objects, N - 1) velocities in m/s, rows (obj1 x, obj1 y, obj2 x, obj2 y).
    """
    v = jnp.diff(pos, axis=0) / jnp.diff(frame_times)[:, None, None]
    return v.reshape(v.shape[0], -1).T


def steps_needed(sim: Simulator, duration: float) -> int:
    """Physics steps to cover ``duration`` seconds after release (plus one)."""
    return int(np.ceil(duration / sim.dt)) + 1


def velocity_profile(sim: Simulator, params: PhysParams, frame_times: jax.Array, release_time: jax.Array,
                     n_steps: int, live_steps: jax.Array | None = None) -> jax.Array:
    """Simulated velocity profile at the video's frame times.

    Args:
        sim: the simulator.
        params: unbatched :class:`PhysParams`.
        frame_times: (N,) video frame times in s.
        release_time: scalar, video time (s) at which the objects are released.
        n_steps: physics steps to simulate (static; use :func:`steps_needed`).
        live_steps: optional () int: only these steps matter (:func:`rollout`).

    Returns:
        (2 * n_objects, N - 1) velocity profile in m/s.
    """
    traj = rollout(sim, params, n_steps, live_steps)
    pos = sample_poses(traj, frame_times - release_time)[..., :2]
    return profile_from_positions(pos, frame_times)
