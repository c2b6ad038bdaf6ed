"""Training data of the amortised CNN (:mod:`galileo_jax.inference.cnn`), simulated inside
``jit``: the prior the parameters are drawn from (:func:`training_prior`; the seed's,
:func:`seed_prior`), the tracking noise added (:class:`NoiseModel`), and one batch of simulated,
noisy network inputs with their targets (:func:`simulate_examples`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from galileo_jax.inference.cnn import MAX_SPEED, CNNSpec
from galileo_jax.params import ParamSpace
from galileo_jax.scene import Scene


class NoiseModel(NamedTuple):
    """How training profiles are corrupted and cut (the observation model of
    :mod:`galileo_jax.likelihood`: independent Gaussian position errors, differenced).

    Attributes:
        position_sd: (low, high) in m: each trace's position noise SD is log-uniform on it.
        min_samples: shortest valid length of a training window (samples).
        prefix: largest masked prefix (samples), drawn for a third of the examples (videos that
            start less than ``release_offset`` before the release).
        scale_error: relative error of the camera's scale: each example's velocities are
            multiplied by 1 + u, u uniform on +-``scale_error`` (the calibration nuisance that
            ``grad`` and ``mh`` fit within ``FitConfig.scale_tolerance``), so the network's
            intervals carry it; 0 takes the scale as exact.
    """

    position_sd: tuple[float, float] = (5e-5, 3e-3)
    min_samples: int = 24
    prefix: int = 6
    scale_error: float = 0.0


def _with_scale_error(v: jax.Array, noise: NoiseModel, key: jax.Array) -> jax.Array:
    """Velocities ``v`` (b, L, T) times a factor 1 + u per example, u uniform on
    +-``noise.scale_error`` (:class:`NoiseModel`); ``v`` itself where that is 0 (a static
    setting: a network trained without it draws no extra key and sees the same examples)."""
    if noise.scale_error <= 0:
        return v
    u = jax.random.uniform(jax.random.fold_in(key, 7), (v.shape[0], 1, 1), v.dtype, minval=-1.0, maxval=1.0)
    return v * (1.0 + noise.scale_error * u)


def training_prior(space: ParamSpace, scene: Scene, key: jax.Array, n: int, slide_margin: float = 0.02) -> jax.Array:
    """n draws (n, d) of theta from the prior of ``space``, with object 1's friction below
    tan(ramp angle) - ``slide_margin`` when it starts on the ramp (so it slides: ``fit``
    rejects videos where it never moves). Pure; ``scene`` is read in Python only.
    """
    theta = space.sample_prior(key, n)
    if "k1" in space.names and scene.placement(0) == "ramp":
        theta = _k1_sliding(space, theta, key, math.tan(scene.ramp.angle) - slide_margin)
    return theta


def _k1_sliding(space: ParamSpace, theta: jax.Array, key: jax.Array, k1_max) -> jax.Array:
    """``theta`` (n, d) with k1 redrawn uniformly between its lower bound and min(its upper
    bound, ``k1_max``) (a scalar or (n,): tan(angle) - margin, where object 1 slides)."""
    j = space.index("k1")
    lo = space.lower[j]
    hi = jnp.minimum(space.upper[j], k1_max)
    u = jax.random.uniform(jax.random.fold_in(key, 1), (theta.shape[0],), minval=1e-6, maxval=1 - 1e-6)
    return theta.at[:, j].set(lo + (hi - lo) * u)


#: The seed's training and test prior (NOTES.md "CNN", dissertation 4.3): frictions uniform on
#: (0, SEED_FRICTION), masses on (0, 1).
SEED_FRICTION = 0.3


def seed_prior(space: ParamSpace, key: jax.Array, n: int) -> jax.Array:
    """n draws (n, d) of theta from the seed's prior: k1, k2 ~ U(0, 0.3), phi = (m1 - m2) / (m1 + m2)
    with m1, m2 ~ U(0, 1) (so phi is not uniform), the other coordinates (the release time) from
    ``space``'s prior. Pure. The like-for-like setting of the seed's error table."""
    k = jax.random.split(key, 3)
    theta = space.sample_prior(k[0], n)
    fr = jax.random.uniform(k[1], (n, 2), minval=0.0, maxval=SEED_FRICTION)
    m = jax.random.uniform(k[2], (n, 2), minval=1e-3, maxval=1.0)
    cols = {"k1": fr[:, 0], "k2": fr[:, 1], "phi": (m[:, 0] - m[:, 1]) / (m[:, 0] + m[:, 1])}
    for name, col in cols.items():
        if name in space.names:
            theta = theta.at[:, space.index(name)].set(col.astype(theta.dtype))
    return theta


def simulate_examples(engine, spec: CNNSpec, noise: NoiseModel, theta: jax.Array, key: jax.Array,
                      views: int = 1) -> jax.Array:
    """Network inputs (n * views, L, T + 1) float32 for parameters ``theta`` (n, d) (pure, jittable).

    One rollout per row of ``theta`` on ``engine`` (MJX: vmapped in chunks of ``engine.max_batch``;
    C MuJoCo: one batched native call through a callback), at the window's frame times t_k = k / fps, the
    release at ``release_offset`` + theta's ``dt_release``), then ``views`` noisy, cut copies of
    each: position noise e ~ N(0, sd^2) per trace with sd log-uniform on ``noise.position_sd``,
    velocity noise (e[k+1] - e[k]) * fps, all scaled by a camera scale error (``noise.scale_error``);
    a valid length uniform on [min_samples, L]; a masked prefix for a third of the copies. Rows of
    the output are grouped by view (view-major).
    """
    from galileo_jax.inference.problem import ProblemData, map_batch

    n = theta.shape[0]
    L, T = spec.n_samples, spec.n_traces
    data = ProblemData(jnp.arange(L + 1) / spec.fps, jnp.asarray(spec.release_offset), None)
    prof = map_batch(lambda t: engine.profile_theta(t, data), jnp.asarray(theta, jnp.float64), engine.max_batch)
    # A rollout that blew up (extreme mass ratios: phi near +-1 leaves an object of ~0 kg) is
    # dropped: all-zero input and mask, which the loss skips (:func:`usable`).
    ok = jnp.all(jnp.isfinite(prof) & (jnp.abs(prof) <= MAX_SPEED), axis=(1, 2))
    prof = jnp.where(ok[:, None, None], prof, 0.0)
    ok = jnp.tile(ok, views)
    prof = jnp.tile(jnp.swapaxes(prof, 1, 2).astype(jnp.float32), (views, 1, 1))  # (B, L, T)
    b = prof.shape[0]
    k_sd, k_e, k_len, k_pre, k_has = jax.random.split(key, 5)
    lo, hi = math.log(noise.position_sd[0]), math.log(noise.position_sd[1])
    sd = jnp.exp(jax.random.uniform(k_sd, (b, 1, T), jnp.float32, minval=lo, maxval=hi))
    e = sd * jax.random.normal(k_e, (b, L + 1, T), jnp.float32)
    v = _with_scale_error(prof + jnp.diff(e, axis=1) * spec.fps, noise, key)
    length = jax.random.randint(k_len, (b, 1), noise.min_samples, L + 1)
    prefix = jnp.where(jax.random.uniform(k_has, (b, 1)) < 1 / 3,
                       jax.random.randint(k_pre, (b, 1), 0, noise.prefix + 1), 0)
    k = jnp.arange(L)[None]
    mask = ((k >= prefix) & (k < length) & ok[:, None]).astype(jnp.float32)[..., None]  # (B, L, 1)
    # float32 throughout: with x64 on, float64 inputs would promote the convolutions to float64,
    # 3x slower per training step (measured: 2.8 s vs 0.9 s of simulation).
    return jnp.concatenate([v * mask, mask], axis=-1).astype(jnp.float32)


def family_space(spec: CNNSpec) -> ParamSpace:
    """The coordinates of a scene-conditioned network (``spec.family``): every family scene's
    :class:`ParamSpace` (k1, k2, phi, dt_release, with the same bounds)."""
    from galileo_jax.scene_family import SceneFamily, family_scene

    return ParamSpace.from_scene(family_scene(SceneFamily.from_dict(spec.family).middle()))


def family_prior(space: ParamSpace, features: jax.Array, key: jax.Array, slide_margin: float = 0.02) -> jax.Array:
    """One draw of theta per family scene (features (n, F) -> (n, d)): :func:`training_prior`
    with each scene's own ramp angle (object 1's friction below tan(angle) - ``slide_margin``,
    so it slides). Pure."""
    from galileo_jax.scene_family import family_angle

    theta = space.sample_prior(key, features.shape[0])
    return _k1_sliding(space, theta, key, jnp.tan(family_angle(features)) - slide_margin)


def simulate_family_examples(spec: CNNSpec, noise: NoiseModel, features: jax.Array, theta: jax.Array,
                             key: jax.Array, views: int = 1) -> jax.Array:
    """Network inputs (n * views, L, T + F + 1) float32 of a scene-conditioned network
    (``spec.family``) for scenes ``features`` (n, F) and parameters ``theta`` (n, d) (pure, jittable).

    One C MuJoCo rollout per row, each of its own scene
    (:func:`~galileo_jax.physics.simulate_family.family_rollout_poses`), released at
    ``release_offset`` + theta's ``dt_release`` after the window's start. Then, per view, a
    video as a camera would record it: frames at the scene's frame rate (feature ``fps``) from
    a random phase, object centres with position noise e ~ N(0, sd^2) per frame and trace (sd
    log-uniform on ``noise.position_sd``) and the velocities scaled by a camera scale error
    (``noise.scale_error``), resampled to the network's grid (``spec.fps``) by
    linear interpolation and differenced, as :func:`~galileo_jax.inference.cnn.family_network_input`
    resamples a tracked video; then cut and masked as :func:`simulate_examples` does (a valid
    length, a masked prefix for a third). A rollout that blew up gives an all-zero example
    (skipped by the loss). Rows are grouped by view (view-major).
    """
    from galileo_jax.physics.simulate import Trajectory, sample_poses
    from galileo_jax.physics.simulate_family import FAMILY_DT, family_rollout_poses
    from galileo_jax.scene_family import FEATURES, SceneFamily

    family = SceneFamily.from_dict(spec.family)
    space = family_space(spec)
    n = theta.shape[0]
    L, T, F = spec.n_samples, spec.n_traces, spec.n_scene
    grid_dt = 1.0 / spec.fps
    window = (L + 1) * grid_dt
    n_steps = int(math.ceil(window / FAMILY_DT)) + 1
    theta = jnp.asarray(theta, jnp.float64)
    features = jnp.asarray(features, jnp.float64)
    phys = space.physical(theta)
    poses = jax.vmap(lambda f, m, k: family_rollout_poses(f, m, k, n_steps))(features, phys.mass, phys.friction)
    release = spec.release_offset + space.release_offset(theta)  # (n,) s after the window's start
    fps_all = features[:, FEATURES.index("fps")]
    n_frames = int(math.ceil(window * float(family.upper[FEATURES.index("fps")]))) + 3
    b = n * views
    k_ph, k_sd, k_e, k_len, k_pre, k_has = jax.random.split(key, 6)
    poses, release, fps_b = (jnp.tile(a, (views,) + (1,) * (a.ndim - 1)) for a in (poses, release, fps_all))
    # frames from a random phase, the first one before the window's start
    phase = jax.random.uniform(k_ph, (b,), jnp.float64) / fps_b
    t_frames = phase[:, None] + (jnp.arange(n_frames)[None] - 1.0) / fps_b[:, None]  # (b, Nf)

    def centres(pose, t):
        return sample_poses(Trajectory(pose, FAMILY_DT), t)[..., :2].reshape(t.shape[0], -1)  # (Nf, T)

    pos = jax.vmap(centres)(poses, t_frames - release[:, None])
    lo, hi = math.log(noise.position_sd[0]), math.log(noise.position_sd[1])
    sd = jnp.exp(jax.random.uniform(k_sd, (b, 1, T), jnp.float64, minval=lo, maxval=hi))
    pos = pos + sd * jax.random.normal(k_e, pos.shape, jnp.float64)
    grid = jnp.arange(L + 1) * grid_dt
    on_grid = jax.vmap(lambda t, p: jax.vmap(lambda c: jnp.interp(grid, t, c), in_axes=1, out_axes=1)(p))(t_frames, pos)
    v = _with_scale_error(jnp.diff(on_grid, axis=1) / grid_dt, noise, key)  # (b, L, T)
    clean = jnp.diff(jax.vmap(centres)(poses, grid[None] - release[:, None]), axis=1) / grid_dt
    ok = jnp.all(jnp.isfinite(clean) & (jnp.abs(clean) <= MAX_SPEED), axis=(1, 2))
    v = jnp.where(ok[:, None, None], v, 0.0).astype(jnp.float32)
    length = jax.random.randint(k_len, (b, 1), noise.min_samples, L + 1)
    prefix = jnp.where(jax.random.uniform(k_has, (b, 1)) < 1 / 3,
                       jax.random.randint(k_pre, (b, 1), 0, noise.prefix + 1), 0)
    k = jnp.arange(L)[None]
    mask = ((k >= prefix) & (k < length) & ok[:, None]).astype(jnp.float32)[..., None]  # (b, L, 1)
    scene = jnp.broadcast_to(family.normalise(jnp.tile(features, (views, 1)))[:, None, :].astype(jnp.float32),
                             (b, L, F))
    return jnp.concatenate([v * mask, scene, mask], axis=-1).astype(jnp.float32)
