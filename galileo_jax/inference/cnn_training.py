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
    """

    position_sd: tuple[float, float] = (5e-5, 3e-3)
    min_samples: int = 24
    prefix: int = 6


def training_prior(space: ParamSpace, scene: Scene, key: jax.Array, n: int, slide_margin: float = 0.02) -> jax.Array:
    """n draws (n, d) of theta from the prior of ``space``, with object 1's friction below
    tan(ramp angle) - ``slide_margin`` when it starts on the ramp (so it slides: ``fit``
    rejects videos where it never moves). Pure; ``scene`` is read in Python only.
    """
    theta = space.sample_prior(key, n)
    if "k1" in space.names and scene.placement(0) == "ramp":
        j = space.index("k1")
        lo = space.lower[j]
        hi = min(space.upper[j], math.tan(scene.ramp.angle) - slide_margin)
        u = jax.random.uniform(jax.random.fold_in(key, 1), (n,), minval=1e-6, maxval=1 - 1e-6)
        theta = theta.at[:, j].set(lo + (hi - lo) * u)
    return theta


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
    velocity noise (e[k+1] - e[k]) * fps; a valid length uniform on [min_samples, L]; a masked
    prefix for a third of the copies. Rows of the output are grouped by view (view-major).
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
    v = prof + jnp.diff(e, axis=1) * spec.fps
    length = jax.random.randint(k_len, (b, 1), noise.min_samples, L + 1)
    prefix = jnp.where(jax.random.uniform(k_has, (b, 1)) < 1 / 3,
                       jax.random.randint(k_pre, (b, 1), 0, noise.prefix + 1), 0)
    k = jnp.arange(L)[None]
    mask = ((k >= prefix) & (k < length) & ok[:, None]).astype(jnp.float32)[..., None]  # (B, L, 1)
    # float32 throughout: with x64 on, float64 inputs would promote the convolutions to float64,
    # 3x slower per training step (measured: 2.8 s vs 0.9 s of simulation).
    return jnp.concatenate([v * mask, mask], axis=-1).astype(jnp.float32)
