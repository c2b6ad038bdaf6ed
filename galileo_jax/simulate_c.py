"""The C MuJoCo engine: batched rollouts of the scene through MuJoCo's native ``mujoco.rollout``.

Same scene, same model and same parameters as the MJX rollout (:func:`galileo_jax.simulate.rollout`),
but stepped by C MuJoCo on a thread pool. On this project's CPU (2 cores) it runs the ramp
scene far faster than MJX's ``jit(vmap(scan))`` (``benchmarks/engines.py``), so the
gradient-free methods use it by default on CPU (``fit --engine mujoco``); MJX stays for
derivatives (``grad.jacobian: ad``), for the CNN's training batches generated inside ``jit``
and for GPUs.

How it plugs into JAX: :func:`rollout_poses` is a ``jax.pure_callback`` with
``vmap_method="expand_dims"``, so a vmapped batch of B rollouts reaches the host as ONE call
of B rollouts (one ``mujoco.rollout`` over a thread pool), and the samplers, the
finite-difference Jacobian and the likelihood run unchanged inside ``jit``. It has no
derivative: differentiating through it raises (use the MJX engine for ``jacobian: ad``).

Per rollout b, a copy of the compiled model gets the masses and frictions as
:func:`galileo_jax.simulate.apply_params` sets them in MJX (``body_mass``, ``body_inertia``
x m/m0, ``pair_friction``; ``mj_setConst`` recomputes the invweights, as
:func:`galileo_jax.synth.set_physics` does for the renderer), then the effects' model updates
and release velocities (:func:`galileo_jax.effects.runtime.apply_c_model`). Effects that act
every step (forces, velocity-dependent friction) need a state-dependent input that an
open-loop ``mujoco.rollout`` cannot take: :func:`check_supported` rejects them.
"""

from __future__ import annotations

import copy
import os

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from galileo_jax.effects.runtime import apply_c_model, has_step_hooks, neutral_values
from galileo_jax.errors import GalileoError
from galileo_jax.model import object_poses

#: Engines a simulator can run on.
ENGINES = ("mjx", "mujoco")

_STATE_SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS
#: Largest batch handed to one ``mujoco.rollout`` call; bigger batches go in chunks. Measured:
#: a 4096-rollout call from inside the jitted callback hung (every thread asleep) where the
#: same call outside jit, and 1024 inside, ran.
MAX_CALL = 1024


def check_supported(effects) -> None:
    """Raise if the C engine cannot simulate these effects.

    Raises:
        GalileoError: an effect acts every physics step (``force`` or ``friction`` hook), which
            the open-loop ``mujoco.rollout`` cannot apply; the fix is ``--engine mjx``.
    """
    stepped = [e.name for e in effects if has_step_hooks((e,))]
    if stepped:
        raise GalileoError(f"effect(s) {', '.join(stepped)} act every physics step, which the C MuJoCo engine "
                           "cannot do; use --engine mjx")


def c_models(sim, mass: np.ndarray, friction: np.ndarray, effects: np.ndarray | None
             ) -> tuple[list[mujoco.MjModel], np.ndarray]:
    """One C model per rollout with its parameters set, and the initial states.

    Args:
        sim: a :class:`~galileo_jax.simulate.Simulator`.
        mass: (B, n_objects) masses in kg.
        friction: (B, n_objects) friction coefficients.
        effects: (B, n_effect_params) effect values, or None (neutral).

    Returns:
        (models, state0): B ``MjModel`` copies and (B, nstate) full physics states at release.
    """
    from galileo_jax.simulate import PhysParams  # simulate imports this module
    from galileo_jax.synth import set_physics

    base = sim.mj_model
    index = sim.index
    data = mujoco.MjData(base)
    nstate = mujoco.mj_stateSize(base, _STATE_SPEC)
    models, state0 = [], np.empty((mass.shape[0], nstate))
    neutral = neutral_values(sim.effects)
    for b in range(mass.shape[0]):
        m = copy.copy(base)
        mujoco.mj_resetData(m, data)
        set_physics(m, data, index, PhysParams(mass[b], friction[b]))  # as the renderer sets them
        if sim.effects:
            values = effects[b] if effects is not None else neutral
            apply_c_model(sim.effects, values, m, data, index, sim.ctx, friction[b])
        mujoco.mj_getState(m, data, state0[b], _STATE_SPEC)
        models.append(m)
    return models, state0


def rollout_poses_host(sim, mass: np.ndarray, friction: np.ndarray, effects: np.ndarray | None,
                       n_steps: int) -> np.ndarray:
    """Batched C MuJoCo rollouts on the host (NumPy in, NumPy out).

    Args:
        sim: the simulator.
        mass, friction: (B, n_objects); effects: (B, n_effect_params) or None.
        n_steps: physics steps.

    Returns:
        (B, n_steps + 1, n_objects, 3) poses: centre x, z (m) and pitch about y (rad), as
        :class:`~galileo_jax.simulate.Trajectory` holds them; non-finite where a rollout diverged.
    """
    if mass.shape[0] > MAX_CALL:  # see MAX_CALL
        return np.concatenate([rollout_poses_host(sim, mass[i:i + MAX_CALL], friction[i:i + MAX_CALL],
                                                  None if effects is None else effects[i:i + MAX_CALL], n_steps)
                               for i in range(0, mass.shape[0], MAX_CALL)])
    models, state0 = c_models(sim, mass, friction, effects)
    nthread = os.cpu_count() or 1
    # A fresh thread pool per call: mujoco.rollout's persistent pool crashed (segfault) when
    # called from XLA's host-callback threads with batches of changing size.
    datas = [mujoco.MjData(sim.mj_model) for _ in range(min(nthread, len(models)))]
    state, _ = mj_rollout.rollout(models, datas, state0, nstep=n_steps)
    qpos = np.concatenate([state0[:, None, 1:1 + sim.mj_model.nq], state[:, :, 1:1 + sim.mj_model.nq]], axis=1)
    return object_poses(sim.index, qpos)


def rollout_poses(sim, mass: jax.Array, friction: jax.Array, effects: jax.Array | None, n_steps: int) -> jax.Array:
    """:func:`rollout_poses_host` as a ``jax.pure_callback`` for one rollout (vmap batches it).

    Args:
        mass, friction: (n_objects,); effects: (n_effect_params,) or None; extra leading
            (vmapped) axes reach the host as one batch.

    Returns:
        (n_steps + 1, n_objects, 3) float64 poses.
    """
    n = sim.n_objects
    shape = jax.ShapeDtypeStruct((n_steps + 1, n, 3), jnp.float64)
    eff = effects if effects is not None else jnp.zeros((0,), jnp.float64)

    def host(m, k, e):
        m, k, e = np.asarray(m, np.float64), np.asarray(k, np.float64), np.asarray(e, np.float64)
        lead = np.broadcast_shapes(m.shape[:-1], k.shape[:-1], e.shape[:-1])
        mb = np.broadcast_to(m, lead + (n,)).reshape(-1, n)
        kb = np.broadcast_to(k, lead + (n,)).reshape(-1, n)
        eb = np.broadcast_to(e, lead + e.shape[-1:]).reshape(mb.shape[0], e.shape[-1])
        poses = rollout_poses_host(sim, mb, kb, eb if e.shape[-1] else None, n_steps)
        return poses.reshape(lead + (n_steps + 1, n, 3))

    return jax.pure_callback(host, shape, jnp.asarray(mass, jnp.float64), jnp.asarray(friction, jnp.float64),
                             jnp.asarray(eff, jnp.float64), vmap_method="expand_dims")
