"""Random-walk Metropolis-Hastings with many chains, in the BlackJAX init/step style.

The kernel (:func:`build_kernel`) is pure: given a key, a state and the log density it proposes
x' = x + L eps, eps ~ N(0, I) (symmetric, so the Hastings ratio is 1) and accepts when
log u < log p(x') - log p(x), u ~ U(0, 1) (Metropolis et al. 1953; Hastings 1970). States may
carry a leading chain axis: all chains are proposed together and the density is called ONCE
per step on the (chains, d) batch, i.e. one vmapped MJX rollout per step.

:func:`run_mh` samples the posterior of a :class:`~galileo_jax.inference.problem.Problem` in its
unconstrained coordinates z:

* Initialisation: prior draws (default), or a given point (e.g. ``--init cnn``) with jitter.
* Warm-up (discarded), first annealed: during the first ``anneal`` fraction of the warm-up the
  likelihood is tempered, log p_beta = log prior + beta log lik, with beta rising geometrically
  from ``beta0`` to 1, so chains started from the prior can cross between the basins of the
  rough, multimodal likelihood. Each rise of beta reweights the chains by
  exp(delta_beta log lik) and resamples them (systematic) when the effective sample size
  falls below 90% of the chains: the warm-up is a small sequential Monte Carlo sampler with MH
  moves (Del Moral, Doucet & Jasra 2006), which moves chains out of basins tens of nats
  below the best instead of leaving them stuck there.
  Throughout the warm-up the proposal adapts as in adaptive Metropolis (Haario, Saksman &
  Tamminen 2001): its covariance is s^2 Sigma, with Sigma the within-chain sample covariance
  of the last chunk's draws pooled over chains, and the global scale s adapted by a
  multiplicative step log s += 0.7 log((a + 0.01) / (a* + 0.01)) (clipped to [-2, 1]) after
  every chunk (Sigma is renormalised to keep its determinant, so s alone sets the size), towards an acceptance rate
  a* = 0.3 (Roberts & Rosenthal 2001: 0.234 as d -> inf, ~0.3 for d = 3-4, 0.44 for d = 1).
  The shape Sigma is the covariance of ALL chains' draws of the chunk (within- plus
  between-chain; ``adapt="population"``, the particle covariance an SMC sampler's MH moves use,
  Chopin 2002), not the within-chain covariance alone (``adapt="within"``): over a 20-step chunk
  a chain's own draws mostly echo the proposal it was made with, while the population spans
  the posterior's ridge.
  In untempered chunks before 3/4 of the warm-up, chains stuck far below the best (log
  density more than ``reset_threshold`` nats under the best chain, e.g. in a secondary
  basin) are restarted at copies of good chains.
* Jumps: the proposal is a mixture (Tierney 1994): with probability 1 - ``jump`` the adapted
  local walk above, with probability ``jump`` a population-wide step N(0, 2.38^2/d Sigma_pop)
  with Sigma_pop the population covariance of the last chunk (not scaled by s). Why: the
  log-likelihood is rough around contact events (the simulated impact responds
  pseudo-randomly to parameter changes; measured on a rendered 20 degree video, log L moves by
  5-20 nats between k1 values 0.0001 apart, inside a posterior SD of 0.0007; a wider model
  error at the impact does not remove it, a finer physics step shrinks it: along k1 2.33 / 1.01
  / 0.58 nats off a quadratic with 8 / 16 / 32 steps a frame on another 20 degree video,
  ``benchmarks/results/mh_roughness.md``, where the sampler reaches R-hat 1.045 and ESS 378 on
  a Gaussian of the same covariance and 1.087 and 159 on the video). The local walk adapts
  to the spikes' width and each chain stays on its own spike (R-hat 4.5 with 16 chains x 400
  draws); the wide component hops between spikes along the posterior's extent. Measured on the
  5 rendered videos whose R-hat was worst (16 chains, 300 + 400 steps,
  ``benchmarks/results/mh_mixing.md``): worst R-hat per video 5.26, 1.67, 1.10, 1.68, 1.13
  and median smallest bulk ESS 26 with the local walk alone; 1.74, 1.25, 1.08, 1.12, 1.14 and
  ESS 82 with ``jump=0.5``, at the same time per step. R-hat is still above 1.1 on 4 of 5.
* Independence proposals (``independent``, the probability of this third component; the two
  walks share the rest as ``jump`` says): x' drawn from a multivariate Student-t
  (:data:`INDEPENDENT_DF` degrees of freedom) with the mean and covariance of the population's
  draws of the last :data:`INDEPENDENT_CHUNKS` untempered warm-up chunks, whatever the chain's
  current point, accepted with the independence sampler's Hastings ratio (Tierney 1994;
  adapted during warm-up only, as Holden, Hauge & Holden 2009 adapt theirs). Where the
  posterior is about as wide as that t (the near-Gaussian posteriors this likelihood has
  under its roughness), an accepted draw is nearly independent of the chain's past: a walk
  needs many steps to cross the posterior, this needs one, and a chain sitting on a spike of
  the rough likelihood leaves it as soon as a proposal lands on an equally good one anywhere.
  Measured with 16 chains, 300 + 400 steps on Gaussians of a rendered video's posterior
  covariance (``mh_roughness.py``'s targets, two seeds each), ``independent`` 0 -> 0.7 -> 0.9:
  smallest bulk ESS 330-336 -> 2457-2820 -> 3617-3659 (R-hat 1.05 -> 1.004 -> 1.003); with 1 nat
  of roughness 92-185 -> 680-976 -> 1037-1068 (R-hat 1.07-1.13 -> 1.02-1.03 -> 1.02); with 2
  nats 24-30 -> 93-122 -> 80-98 (R-hat 1.53-1.77 -> 1.12-1.15 -> 1.14). On the rendered
  videos of ``mh_mixing.md``, with the likelihood smoothed by a rollout ensemble of 2
  (``fit``'s mh default): worst R-hat per video 1.04, 1.02, 1.01, 1.02, 1.01 and median
  smallest ESS 918 at 0.9. The proposals start
  once the annealing has ended: fitted to the tempered population and proposed while it was
  being reweighted, they left the chains of samplers ramp_20 video_1 (at 0.9) in a secondary
  basin at k2 ~0.95 (truth ~0.6), acceptance 0.03, R-hat 3.2; from the untempered draws the
  same run gave R-hat 1.04.
* Sampling: the proposal is frozen, so the chains are exact MH chains for the posterior.

Chunks of ``chunk`` steps run as one jitted ``lax.scan``; the progress bar and the adaptation
update between chunks.
"""

from __future__ import annotations

import math
import time
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from galileo_jax.inference.problem import map_batch

#: Default target acceptance rate during warm-up (Roberts & Rosenthal 2001).
TARGET_ACCEPTANCE = 0.3
#: Degrees of freedom of the independence proposal (:func:`run_mh`, ``independent``): heavy
#: tails (variance 5/3 of its scale matrix), so that it covers a posterior wider than the draws
#: it was fitted to.
INDEPENDENT_DF = 5.0
#: Warm-up chunks (at the current temperature) whose draws the independence proposal is fitted to.
INDEPENDENT_CHUNKS = 5
#: Random-walk scale: proposal covariance (RW_SCALE^2 / d) Sigma for a d-dimensional posterior
#: of covariance Sigma (Roberts, Gelman & Gilks 1997; Gelman et al., BDA3 12.2).
RW_SCALE = 2.38


class RWState(NamedTuple):
    """State of random-walk chains.

    Attributes:
        position: (..., d) current points (unconstrained z).
        logdensity: (...) log density at ``position``.
    """

    position: jax.Array
    logdensity: jax.Array


class RWInfo(NamedTuple):
    """Diagnostics of one step (never fed back into the kernel).

    Attributes:
        acceptance_rate: (...) min(1, p(x') / p(x)), the MH acceptance probability.
        is_accepted: (...) bool, whether the proposal was accepted.
        proposal: the proposed :class:`RWState`.
        component: (...) int, which component of a mixture proposal made the proposal (0 for
            a single Gaussian).
    """

    acceptance_rate: jax.Array
    is_accepted: jax.Array
    proposal: RWState
    component: jax.Array


class IndependentProposal(NamedTuple):
    """A multivariate Student-t proposal that ignores the current point (an independence
    sampler's proposal, Tierney 1994; heavy-tailed so that it covers the posterior's tails).

    Attributes:
        mean: (d,) its centre (z).
        chol: (d, d) lower-triangular factor of its scale matrix (z).
        df: degrees of freedom (> 0).
    """

    mean: jax.Array
    chol: jax.Array
    df: float


def independent_logq(x: jax.Array, proposal: IndependentProposal) -> jax.Array:
    """Log density (..., ) of the Student-t ``proposal`` at ``x`` (..., d), up to a constant
    (the constant cancels in the Hastings ratio)."""
    dev = jnp.asarray(x) - proposal.mean
    white = jax.scipy.linalg.solve_triangular(proposal.chol, dev[..., None], lower=True)[..., 0]
    d = dev.shape[-1]
    return -0.5 * (proposal.df + d) * jnp.log1p(jnp.sum(white**2, axis=-1) / proposal.df)


class RandomWalk(NamedTuple):
    """``init(position) -> RWState`` and ``step(rng_key, state) -> (RWState, RWInfo)``."""

    init: Callable[[jax.Array], RWState]
    step: Callable[[jax.Array, RWState], tuple[RWState, RWInfo]]


def _check_scale(scale, d: int) -> None:
    shape = tuple(np.shape(scale))
    if not (shape in ((), (d,), (d, d)) or (len(shape) == 3 and shape[1:] == (d, d))):
        raise ValueError(f"scale must be a scalar, ({d},) per-dimension SDs, a ({d}, {d}) Cholesky factor or "
                         f"(K, {d}, {d}) factors of a mixture, got shape {shape}")


def init(position: jax.Array, logdensity_fn: Callable[[jax.Array], jax.Array]) -> RWState:
    """Initial state: ``RWState(position, logdensity_fn(position))`` (NaN density -> -inf)."""
    position = jnp.asarray(position)
    ld = logdensity_fn(position)
    return RWState(position, jnp.where(jnp.isnan(ld), -jnp.inf, ld))


def build_kernel() -> Callable:
    """Return the random-walk MH kernel ``kernel(rng_key, state, logdensity_fn, scale, weights=None)``.

    ``scale`` is a scalar or (d,) proposal SD, a (d, d) lower-triangular L with proposal
    covariance L L^T, or (K, d, d) factors of a mixture of K Gaussian random walks: each chain
    picks component k with probability ``weights[k]`` ((K,), summing to 1) independently of its
    state, so the proposal stays symmetric and the Hastings ratio 1 (a mixture of MH kernels,
    Tierney 1994). ``logdensity_fn`` maps positions (..., d) to (...). Returns
    ``(new_state, info)``; acceptance is log u < logdensity(x') - logdensity(x), so a proposal
    with a higher density is always accepted and a NaN density is treated as -inf.

    With ``independent`` (an :class:`IndependentProposal`) the mixture has one more component,
    the last (``weights`` then has K + 1 entries): x' drawn from that Student-t whatever x is,
    accepted with the independence sampler's Hastings ratio, log u < log p(x') - log p(x) +
    log q(x) - log q(x') (Tierney 1994). Where q resembles the posterior its draws are nearly
    independent of the chain's past, whatever the roughness of the density in between.
    """

    def kernel(rng_key: jax.Array, state: RWState, logdensity_fn: Callable, scale: jax.Array,
               weights: jax.Array | None = None, independent: IndependentProposal | None = None
               ) -> tuple[RWState, RWInfo]:
        k_prop, k_acc, k_comp, k_t = jax.random.split(rng_key, 4)
        x = state.position
        scale = jnp.asarray(scale, x.dtype)
        eps = jax.random.normal(k_prop, x.shape, x.dtype)
        component = jnp.zeros(x.shape[:-1], jnp.int32)
        n_rw = scale.shape[0] if scale.ndim == 3 else 1
        n_comp = n_rw + (independent is not None)
        if n_comp > 1:
            w = jnp.full((n_comp,), 1.0 / n_comp) if weights is None else jnp.asarray(weights)
            component = jax.random.choice(k_comp, n_comp, x.shape[:-1], p=w)
        if scale.ndim == 3:
            step = jnp.einsum("...ij,...j->...i", scale[jnp.minimum(component, n_rw - 1)], eps)
        else:
            step = eps @ scale.T if scale.ndim == 2 else eps * scale
        x_new = x + step
        log_hastings = jnp.zeros(x.shape[:-1], x.dtype)
        if independent is not None:
            df = jnp.asarray(independent.df, x.dtype)
            gamma = jax.random.gamma(k_t, 0.5 * df, x.shape[:-1], x.dtype) / (0.5 * df)  # chi2_df / df
            far = independent.mean + (eps @ jnp.asarray(independent.chol, x.dtype).T) / jnp.sqrt(gamma)[..., None]
            is_far = component == n_rw
            x_new = jnp.where(is_far[..., None], far, x_new)
            log_hastings = jnp.where(is_far, independent_logq(x, independent) - independent_logq(x_new, independent),
                                     0.0)
        ld_new = logdensity_fn(x_new)
        ld_new = jnp.where(jnp.isnan(ld_new), -jnp.inf, ld_new)
        delta = ld_new - state.logdensity + log_hastings
        delta = jnp.where(jnp.isnan(delta), -jnp.inf, delta)  # -inf - -inf
        log_u = jnp.log(jax.random.uniform(k_acc, state.logdensity.shape, x.dtype))
        accept = log_u < delta
        new = RWState(jnp.where(accept[..., None], x_new, x), jnp.where(accept, ld_new, state.logdensity))
        info = RWInfo(jnp.exp(jnp.minimum(delta, 0.0)), accept, RWState(x_new, ld_new), component)
        return new, info

    return kernel


def random_walk(logdensity_fn: Callable[[jax.Array], jax.Array], scale, dim: int | None = None,
                weights=None) -> RandomWalk:
    """Top-level API: close over the density and the proposal scale.

    Arguments:
        logdensity_fn: (..., d) -> (...) log density (batched over chains).
        scale: proposal scale as in :func:`build_kernel`.
        dim: d, to validate ``scale`` in Python (optional).
        weights: (K,) component probabilities of a mixture ``scale`` (K, d, d); None: equal.

    Raises:
        ValueError: ``scale`` has a shape other than (), (d,), (d, d), (K, d, d).
    """
    if dim is not None:
        _check_scale(scale, dim)
    kernel = build_kernel()

    def init_fn(position):
        return init(position, logdensity_fn)

    def step_fn(rng_key, state):
        return kernel(rng_key, state, logdensity_fn, scale, weights)

    return RandomWalk(init_fn, step_fn)


def sample_chunk(kernel: Callable, logdensity_fn: Callable, rng_key: jax.Array, state: RWState, chol: jax.Array,
                 n_steps: int, weights: jax.Array | None = None, independent: IndependentProposal | None = None
                 ) -> tuple[RWState, tuple[RWState, RWInfo]]:
    """Run ``n_steps`` kernel steps under ``lax.scan`` (pure; jit it). Returns the last state
    and the per-step (state, info) with a leading step axis."""

    def one(state, key):
        state, info = kernel(key, state, logdensity_fn, chol, weights, independent)
        return state, (state, info)

    return jax.lax.scan(one, state, jax.random.split(rng_key, n_steps))


class MHResult(NamedTuple):
    """Output of :func:`run_mh` (NumPy arrays).

    Attributes:
        names: parameter names (d,).
        theta: (chains, draws, d) posterior draws in physical coordinates.
        z: (chains, draws, d) the same draws in unconstrained coordinates.
        loglik: (chains, draws) log-likelihood of each draw (nats).
        logdensity: (chains, draws) log posterior density (z coordinates) of each draw.
        acceptance: (chains,) acceptance rate during sampling.
        warmup_acceptance: mean acceptance rate over the last warm-up chunk.
        proposal_chol: (d, d) Cholesky factor of the final proposal covariance (z).
        n_resets: chains restarted during warm-up.
        n_resampled: SMC resampling events during the annealed warm-up.
        seconds_per_step: wall time per step of all chains in the sampling phase.
        time_s: total wall time (s), including compilation.
    """

    names: tuple[str, ...]
    theta: np.ndarray
    z: np.ndarray
    loglik: np.ndarray
    logdensity: np.ndarray
    acceptance: np.ndarray
    warmup_acceptance: float
    proposal_chol: np.ndarray
    n_resets: int
    n_resampled: int
    seconds_per_step: float
    time_s: float

    @property
    def best_theta(self) -> np.ndarray:
        """(d,) the draw with the highest log-likelihood."""
        i = np.unravel_index(np.argmax(self.loglik), self.loglik.shape)
        return self.theta[i]


def _pooled_within_cov(x: np.ndarray) -> np.ndarray:
    """Within-chain covariance of (chains, steps, d) draws, pooled over chains."""
    c, n, d = x.shape
    dev = x - x.mean(axis=1, keepdims=True)
    return np.einsum("cni,cnj->ij", dev, dev) / max(c * (n - 1), 1)


def _population_cov(x: np.ndarray) -> np.ndarray:
    """Covariance of all (chains, steps, d) draws together: within- plus between-chain."""
    flat = x.reshape(-1, x.shape[-1])
    return np.atleast_2d(np.cov(flat, rowvar=False))


def _chunk_runner(problem, chunk: int) -> Callable:
    """Pure ``run(key, state, chol, beta, data)``: ``chunk`` tempered MH steps (reads only static parts)."""
    kernel = build_kernel()
    space, loglik_fn, max_batch = problem.space, problem.loglik_fn, problem.max_batch

    def run(key, state, chol, weights, independent, beta, data):
        def logdensity_fn(zb):
            ll = map_batch(lambda z: loglik_fn(z, data), zb, max_batch)
            lp = space.log_prior(zb) + beta * ll
            return jnp.where(jnp.isnan(lp), -jnp.inf, lp)

        return sample_chunk(kernel, logdensity_fn, key, state, chol, chunk, weights, independent)

    return run


def run_mh(problem, rng_key: jax.Array, *, n_chains: int = 16, n_warmup: int = 200, n_samples: int = 200,
           init_theta: np.ndarray | None = None, init_sd: float = 0.1, target_acceptance: float = TARGET_ACCEPTANCE,
           anneal: float = 0.5, beta0: float = 0.01, resample_ess: float = 0.9, reset_threshold: float = 10.0,
           chunk: int = 20, adapt: str = "population", jump: float = 0.5, independent: float = 0.9,
           independent_df: float = INDEPENDENT_DF, progress: bool = True) -> MHResult:
    """Sample the posterior of ``problem`` with adaptive random-walk MH (module docstring).

    Arguments:
        problem: a :class:`~galileo_jax.inference.problem.Problem` (or a joint or fixed
            problem: uses ``space``, ``loglik_fn``, ``max_batch``, ``data`` and ``jitted``).
        rng_key: PRNG key.
        n_chains: chains advanced together (one batched density call per step).
        n_warmup: warm-up steps (annealing and adaptation; discarded).
        n_samples: kept steps per chain.
        init_theta: None (prior draws), a (d,) point (chains start at z(point) + init_sd * N(0, I))
            or (n_chains, d) starting points, in physical coordinates.
        init_sd: initial proposal SD in z (and the jitter around ``init_theta``).
        target_acceptance: warm-up acceptance target in (0, 1).
        anneal: fraction of the warm-up chunks in which the likelihood is tempered,
            log p_beta = log prior + beta log lik with beta rising geometrically from ``beta0``
            to 1 (0 disables annealing; use it with ``init_theta`` near the optimum).
        beta0: first inverse temperature, in (0, 1].
        resample_ess: resample the chains at a rise of beta when the effective sample size of
            the incremental weights is below ``resample_ess * n_chains`` (1 = always).
        reset_threshold: nats below the best chain at which a chain is restarted at a copy of
            a good chain, in untempered warm-up chunks before 3/4 of the warm-up
            (``inf`` disables restarts).
        chunk: steps per jitted scan (progress/adaptation granularity). Step counts are
            rounded up to whole chunks.
        adapt: "population" (the proposal's shape from all chains' draws) or "within" (from
            each chain's own draws, pooled), module docstring.
        jump: probability in [0, 1) of a population-wide jump proposal (module docstring); 0
            gives the local adaptive walk alone.
        independent: probability in [0, 1) of an independence proposal (module docstring,
            "Independence proposals"): a Student-t with ``independent_df`` degrees of freedom
            fitted to the population's recent draws; the walks share the rest as ``jump`` says.
        independent_df: its degrees of freedom (> 2).
        progress: show a tqdm progress bar.

    Returns:
        :class:`MHResult`.

    Raises:
        ValueError: bad counts, acceptance target, annealing, ``adapt`` or ``jump`` settings, or
            ``init_theta`` shape/bounds.
    """
    space = problem.space
    d = space.dim
    if n_chains < 2:
        raise ValueError(f"n_chains must be >= 2 (R-hat needs several chains), got {n_chains}")
    if n_samples < 1 or n_warmup < 0 or chunk < 1:
        raise ValueError(f"need n_samples >= 1, n_warmup >= 0, chunk >= 1; got {n_samples}, {n_warmup}, {chunk}")
    if not 0.0 < target_acceptance < 1.0:
        raise ValueError(f"target_acceptance must be in (0, 1), got {target_acceptance}")
    if not init_sd > 0:
        raise ValueError(f"init_sd must be > 0, got {init_sd}")
    if adapt not in ("population", "within"):
        raise ValueError(f"adapt must be 'population' or 'within', got {adapt!r}")
    if not 0.0 <= jump < 1.0:
        raise ValueError(f"jump must be in [0, 1), got {jump}")
    if not 0.0 <= independent < 1.0 or not independent_df > 2.0:
        raise ValueError(f"need 0 <= independent < 1 and independent_df > 2, got {independent}, {independent_df}")
    if not (0.0 <= anneal <= 1.0 and 0.0 < beta0 <= 1.0):
        raise ValueError(f"need 0 <= anneal <= 1 and 0 < beta0 <= 1, got anneal={anneal}, beta0={beta0}")

    k_init, k_jit, k_run = jax.random.split(rng_key, 3)
    if init_theta is None:
        z0 = space.to_unconstrained(space.sample_prior(k_init, n_chains))
    else:
        th = np.asarray(init_theta, np.float64)
        if th.shape not in ((d,), (n_chains, d)):
            raise ValueError(f"init_theta must have shape ({d},) or ({n_chains}, {d}), got {th.shape}")
        lo, hi = np.asarray(space.lower), np.asarray(space.upper)
        if not np.all((th > lo) & (th < hi)):
            raise ValueError(f"init_theta is outside the bounds {list(zip(space.lower, space.upper))}")
        z0 = jnp.broadcast_to(space.to_unconstrained(jnp.asarray(th, jnp.float64)), (n_chains, d))
        if th.ndim == 1:
            z0 = z0 + init_sd * jax.random.normal(k_jit, (n_chains, d))
    z0 = jnp.asarray(z0, jnp.float64)

    # One compiled program for warm-up and sampling (beta, the proposal and the data are
    # arguments), shared by every problem with the same static key.
    run_chunk_data = problem.jitted(("mh_chunk", chunk), _chunk_runner(problem, chunk))
    run_chunk = lambda key, state, chol, w, beta: run_chunk_data(key, state, chol, w, indep_now(), beta,  # noqa: E731
                                                                 problem.data)
    log_prior = problem.jitted("log_prior", space.log_prior)

    n_warm_chunks = math.ceil(n_warmup / chunk)
    n_samp_chunks = math.ceil(n_samples / chunk)
    n_anneal = int(round(anneal * n_warm_chunks))
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=(n_warm_chunks + n_samp_chunks) * chunk, desc="mh", unit="step", leave=False)

    t_start = time.perf_counter()
    # The initial density is -inf, so the first step accepts the first (finite) proposal
    # around z0: no separate compiled evaluation is needed.
    state = RWState(z0, jnp.full((n_chains,), -jnp.inf, jnp.float64))
    sigma = np.eye(d) * init_sd**2 * d / RW_SCALE**2  # s = RW_SCALE / sqrt(d) then gives SD init_sd
    log_s = math.log(RW_SCALE / math.sqrt(d))
    beta = 1.0
    n_resets, n_resampled, warm_acc = 0, 0, float("nan")
    rng = np.random.default_rng(int(jax.random.randint(k_jit, (), 0, 2**31 - 1)))
    keys = jax.random.split(k_run, n_warm_chunks + n_samp_chunks)

    jump_chol = np.zeros((d, d))  # no population estimate yet: the jump component is off

    def chol_of(sig, ls):
        cov = math.exp(2 * ls) * sig + 1e-10 * np.eye(d)
        return jnp.asarray(np.stack([np.linalg.cholesky(cov), jump_chol]), jnp.float64)

    indep = None  # (mean, chol) of the independence proposal: none before the first estimate
    recent: list[np.ndarray] = []  # the last untempered chunks' draws, (chains, chunk, d) each

    def weights_now():
        w = jump if jump_chol.any() else 0.0
        v = independent if indep is not None else 0.0
        return jnp.asarray([(1.0 - w) * (1.0 - v), w * (1.0 - v), v], jnp.float64)

    def indep_now():
        mean, chol = indep if indep is not None else (np.zeros(d), np.eye(d))
        return IndependentProposal(jnp.asarray(mean, jnp.float64), jnp.asarray(chol, jnp.float64),
                                   jnp.float64(independent_df))

    def set_beta(state, old, new):
        """Move the chains from beta = old to new: SMC reweighting by exp((new - old) log lik),
        systematic resampling when the effective sample size drops below resample_ess * n_chains, and
        the tempered densities recomputed without a rollout."""
        nonlocal n_resampled
        if old == new:
            return state
        lp = log_prior(state.position)
        ll = (state.logdensity - lp) / old
        logw = np.asarray(jnp.where(jnp.isfinite(state.logdensity), (new - old) * ll, -jnp.inf), np.float64)
        if np.isfinite(logw).any():
            w = np.exp(logw - logw.max())
            w /= w.sum()
            if 1.0 / np.sum(w**2) < resample_ess * n_chains:
                u = (rng.random() + np.arange(n_chains)) / n_chains
                idx = np.minimum(np.searchsorted(np.cumsum(w), u), n_chains - 1)
                state = RWState(state.position[idx], state.logdensity[idx])
                lp, ll = lp[idx], ll[idx]
                n_resampled += 1
        ld = lp + ll * new
        return RWState(state.position, jnp.where(jnp.isfinite(state.logdensity), ld, state.logdensity))

    for c in range(n_warm_chunks):
        new_beta = beta0 ** (1.0 - c / n_anneal) if c < n_anneal else 1.0
        state = set_beta(state, beta, new_beta)
        beta = new_beta
        state, (trace, info) = run_chunk(keys[c], state, chol_of(sigma, log_s), weights_now(), jnp.float64(beta))
        skip = 1 if c == 0 else 0  # the very first step leaves the -inf start: not a real move
        acc = np.asarray(info.acceptance_rate)[skip:]  # (chunk, chains)
        local = np.asarray(info.component)[skip:] == 0
        warm_acc = float(acc[local].mean()) if local.any() else float(acc.mean())
        log_s += float(np.clip(0.7 * math.log((warm_acc + 0.01) / (target_acceptance + 0.01)), -2.0, 1.0))
        pos = np.transpose(np.asarray(trace.position, np.float64), (1, 0, 2))[:, skip:]  # (chains, chunk, d)
        pop = _population_cov(pos) if chunk > 2 and (jump > 0 or adapt == "population") else None
        if warm_acc > 0.05 and chunk > 2:
            new = pop if adapt == "population" else _pooled_within_cov(pos)
            if np.all(np.isfinite(new)) and np.linalg.eigvalsh(new).min() > 0:
                # keep the overall size in log_s: Sigma only carries the shape (correlations, ratios)
                geo = lambda a: np.exp(np.mean(np.log(np.linalg.eigvalsh(a))))  # noqa: E731
                sigma = new * (geo(sigma) / geo(new))
        if jump > 0 and pop is not None and np.all(np.isfinite(pop)):
            jump_chol = np.linalg.cholesky(pop * RW_SCALE**2 / d + 1e-12 * np.eye(d))
        if independent > 0 and beta == 1.0:  # the untempered posterior's draws only (beta stays 1 once there)
            recent = recent[-(INDEPENDENT_CHUNKS - 1):] + [pos]
            draws = np.concatenate(recent, axis=1)
            cov = _population_cov(draws)
            if np.all(np.isfinite(cov)) and np.linalg.eigvalsh(cov).min() > 0:
                indep = (draws.reshape(-1, d).mean(axis=0), np.linalg.cholesky(cov + 1e-12 * np.eye(d)))
        if beta == 1.0 and c < 0.75 * n_warm_chunks and np.isfinite(reset_threshold):
            ld = np.asarray(state.logdensity, np.float64)
            best = np.max(np.where(np.isfinite(ld), ld, -np.inf))
            bad = ~(ld >= best - reset_threshold)
            good = np.flatnonzero(~bad)
            if bad.any() and good.size:
                idx = np.arange(n_chains)
                idx[bad] = rng.choice(good, size=int(bad.sum()))
                state = RWState(state.position[idx], state.logdensity[idx])
                n_resets += int(bad.sum())
        if bar is not None:
            bar.update(chunk)
            bar.set_postfix(beta=f"{beta:.3g}", acc=f"{warm_acc:.2f}", scale=f"{math.exp(log_s):.2f}")

    state = set_beta(state, beta, 1.0)
    chol, weights = chol_of(sigma, log_s), weights_now()
    zs, lds, accs = [], [], []
    t_samp = time.perf_counter()
    for c in range(n_samp_chunks):
        state, (trace, info) = run_chunk(keys[n_warm_chunks + c], state, chol, weights, jnp.float64(1.0))
        zs.append(np.asarray(trace.position))
        lds.append(np.asarray(trace.logdensity))
        accs.append(np.asarray(info.is_accepted))
        if bar is not None:
            bar.update(chunk)
            bar.set_postfix(acc=f"{np.concatenate(accs).mean():.2f}")
    t_end = time.perf_counter()
    if bar is not None:
        bar.close()

    z = np.transpose(np.concatenate(zs), (1, 0, 2))[:, :n_samples]  # (chains, draws, d)
    ld = np.concatenate(lds).T[:, :n_samples]
    acc = np.concatenate(accs).T[:, :n_samples]
    theta = np.asarray(space.from_unconstrained(jnp.asarray(z)), np.float64)
    loglik = ld - np.asarray(log_prior(jnp.asarray(z)), np.float64)
    return MHResult(names=space.names, theta=theta, z=z.astype(np.float64), loglik=loglik,
                    logdensity=ld.astype(np.float64), acceptance=acc.mean(axis=1), warmup_acceptance=warm_acc,
                    proposal_chol=np.asarray(chol[0], np.float64), n_resets=n_resets, n_resampled=n_resampled,
                    seconds_per_step=(t_end - t_samp) / (n_samp_chunks * chunk), time_s=t_end - t_start)
