"""Starting points of the multi-start fits: Latin-hypercube points over the prior box
(:func:`latin_hypercube_starts`), the best of them kept apart from each other
(:func:`diverse_best`), and a given start moved inside the bounds (:func:`start_point`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

#: Starting points of the release-time correction are drawn from this fraction of its range,
#: around 0 (the tracker's estimate is rarely more than a frame off; a wide draw only adds
#: starts in the k1 / release-time valley, where LM is slow).
RELEASE_START_FRACTION = 0.1


def latin_hypercube_starts(problem, key: jax.Array, n: int, margin: float = 0.05,
                           around: np.ndarray | None = None, spread: float | jax.Array = 0.25) -> jax.Array:
    """n starting points theta (n, d), a Latin hypercube over the bounds (shrunk by ``margin``;
    a release-time coordinate over :data:`RELEASE_START_FRACTION` of its range around 0).

    With ``around`` (d,), every coordinate except the effect parameters is drawn within
    +-``spread`` (scalar or (d,)) of its range around ``around`` (clipped to the bounds): a local screen for
    refitting a model plus one effect near the model's estimate, where the effect's value is
    unknown but the other parameters move only as far as the effect makes them."""
    d = problem.dim
    k_perm, k_u = jax.random.split(key)
    perms = jnp.stack([jax.random.permutation(k, n) for k in jax.random.split(k_perm, d)], axis=1)
    u = (perms + jax.random.uniform(k_u, (n, d))) / n
    u = margin + (1.0 - 2.0 * margin) * u
    lo, hi = problem.space._bounds()
    release = jnp.asarray([k == "release" for k in problem.space.kinds])
    u = jnp.where(release, 0.5 + RELEASE_START_FRACTION * (u - 0.5), u)
    if around is None:
        return lo + (hi - lo) * u
    effect = jnp.asarray([k == "effect" for k in problem.space.kinds])
    a_lo = jnp.maximum(lo, jnp.asarray(around) - spread * (hi - lo))
    a_hi = jnp.minimum(hi, jnp.asarray(around) + spread * (hi - lo))
    a_lo, a_hi = a_lo + margin * (a_hi - a_lo), a_hi - margin * (a_hi - a_lo)
    return jnp.where(effect, lo + (hi - lo) * u, a_lo + (a_hi - a_lo) * (u - margin) / (1.0 - 2.0 * margin))


#: Screened starts closer than this (Euclidean, in the prior box scaled to the unit cube) to a
#: better one already chosen are passed over (:func:`diverse_best`).
START_SEPARATION = 0.25


def unit_box(theta, lo, hi, kinds=None):
    """(..., d') points ``theta`` (..., d) scaled to the unit cube of the box ``lo``..``hi``,
    release-time coordinates (``kinds`` "release") left out: where :func:`diverse_best`
    measures distances."""
    lo, hi = jnp.asarray(lo), jnp.asarray(hi)
    u = (jnp.asarray(theta) - lo) / jnp.where(hi > lo, hi - lo, 1.0)
    if kinds is not None:
        u = u[..., np.array([k != "release" for k in kinds], bool)]
    return u


def diverse_best(u, loglik, n: int, separation: float = START_SEPARATION) -> jax.Array:
    """Indices of ``n`` starting points among screened candidates: the best by log-likelihood
    first, then each next-best candidate at least ``separation`` from every one already chosen;
    candidates whose rollout failed (non-finite log-likelihood) are not spread to; where too
    few are that far apart, the best of the rest fill up. Pure JAX (jittable, vmappable over
    videos: :func:`~galileo_jax.inference.batch.solve_batch` uses it too).

    The likelihood of a screen point is a poor guide to which basin LM will end in: on a
    two-object video the best screened points often share one wrong mode (object 2 stopping
    early, high k2 with a light object 1, ``benchmarks/results/fit_world.md``) and all of the
    4 best starts end there; spreading the starts keeps one in each region.

    Args:
        u: (S, d') candidate points in the unit cube (:func:`unit_box`).
        loglik: (S,) their log-likelihoods.
        n: starts wanted (<= S).
        separation: the least distance between chosen starts.

    Returns:
        (n,) int indices into the candidates, best first.
    """
    ll = jnp.asarray(loglik)
    finite = jnp.isfinite(ll)
    order = jnp.argsort(-jnp.where(finite, ll, -jnp.inf), stable=True)
    u_s, fin_s = jnp.asarray(u)[order], finite[order]

    def pick(t, carry):
        chosen, picks, dist = carry
        spread = fin_s & ~chosen & (dist >= separation)
        j = jnp.where(spread.any(), jnp.argmax(spread), jnp.argmax(~chosen))
        dist = jnp.minimum(dist, jnp.linalg.norm(u_s - u_s[j], axis=-1))
        return chosen.at[j].set(True), picks.at[t].set(j), dist

    init = (jnp.zeros(len(ll), bool), jnp.zeros(n, int), jnp.full(len(ll), jnp.inf))
    _, picks, _ = jax.lax.fori_loop(0, n, pick, init)
    return order[picks]


#: Fraction of a parameter's range kept between an ``init`` start and the bounds (z = +-4.6).
INIT_MARGIN = 0.01


def start_point(space, theta, what: str = "init") -> np.ndarray:
    """A user's start ``theta`` (d,) checked against ``space`` and moved :data:`INIT_MARGIN` of
    the range inward from the bounds (the logistic transform is flat there, so a local
    optimiser could not leave a start on a bound).

    Raises:
        ValueError: wrong shape, or values outside the bounds (the message names ``what``).
    """
    theta = np.asarray(theta, np.float64)
    if theta.shape != (space.dim,):
        raise ValueError(f"{what} must have shape ({space.dim},) for parameters {list(space.names)}, got {theta.shape}")
    lo, hi = np.asarray(space.lower, np.float64), np.asarray(space.upper, np.float64)
    if not np.all((theta >= lo) & (theta <= hi)):
        raise ValueError(f"{what} {theta.tolist()} is outside the bounds {list(zip(space.lower, space.upper))}")
    return np.clip(theta, lo + INIT_MARGIN * (hi - lo), hi - INIT_MARGIN * (hi - lo))
