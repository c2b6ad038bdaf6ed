"""Predictions beyond the video: where each object comes to rest, and "will it slide?".

The two questions of Wu et al. (NIPS 2015) that the dissertation (4.3, "Potential tests")
proposes: "Will the object on the inclined plane slide?" (closed form: it slides from rest
when k1 < tan(theta)) and "How far will it slide?" (simulate until all motion stops).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from galileo_jax.physics.simulate import PhysParams, Simulator, rollout, steps_needed
from galileo_jax.scene import Scene

#: Speed (m/s) below which an object counts as at rest.
REST_SPEED = 0.01


class RestPrediction(NamedTuple):
    """Where the objects stop, for a batch of parameter sets.

    Attributes:
        rest_x: (B, n_objects) world x of each object's centre at the end, in m (the ramp's
            foot is x = 0; positive x is on the floor).
        stop_time: (B, n_objects) time after release (s) after which the object stays below
            :data:`REST_SPEED`; ``nan`` if it is still moving at the end of the simulation.
        moving_at_end: (B, n_objects) bool, still moving when the simulation ends.
    """

    rest_x: np.ndarray
    stop_time: np.ndarray
    moving_at_end: np.ndarray


def slides(scene: Scene, friction: float | np.ndarray) -> np.ndarray:
    """Whether an object released at rest on the ramp slides: k < tan(theta).

    Args:
        scene: the scene (ramp angle).
        friction: sliding friction coefficient(s), any shape.

    Returns:
        bool array of the same shape.
    """
    return np.asarray(friction) < math.tan(scene.ramp.angle)


def predict_rest(sim: Simulator, params: PhysParams, duration: float, chunk: int = 16) -> RestPrediction:
    """Simulate ``duration`` seconds after release and report where the objects stop.

    Args:
        sim: the simulator.
        params: batched :class:`PhysParams`, leaves of shape (B, n_objects).
        duration: seconds to simulate after release.
        chunk: rollouts per vmapped batch.

    Returns:
        :class:`RestPrediction` with arrays of shape (B, n_objects).
    """
    n = steps_needed(sim, duration)
    stride = max(1, int(round(0.05 / sim.dt)))

    @jax.jit
    def one(p):
        pose = rollout(sim, p, n).pose[::stride, :, :2]
        speed = jnp.linalg.norm(jnp.diff(pose, axis=0), axis=-1) / (stride * sim.dt)
        return pose[-1, :, 0], speed

    batched = jax.jit(lambda ps: jax.lax.map(one, ps, batch_size=chunk))
    rest_x, speed = batched(params)
    speed = np.asarray(speed)  # (B, S, n)
    moving = speed > REST_SPEED
    # last index at which each object moves; stop time is the end of that interval
    any_moving = moving.any(axis=1)
    last = np.where(any_moving, moving.shape[1] - 1 - np.argmax(moving[:, ::-1], axis=1), -1)
    stop_time = (last + 1) * stride * sim.dt
    moving_at_end = moving[:, -1, :]
    stop_time = np.where(moving_at_end, np.nan, stop_time)
    return RestPrediction(np.asarray(rest_x), stop_time, moving_at_end)
