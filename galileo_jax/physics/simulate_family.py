"""Rollouts across a scene family: each rollout its own ramp scene, on C MuJoCo.

The scene-conditioned CNN's training batches (:mod:`galileo_jax.inference.cnn_training`) draw
a scene (:class:`~galileo_jax.scene_family.SceneFamily` features) with every parameter vector.
MJX compiles one program per model structure and keeps the geometry in the model, so it
would need the geometry fields batched by hand; C MuJoCo compiles a family scene in about
1.7 ms (:func:`~galileo_jax.physics.model.build_model`, measured on this project's 2-core
CPU), less than the rollout itself (4-8 ms for 3.4 s at 1/240 s). So
:func:`family_rollout_poses_host` builds each row's scene (:func:`~galileo_jax.scene_family.family_scene`)
with the model builder the renderer and the fits use, sets its masses and frictions as the C
engine does (:func:`~galileo_jax.physics.simulate_c.c_models`), and runs all rows in one
``mujoco.rollout`` call over a thread pool. :func:`family_rollout_poses` is the same as a host
call (:mod:`galileo_jax.physics.host_call`) for use inside ``jit`` and ``vmap``: a vmapped batch
reaches the host as one call, as the C engine's rollouts do. No derivatives.

The physics timestep is the renderer's and the fits' default, 1/240 s (8 substeps at 30 fps),
whatever the video's frame rate: the network reads the profile on its own time grid.
"""

from __future__ import annotations

import os
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from galileo_jax.physics.host_call import host_call, stable_name
from galileo_jax.physics.model import build_model, object_poses
from galileo_jax.physics.simulate import Trajectory
from galileo_jax.physics.simulate_c import MAX_CALL, c_models
from galileo_jax.scene_family import FEATURES, family_scene

#: Physics timestep of the family's rollouts (s).
FAMILY_DT = 1.0 / 240.0
#: Objects of a family scene.
N_OBJECTS = 2


def family_rollout_poses_host(features: np.ndarray, mass: np.ndarray, friction: np.ndarray, n_steps: int,
                              dt: float = FAMILY_DT) -> np.ndarray:
    """Batched C MuJoCo rollouts, each of its own family scene (NumPy in, NumPy out).

    Args:
        features: (B, F) scene features (:data:`~galileo_jax.scene_family.FEATURES`).
        mass: (B, 2) masses in kg; friction: (B, 2) friction coefficients.
        n_steps: physics steps.
        dt: physics timestep (s).

    Returns:
        (B, n_steps + 1, 2, 3) poses (centre x, z in m, pitch in rad), the start pose first;
        non-finite where a rollout diverged.

    Raises:
        pydantic.ValidationError: features that make no valid scene (a start over the foot).
    """
    features = np.asarray(features, np.float64).reshape(-1, len(FEATURES))
    B = features.shape[0]
    if B > MAX_CALL:
        return np.concatenate([family_rollout_poses_host(features[i:i + MAX_CALL], mass[i:i + MAX_CALL],
                                                         friction[i:i + MAX_CALL], n_steps, dt)
                               for i in range(0, B, MAX_CALL)])
    models, states, index = [], [], None
    for b in range(B):
        model, index = build_model(family_scene(features[b]), timestep=dt, engine="mujoco")
        one = SimpleNamespace(mj_model=model, index=index)
        m, s0 = c_models(one, np.asarray(mass[b:b + 1], np.float64), np.asarray(friction[b:b + 1], np.float64),
                         models=[model])
        models.append(m[0])
        states.append(s0[0])
    if B == 0:
        return np.zeros((0, n_steps + 1, N_OBJECTS, 3))
    state0 = np.stack(states)
    nthread = min(os.cpu_count() or 1, B)
    datas = [mujoco.MjData(models[0]) for _ in range(nthread)]
    state, _ = mj_rollout.rollout(models, datas, state0, nstep=n_steps)
    nq = models[0].nq
    qpos = np.concatenate([state0[:, None, 1:1 + nq], state[:, :, 1:1 + nq]], axis=1)
    return object_poses(index, qpos)


def family_rollout_poses(features: jax.Array, mass: jax.Array, friction: jax.Array, n_steps: int,
                         dt: float = FAMILY_DT) -> jax.Array:
    """:func:`family_rollout_poses_host` for one rollout as a host call (vmap batches it).

    Args:
        features: (F,) scene features; mass, friction: (2,).
        n_steps: physics steps (static); dt: timestep (static).

    Returns:
        (n_steps + 1, 2, 3) float64 poses.
    """
    F = len(FEATURES)
    shape = jax.ShapeDtypeStruct((n_steps + 1, N_OBJECTS, 3), jnp.float64)
    own = [(F,), (N_OBJECTS,), (N_OBJECTS,)]

    def host(*arrays):
        arrays = [np.asarray(a, np.float64) for a in arrays]
        lead = np.broadcast_shapes(*(a.shape[:a.ndim - len(o)] for a, o in zip(arrays, own)))
        flat = [np.broadcast_to(a, lead + o).reshape((-1,) + o) for a, o in zip(arrays, own)]
        poses = family_rollout_poses_host(*flat, n_steps=n_steps, dt=dt)
        return poses.reshape(lead + (n_steps + 1, N_OBJECTS, 3))

    name = stable_name("galileo_family_rollout", FEATURES, int(n_steps), float(dt))
    return host_call(name, host, shape, *(jnp.asarray(a, jnp.float64) for a in (features, mass, friction)))


def family_trajectory(features: jax.Array, mass: jax.Array, friction: jax.Array, n_steps: int,
                      dt: float = FAMILY_DT) -> Trajectory:
    """:func:`family_rollout_poses` as a :class:`~galileo_jax.physics.simulate.Trajectory` (so
    :func:`~galileo_jax.physics.simulate.sample_poses` reads it at any time after release)."""
    return Trajectory(family_rollout_poses(features, mass, friction, n_steps, dt), dt)
