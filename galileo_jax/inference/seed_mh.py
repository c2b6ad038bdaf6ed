"""The seed's sampler, kept as a named baseline (dissertation 4.2.5, Algorithm 1, Figure 4.16).

What the seed did, reproduced exactly except that all chains run together (one batched
rollout per step):

* Parameters: the scene's free physical parameters among (m1, k1, m2, k2), each in its prior
  box (the seed: (0, 1) for all four); known values come from the scene. Masses are sampled
  directly (not phi), as the seed did.
* 16 chains x 75 proposal steps, started at uniform random points.
* Proposal: each component uniform on [x - w, x + w], redrawn until inside the box, with
  w = 0.05 (times the box width) and w = 0.5 on every 20th step (i % 20 == 0, i = 1..75).
  Redrawing a uniform until it lands inside equals drawing it uniformly on
  [max(x - w, lo), min(x + w, hi)], which is what is done here.
* Decision: accept when the similarity ratio L'/L >= 1 (for the log-similarity of eq. 4.3,
  log L' >= log L; for EMD/RMS, S' >= S), otherwise accept with probability 0.5 (a coin
  toss, NOT the Metropolis rule: the chains do not sample the posterior).
* Answer: the single proposal with the highest similarity over all chains and steps
  (section "Selecting a result").

The similarity defaults to the seed's ``"seed_gaussian"`` (eq. 4.3 with SD 0.05 m/s); any
kind of :mod:`galileo_jax.likelihood` can be chosen for benchmarks.
"""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from galileo_jax.inference.problem import map_batch
from galileo_jax.likelihood import make_likelihood
from galileo_jax.physics.model import NOMINAL_MASS
from galileo_jax.physics.simulate import PhysParams

#: The seed's settings (dissertation 4.2.5).
SEED_CHAINS, SEED_STEPS, SEED_WIDTH, SEED_WIDE, SEED_WIDE_EVERY = 16, 75, 0.05, 0.5, 20


class SeedResult(NamedTuple):
    """Output of :func:`run_seed_mh` (NumPy arrays).

    Attributes:
        names: sampled physical parameter names, e.g. ("m1", "k1", "m2", "k2").
        best: {"m1", "k1", "m2", "k2" (those that exist), "phi" (two objects)}: the answer,
            known values filled in from the scene.
        best_similarity: similarity of the answer.
        proposals: (chains, steps, d) every proposal.
        proposal_similarity: (chains, steps) their similarities.
        chain: (chains, steps + 1, d) the chain states (start included; a rejection repeats).
        chain_similarity: (chains, steps + 1) similarity of the chain states.
        accepted: (chains, steps) bool, which proposals were saved.
        likelihood: the similarity kind used.
        time_s: wall time in s (including compilation).
    """

    names: tuple[str, ...]
    best: dict
    best_similarity: float
    proposals: np.ndarray
    proposal_similarity: np.ndarray
    chain: np.ndarray
    chain_similarity: np.ndarray
    accepted: np.ndarray
    likelihood: str
    time_s: float


def _physical(scene, names, x):
    """PhysParams (B, n) from sampled physical values x (B, d) and the scene's known values."""
    b = x.shape[0]
    mass, fric = [], []
    for i, obj in enumerate(scene.objects, start=1):
        mass.append(x[:, names.index(f"m{i}")] if f"m{i}" in names else jnp.full((b,), obj.mass or NOMINAL_MASS, x.dtype))
        fric.append(x[:, names.index(f"k{i}")] if f"k{i}" in names else jnp.full((b,), obj.friction, x.dtype))
    return PhysParams(jnp.stack(mass, -1), jnp.stack(fric, -1))


def _similarity_fn(engine, scene, names):
    """Pure batched similarity ``f(x (B, d), data) -> (B,)`` of physical points x (NaN -> -inf)."""

    def similarity(x, data):
        s = map_batch(lambda p: data.likelihood(engine.profile_physical(p, data)), _physical(scene, names, x),
                      engine.max_batch)
        return jnp.where(jnp.isnan(s), -jnp.inf, s)

    return similarity


def _seed_runner(engine, scene, names, lo: np.ndarray, hi: np.ndarray):
    """Pure ``run(carry, keys, idx, data)``: the seed's steps under ``lax.scan`` (Algorithm 1)."""
    similarity = _similarity_fn(engine, scene, names)
    lo_j, hi_j = jnp.asarray(lo), jnp.asarray(hi)

    def run(carry, keys, idx, data):
        def step(carry, inp):
            x, s = carry
            key, i = inp
            k_u, k_c = jax.random.split(key)
            w = jnp.where(i % SEED_WIDE_EVERY == 0, SEED_WIDE, SEED_WIDTH) * (hi_j - lo_j)
            a, b = jnp.maximum(x - w, lo_j), jnp.minimum(x + w, hi_j)
            x_new = a + jax.random.uniform(k_u, x.shape, x.dtype) * (b - a)
            s_new = similarity(x_new, data)
            accept = (s_new >= s) | (jax.random.uniform(k_c, s.shape) < 0.5)
            x = jnp.where(accept[:, None], x_new, x)
            s = jnp.where(accept, s_new, s)
            return (x, s), (x_new, s_new, accept, x, s)

        return jax.lax.scan(step, carry, (keys, idx))

    return run


def run_seed_mh(problem, rng_key: jax.Array, *, n_chains: int = SEED_CHAINS, n_steps: int = SEED_STEPS,
                likelihood: str = "seed_gaussian", chunk: int = 15, progress: bool = True) -> SeedResult:
    """Run the seed's coin-toss sampler and return its best proposal (module docstring).

    Arguments:
        problem: a :class:`~galileo_jax.inference.problem.Problem` (scene, observation, simulator).
        rng_key: PRNG key.
        n_chains: chains (seed: 16).
        n_steps: proposal steps per chain (seed: 75).
        likelihood: similarity kind (``galileo_jax.likelihood.KINDS``; seed: "seed_gaussian").
        chunk: steps per jitted scan (progress granularity).
        progress: show a tqdm progress bar.

    Returns:
        :class:`SeedResult`.

    Raises:
        ValueError: n_chains or n_steps < 1, unknown likelihood, or no free parameter.
    """
    if n_chains < 1 or n_steps < 1 or chunk < 1:
        raise ValueError(f"need n_chains, n_steps, chunk >= 1; got {n_chains}, {n_steps}, {chunk}")
    scene = problem.scene
    names = tuple(scene.free_parameters())
    if not names:
        raise ValueError(f"scene {scene.name!r} has no free parameter")
    lik = make_likelihood(problem.observation, likelihood, problem.likelihood.sd_model,
                          n_samples=problem.likelihood.obs.shape[1])
    data = problem.data._replace(likelihood=lik)
    lo = np.array([scene.priors.mass[0] if n[0] == "m" else scene.priors.friction[0] for n in names], np.float64)
    hi = np.array([scene.priors.mass[1] if n[0] == "m" else scene.priors.friction[1] for n in names], np.float64)
    # pure functions of (x, data): they read only the scene and the engine (the static key)
    run_data = problem.jitted(("seed_mh", likelihood), _seed_runner(problem.engine, scene, names, lo, hi))
    start_data = problem.jitted(("seed_similarity", likelihood), _similarity_fn(problem.engine, scene, names))
    run = lambda carry, keys, idx: run_data(carry, keys, idx, data)  # noqa: E731
    start_sim = lambda x: start_data(x, data)  # noqa: E731
    lo_j, hi_j = jnp.asarray(lo), jnp.asarray(hi)
    n_chunks = math.ceil(n_steps / chunk)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=n_steps, desc="seed-mh", unit="step", leave=False)
    t0 = time.perf_counter()
    k0, k_run = jax.random.split(rng_key)
    x0 = lo_j + jax.random.uniform(k0, (n_chains, len(names))) * (hi_j - lo_j)
    s0 = start_sim(x0)
    carry = (x0, s0)
    keys = jax.random.split(k_run, n_chunks * chunk)
    outs = []
    for c in range(n_chunks):
        idx = jnp.arange(c * chunk + 1, (c + 1) * chunk + 1)
        carry, out = run(carry, keys[c * chunk:(c + 1) * chunk], idx)
        outs.append(jax.tree_util.tree_map(np.asarray, out))
        if bar is not None:
            bar.update(min(chunk, n_steps - c * chunk))
    if bar is not None:
        bar.close()
    x_prop, s_prop, acc, x_chain, s_chain = (np.concatenate([o[k] for o in outs])[:n_steps] for k in range(5))
    x_prop = np.transpose(x_prop, (1, 0, 2))
    s_prop = s_prop.T
    chain = np.concatenate([np.asarray(x0)[:, None], np.transpose(x_chain, (1, 0, 2))], axis=1)
    chain_sim = np.concatenate([np.asarray(s0)[:, None], s_chain.T], axis=1)
    # The answer: the best of all simulated points (starts and proposals).
    all_x = np.concatenate([np.asarray(x0)[:, None], x_prop], axis=1).reshape(-1, len(names))
    all_s = np.concatenate([np.asarray(s0)[:, None], s_prop], axis=1).reshape(-1)
    j = int(np.argmax(all_s))
    p = _physical(scene, names, jnp.asarray(all_x[j:j + 1]))
    best = {}
    for i in range(scene.n_objects):
        best[f"m{i + 1}"] = float(p.mass[0, i])
        best[f"k{i + 1}"] = float(p.friction[0, i])
    if scene.n_objects == 2:
        best["phi"] = (best["m1"] - best["m2"]) / (best["m1"] + best["m2"])
    return SeedResult(names, best, float(all_s[j]), x_prop.astype(np.float64), s_prop.astype(np.float64),
                      chain.astype(np.float64), chain_sim.astype(np.float64), acc.T, likelihood, time.perf_counter() - t0)
