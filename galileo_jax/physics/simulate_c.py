"""The C MuJoCo engine: batched rollouts of the scene through MuJoCo's native ``mujoco.rollout``.

Same scene, same model and same parameters as the MJX rollout (:func:`galileo_jax.physics.simulate.rollout`),
but stepped by C MuJoCo on a thread pool. On this project's CPU (2 cores) it runs the ramp
scene far faster than MJX's ``jit(vmap(scan))`` (``benchmarks/engines.py``), so the
gradient-free methods use it by default on CPU (``fit --engine mujoco``); MJX stays for
derivatives (``grad.jacobian: ad``), for the CNN's training batches generated inside ``jit``
and for GPUs.

How it plugs into JAX: :func:`rollout_poses` is a host call (as ``jax.pure_callback``, but an
XLA FFI target that JAX's persistent compilation cache keeps: :mod:`galileo_jax.physics.host_call`)
with ``vmap_method="expand_dims"``, so a vmapped batch of B rollouts reaches the host as ONE call
of B rollouts (one ``mujoco.rollout`` over a thread pool), and the samplers, the
finite-difference Jacobian and the likelihood run unchanged inside ``jit``. It has no
derivative: differentiating through it raises (use the MJX engine for ``jacobian: ad``).

Per rollout b, a copy of the compiled model (reused from earlier batches, with every field a
batch wrote restored first: :func:`_checkout_models`) gets the masses and frictions as
:func:`galileo_jax.physics.simulate.apply_params` sets them in MJX (``body_mass``, ``body_inertia``
x m/m0, ``pair_friction``; ``mj_setConst`` recomputes the invweights, as
:func:`galileo_jax.physics.model.set_physics` does for the renderer), then the effects' model updates
and release velocities. Those are evaluated by the effects' own hooks in JAX, inside ``jit``,
before the callback (:func:`galileo_jax.physics.simulate.rollout`), and reach the host as arrays:
the host code runs no JAX (JAX called from inside a host callback can deadlock). Effects that
act every step (forces, velocity-dependent friction) need a state-dependent input that an
open-loop ``mujoco.rollout`` cannot take: :func:`check_supported` rejects them, unless the effect
has a C form that MuJoCo's own physics computes (``Effect.c_build`` / ``c_model``: quadratic drag
through the ellipsoid fluid model).
"""

from __future__ import annotations

import copy
import os
import threading
from collections import OrderedDict

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from galileo_jax.effects.runtime import needs_mjx
from galileo_jax.errors import GalileoError
from galileo_jax.physics.host_call import host_call, stable_name
from galileo_jax.physics.model import PHYSICS_FIELDS, object_poses, set_physics
from galileo_jax.scene import scene_key

#: Engines a simulator can run on.
ENGINES = ("mjx", "mujoco")

_STATE_SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS
#: Largest batch handed to one ``mujoco.rollout`` call; bigger batches go in chunks. Measured:
#: a 4096-rollout call from inside the jitted callback hung (every thread asleep) where the
#: same call outside jit, and 1024 inside, ran.
MAX_CALL = 1024
#: Rollouts the jitted callback (:func:`rollout_poses`) remembers by their exact inputs, least
#: recently used dropped (about 35 kB each for the ramp scene's 3 s). A vmapped optimiser keeps
#: asking for the same ones: a vmapped while loop runs every start of a multi-start
#: Levenberg-Marquardt until the slowest stops, evaluating the finished ones at their (fixed)
#: last point, and the final Jacobian repeats the last step's. Measured on README command 1
#: (4 starts ending after 37, 24, 30 and 54 steps; see :func:`cached_rollout_poses`). 0 turns it off.
CACHE_ROLLOUTS = 2048
_CACHE: "OrderedDict[tuple, np.ndarray]" = OrderedDict()
_CACHE_MODELS: dict[int, mujoco.MjModel] = {}  # the models keyed by id, kept alive so no id is reused
_CACHE_LOCK = threading.Lock()


def check_supported(effects) -> None:
    """Raise if the C engine cannot simulate these effects.

    Raises:
        GalileoError: an effect acts every physics step (``force`` or ``friction`` hook) and has
            no C form (``c_model``): the open-loop ``mujoco.rollout`` cannot apply it; the fix
            is ``--engine mjx``.
    """
    stepped = [e.name for e in effects if needs_mjx((e,))]
    if stepped:
        raise GalileoError(f"effect(s) {', '.join(stepped)} act every physics step, which the C MuJoCo engine "
                           "cannot do; use --engine mjx")


#: Compiled models whose copies :func:`_checkout_models` keeps (least recently used dropped).
POOL_MODELS = 8
#: {id(compiled model): (that model, [free lists of copies], set of field names ever written)}
_POOL: "OrderedDict[int, tuple]" = OrderedDict()
_POOL_LOCK = threading.Lock()


def _checkout_models(base: mujoco.MjModel, n: int, names) -> list[mujoco.MjModel]:
    """``n`` copies of ``base`` for one batch, reused from earlier batches: a copy of a model
    (``copy.copy``) costs about 0.27 ms, three quarters of setting up a rollout (measured:
    0.36 ms a rollout with a fresh copy each; a C rollout of the ramp scene takes 2-3 ms).
    Before reuse, every field a batch of this model has written (the physics fields and the
    effects' ``names``, whole) is restored from ``base``, so a reused copy starts as a fresh one
    would, and its rollout is bit-identical. The list is the caller's until it hands it back
    (:func:`_return_models`): XLA may run the host callback on several threads at once."""
    with _POOL_LOCK:
        entry = _POOL.get(id(base))
        if entry is None or entry[0] is not base:  # an id reused by another model: start afresh
            entry = _POOL[id(base)] = (base, [], set(PHYSICS_FIELDS))
            while len(_POOL) > POOL_MODELS:
                _POOL.popitem(last=False)
        _POOL.move_to_end(id(base))
        _, free, written = entry
        written.update(names)
        models = free.pop() if free else []
        restore = tuple(written)
    for m in models[:n]:
        for name in restore:
            getattr(m, name)[...] = getattr(base, name)
    models.extend(copy.copy(base) for _ in range(n - len(models)))
    return models


def _return_models(base: mujoco.MjModel, models: list[mujoco.MjModel]) -> None:
    """Hand a batch's models back to the pool once its rollout has returned."""
    with _POOL_LOCK:
        entry = _POOL.get(id(base))
        if entry is not None and entry[0] is base:
            entry[1].append(models)


def c_models(sim, mass: np.ndarray, friction: np.ndarray, fields: dict | None = None,
             velocity: np.ndarray | None = None, offset: np.ndarray | None = None,
             models: list[mujoco.MjModel] | None = None) -> tuple[list[mujoco.MjModel], np.ndarray]:
    """One C model per rollout with its parameters set, and the initial states.

    Args:
        sim: a :class:`~galileo_jax.physics.simulate.Simulator`.
        mass: (B, n_objects) masses in kg.
        friction: (B, n_objects) friction coefficients.
        fields: optional {model field name: (B, ...) values} written after the masses and
            frictions (the effects' model updates, whole fields).
        velocity: optional (B, n_objects, 3) release velocities in m/s (the effects').
        offset: optional (B, n_objects, 3) shifts (m) of the objects' start positions
            (:func:`galileo_jax.physics.simulate.ensemble_offsets`).
        models: optional list of at least B copies of the compiled model as a fresh copy is
            (:func:`_checkout_models`), set up here instead of new copies.

    Returns:
        (models, state0): B ``MjModel`` copies of the compiled model and (B, nstate) full
        physics states at release.
    """
    base = sim.mj_model
    index = sim.index
    data = mujoco.MjData(base)
    nstate = mujoco.mj_stateSize(base, _STATE_SPEC)
    B = mass.shape[0]
    models = [copy.copy(base) for _ in range(B)] if models is None else models[:B]
    state0 = np.empty((B, nstate))
    for b, m in enumerate(models):
        mujoco.mj_resetData(m, data)
        set_physics(m, data, index, mass[b], friction[b])  # as the renderer sets them
        for name, value in (fields or {}).items():
            getattr(m, name)[...] = value[b]
        if velocity is not None:
            for i, d in enumerate(index.dof):
                data.qvel[d:d + 3] += velocity[b, i]
        if offset is not None:
            for i, q in enumerate(index.qpos):
                data.qpos[q:q + 3] += offset[b, i]
        mujoco.mj_getState(m, data, state0[b], _STATE_SPEC)
    return models, state0


def rollout_poses_host(sim, mass: np.ndarray, friction: np.ndarray, n_steps: int, fields: dict | None = None,
                       velocity: np.ndarray | None = None, offset: np.ndarray | None = None) -> np.ndarray:
    """Batched C MuJoCo rollouts on the host (NumPy in, NumPy out).

    Args:
        sim: the simulator.
        mass, friction: (B, n_objects).
        n_steps: physics steps.
        fields, velocity: the effects' model updates and release velocities (:func:`c_models`).
        offset: optional start-position shifts (:func:`c_models`).

    Returns:
        (B, n_steps + 1, n_objects, 3) poses: centre x, z (m) and pitch about y (rad), as
        :class:`~galileo_jax.physics.simulate.Trajectory` holds them; non-finite where a rollout diverged.
    """
    if mass.shape[0] > MAX_CALL:  # see MAX_CALL
        def part(a, i):
            return None if a is None else a[i:i + MAX_CALL]
        return np.concatenate([rollout_poses_host(sim, mass[i:i + MAX_CALL], friction[i:i + MAX_CALL], n_steps,
                                                  {k: v[i:i + MAX_CALL] for k, v in (fields or {}).items()},
                                                  part(velocity, i), part(offset, i))
                               for i in range(0, mass.shape[0], MAX_CALL)])
    pool = _checkout_models(sim.mj_model, mass.shape[0], tuple(fields or {}))
    try:
        models, state0 = c_models(sim, mass, friction, fields, velocity, offset, models=pool)
        nthread = os.cpu_count() or 1
        # A fresh thread pool per call: mujoco.rollout's persistent pool crashed (segfault) when
        # called from XLA's host-callback threads with batches of changing size.
        datas = [mujoco.MjData(sim.mj_model) for _ in range(min(nthread, len(models)))]
        state, _ = mj_rollout.rollout(models, datas, state0, nstep=n_steps)
    finally:
        _return_models(sim.mj_model, pool)
    qpos = np.concatenate([state0[:, None, 1:1 + sim.mj_model.nq], state[:, :, 1:1 + sim.mj_model.nq]], axis=1)
    return object_poses(sim.index, qpos)


def clear_rollout_cache() -> None:
    """Forget the rollouts :func:`cached_rollout_poses` remembers."""
    with _CACHE_LOCK:
        _CACHE.clear()
        _CACHE_MODELS.clear()


def cached_rollout_poses(sim, mass: np.ndarray, friction: np.ndarray, n_steps: int, fields: dict | None = None,
                         velocity: np.ndarray | None = None, offset: np.ndarray | None = None) -> np.ndarray:
    """:func:`rollout_poses_host`, simulating only the rows (rollouts) whose exact inputs it has not
    simulated recently (:data:`CACHE_ROLLOUTS`; 0: none remembered), each distinct row of the
    batch once (batches padded with copies, :meth:`~galileo_jax.inference.problem.BatchedAPI.in_chunks`,
    cost no rollouts): the same poses, since a rollout is a deterministic function of its
    inputs. Thread-safe (XLA may run callbacks concurrently).

    Args and returns: as :func:`rollout_poses_host`.
    """
    B = mass.shape[0]
    if B == 0:
        return rollout_poses_host(sim, mass, friction, n_steps, fields, velocity, offset)
    names = sorted(fields or {})
    parts = [mass, friction] + [fields[k] for k in names] + ([velocity] if velocity is not None else []) + \
        ([offset] if offset is not None else [])
    rows = np.concatenate([np.asarray(a, np.float64).reshape(B, -1) for a in parts], axis=1)
    model = (id(sim.mj_model), int(n_steps), tuple(names), velocity is not None, offset is not None)
    keys = [model + (rows[b].tobytes(),) for b in range(B)]
    remember = CACHE_ROLLOUTS > 0
    found = [None] * B
    if remember:
        with _CACHE_LOCK:
            if id(sim.mj_model) not in _CACHE_MODELS:
                if len(_CACHE_MODELS) >= 16:  # a long session of many scenes: start afresh
                    _CACHE.clear()
                    _CACHE_MODELS.clear()
                _CACHE_MODELS[id(sim.mj_model)] = sim.mj_model
            found = [_CACHE.get(k) for k in keys]
            for k, f in zip(keys, found):
                if f is not None:
                    _CACHE.move_to_end(k)
    todo: dict[tuple, int] = {}
    for b, (k, f) in enumerate(zip(keys, found)):
        if f is None and k not in todo:
            todo[k] = b
    fresh = {}
    if todo:
        idx = np.fromiter(todo.values(), int, len(todo))
        new = rollout_poses_host(sim, mass[idx], friction[idx], n_steps, {k: fields[k][idx] for k in names},
                                 None if velocity is None else velocity[idx], None if offset is None else offset[idx])
        fresh = {k: new[i].copy() for i, k in enumerate(todo)}
        if remember:
            with _CACHE_LOCK:
                _CACHE.update(fresh)
                while len(_CACHE) > CACHE_ROLLOUTS:
                    _CACHE.popitem(last=False)
    return np.stack([f if f is not None else fresh[k] for k, f in zip(keys, found)])


def rollout_poses(sim, mass: jax.Array, friction: jax.Array, n_steps: int, fields: dict | None = None,
                  velocity: jax.Array | None = None, live_steps: jax.Array | None = None,
                  offset: jax.Array | None = None) -> jax.Array:
    """:func:`rollout_poses_host` as a host call (:func:`~galileo_jax.physics.host_call.host_call`)
    for one rollout (vmap batches it).

    Args:
        mass, friction: (n_objects,).
        n_steps: physics steps (static).
        fields: optional {model field name: array of the field's shape}, the effects' model
            updates for this rollout, computed in JAX (:func:`galileo_jax.physics.simulate.rollout`).
        velocity: optional (n_objects, 3) release velocities in m/s.
        live_steps: optional () int (traced): simulate only this many steps (at most
            ``n_steps``; a batch simulates its largest) and hold the last pose after them.
            The poses up to there are the same; the steps after them cost nothing. This keeps
            the output's static shape, so videos whose fit windows end at different times
            share one compiled program.
        offset: optional (n_objects, 3) shifts (m) of the start positions.
        Extra leading (vmapped) axes of any input reach the host as one batch.

    Returns:
        (n_steps + 1, n_objects, 3) float64 poses.
    """
    n = sim.n_objects
    shape = jax.ShapeDtypeStruct((n_steps + 1, n, 3), jnp.float64)
    names = sorted(fields or {})
    inputs = [jnp.asarray(mass, jnp.float64), jnp.asarray(friction, jnp.float64)]
    inputs += [jnp.asarray(fields[k], jnp.float64) for k in names]
    if velocity is not None:
        inputs.append(jnp.asarray(velocity, jnp.float64))
    if offset is not None:
        inputs.append(jnp.asarray(offset, jnp.float64))
    live = live_steps is not None
    if live:
        inputs.append(jnp.asarray(live_steps, jnp.float64))
    # each input's own shape, without the leading axes vmap adds (known here, before vmap)
    own = [np.shape(mass)[-1:], np.shape(friction)[-1:]] + [getattr(sim.mj_model, k).shape for k in names]
    own += [(n, 3)] if velocity is not None else []
    own += [(n, 3)] if offset is not None else []
    own += [()] if live else []

    def host(*arrays):
        arrays = [np.asarray(a, np.float64) for a in arrays]
        lead = np.broadcast_shapes(*(a.shape[:a.ndim - len(o)] for a, o in zip(arrays, own)))
        flat = [np.broadcast_to(a, lead + tuple(o)).reshape((-1,) + tuple(o)) for a, o in zip(arrays, own)]
        steps = n_steps
        if live and flat[-1].size:
            steps = int(np.clip(np.max(flat[-1]), 1, n_steps))
        extra = iter(flat[2 + len(names):])
        vel = next(extra) if velocity is not None else None
        off = next(extra) if offset is not None else None
        poses = cached_rollout_poses(sim, flat[0], flat[1], steps, dict(zip(names, flat[2:2 + len(names)])), vel, off)
        if steps < n_steps:  # hold the last pose (module docstring: only the live steps are used)
            poses = np.concatenate([poses, np.repeat(poses[:, -1:], n_steps - steps, axis=1)], axis=1)
        return poses.reshape(lead + (n_steps + 1, n, 3))

    # the target's name holds everything ``host`` depends on: the simulator's model (its scene's
    # physics, timestep, effects, ensemble) and the static arguments
    name = stable_name("galileo_c_rollout", scene_key(sim.scene), float(sim.dt), tuple(e.name for e in sim.effects),
                       int(sim.ensemble), int(n_steps), tuple(names), tuple(map(tuple, own)), velocity is not None,
                       offset is not None, live)
    return host_call(name, host, shape, *inputs)
