"""Likelihood of an observed velocity profile given a simulated one.

The observation model. Tracking measures each position trace with independent Gaussian
errors e_k ~ N(0, sd_p^2) (``Observation.position_sd``, estimated from the data); the velocity
profile differences them, V_k = (p_{k+1} - p_k) / (t_{k+1} - t_k), so the velocity residual of
one trace is r = D e with D the (N-1, N) scaled difference matrix, and

    Cov(r) = sd_p^2 D D^T      (tridiagonal: 2 sd_p^2 fps^2 on the diagonal, -sd_p^2 fps^2 beside it),

an MA(1) process with lag-1 correlation -1/2. To this we add a white model-error floor
sd_model^2 I in velocity (simulator and model error; default 0.05 m/s, see "Choice of
default" below), so

    C = sd_p^2 D D^T + sd_model^2 I,   restricted to the samples in ``Observation.mask``.

Likelihood kinds (selected by name in :func:`make_likelihood`):

* ``"gaussian_iid"`` (default): the dissertation's Gaussian similarity (eq. 4.3),
  sum_i log N(obs_i; sim_i, sd_i), with sd_i^2 = diag(C) = 2 sd_p^2 fps^2 + sd_model^2: the
  noise estimated from the data instead of a fixed 0.05, plus the model-error floor. Gets
  each sample's variance right but ignores the MA(1) correlation.
* ``"gaussian_ma1"``: the exact Gaussian log-density log N(r; 0, C) per trace, evaluated
  through a precomputed whitening matrix W = L^-1 (C = L L^T, Cholesky), so
  log L = -|W r|^2 / 2 - sum log diag L - (m / 2) log 2 pi.
* ``"seed_gaussian"``: eq. 4.3 exactly as the seed ran it: all samples independent with
  SD 0.05 m/s (scipy ``norm(A[i], 0.05)``), no noise estimate, no model floor.
* ``"emd"``: the seed's "Earth mover's distance" similarity 1 - D, where D is the
  dynamic-programming alignment cost of dissertation 4.2.5 ("The likelihood function"):
  M[i][j] = |A[i-1] - B[j-1]| + min(M[i-1][j], M[i][j-1], M[i-1][j-1]), M[0][0] = 0.
  (This recursion is dynamic time warping; it is kept as the seed defined it.)
* ``"rms"``: the seed's "Root Mean Similarity" sqrt(mean_i (1 - |A_i - B_i| / (|A_i| + |B_i|))).

EMD and RMS are similarities, not log-densities; they are kept for benchmarks and the seed
baseline (higher is better, as for the Gaussian kinds). Both use the seed's sequence
layout: the four traces joined as (obj1 x, obj2 x, obj1 y, obj2 y), masked samples only.

Choice of default (measured, 20 degree two-box scene, 1.5 s at 30 fps, position noise 1 mm,
so 0.042 m/s per velocity sample). The simulated profile is not a smooth function of the
parameters: the foot of the ramp, the impact and contact chatter make it respond
pseudo-randomly, ~0.01 m/s RMS per sample (0.04 m/s at the impact), to parameter changes of
0.001 (the same size as the 1/240 s discretisation error quoted in scene.py). Summed over
the 180 samples this is pseudo-random noise in log L between neighbouring parameter values
(std of second differences / sqrt 6 along k1, k2, phi; posterior SD from a quadratic fit):

    kind          sd_model   log L noise (k1, k2, phi)   posterior SD (k1, k2, phi)
    gaussian_iid  0.01       7.5, 5.4, 3.4 nats          0.0013, 0.015, 0.029
    gaussian_iid  0.05       3.3, 2.4, 1.5               0.0020, 0.023, 0.043
    gaussian_iid  0.10       1.2, 0.9, 0.6               0.0033, 0.038, 0.072
    gaussian_ma1  0.01       56, 72, 44                  0.0005, 0.004, 0.008
    gaussian_ma1  0.05       4.3, 4.0, 2.4               0.0017, 0.018, 0.034

The exact MA(1) form trusts smooth residuals (neighbouring errors cancel), which is exactly
where the simulator's pseudo-random offsets live, so at a small floor it turns them into
tens of nats of noise between parameter values 0.001 apart: a spiky posterior. The iid form
is far smoother at equal floor. Hence the default is ``gaussian_iid`` with
``sd_model = 0.05`` m/s (the seed's SD of eq. 4.3, now read as model error added to the
measured tracking noise): a few nats of log L noise, posterior SD still ~0.002 in k1. The
floor acts as a coarsened likelihood (robustness to the simulator's roughness and to real
model error) rather than as the simulator's literal discretisation error. Lower it for
sharper but rougher posteriors; ``gaussian_ma1`` is the exact likelihood when tracking noise
dominates all model error.

All returned callables are pure JAX (jit/vmap-able) functions of the simulated profile; the
observation-dependent parts (selected samples, whitening matrices) are precomputed in NumPy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from galileo_jax.observation import Observation

#: Likelihood kinds accepted by :func:`make_likelihood`.
KINDS = ("gaussian_ma1", "gaussian_iid", "seed_gaussian", "emd", "rms")
#: Default likelihood kind (see the module docstring for why).
DEFAULT_KIND = "gaussian_iid"
#: Default model-error floor in m/s (see "Choice of default" in the module docstring).
DEFAULT_SD_MODEL = 0.05
#: The seed's fixed Gaussian SD in m/s (dissertation eq. 4.3).
SEED_SD = 0.05
_LOG_2PI = math.log(2.0 * math.pi)


# ---------------------------------------------------------------------------- pure functions
def gaussian_loglik(sim: jax.Array, obs: jax.Array, sd: jax.Array, mask: jax.Array) -> jax.Array:
    """Independent-Gaussian log-likelihood, dissertation eq. 4.3 with per-trace SDs.

    sum over traces i and masked samples k of log N(obs[i, k]; sim[i, k], sd[i]).

    Args:
        sim: (T, M) simulated profile in m/s.
        obs: (T, M) observed profile in m/s.
        sd: (T,) or (T, M) SD in m/s (positive).
        mask: (M,) bool, samples to include.

    Returns:
        Scalar log-likelihood (nats).
    """
    sd = jnp.asarray(sd)
    if sd.ndim == 1:
        sd = sd[:, None]
    z = (obs - sim) / sd
    terms = -0.5 * z**2 - jnp.log(sd) - 0.5 * _LOG_2PI
    return jnp.sum(jnp.where(jnp.asarray(mask)[None, :], terms, 0.0))


def seed_sequence(profile: jax.Array) -> jax.Array:
    """The seed's 1-D layout of a (2n, M) profile: (obj1 x, obj2 x, obj1 y, obj2 y) joined."""
    return jnp.concatenate([profile[0::2].reshape(-1), profile[1::2].reshape(-1)])


def emd_distance(a: jax.Array, b: jax.Array) -> jax.Array:
    """The seed's "EMD" alignment cost D = M[n][n] between two 1-D sequences (n,).

    M[i][j] = |a[i-1] - b[j-1]| + min(M[i-1][j], M[i][j-1], M[i-1][j-1]), M[0][0] = 0 and
    M = inf elsewhere on the borders (dissertation 4.2.5). Each row is computed in one
    vectorised pass: with c_j the row's costs, a_j = c_j + min(M[i-1][j], M[i-1][j-1]) and
    S_j = c_1 + ... + c_j, M[i][j] = S_j + min_{k <= j} (a_k - S_k).
    """
    big = jnp.asarray(1e30, a.dtype)
    n = b.shape[0]
    row0 = jnp.concatenate([jnp.zeros(1, a.dtype), jnp.full(n, big)])

    def body(prev, ai):
        c = jnp.abs(ai - b)
        best_prev = jnp.minimum(prev[1:], prev[:-1])
        acc = c + best_prev
        s = jnp.cumsum(c)
        row = s + jax.lax.cummin(acc - s)
        row = jnp.minimum(row, big)
        return jnp.concatenate([jnp.full(1, big), row]), None

    last, _ = jax.lax.scan(body, row0, a)
    return last[-1]


def emd_similarity(sim: jax.Array, obs: jax.Array, mask: np.ndarray) -> jax.Array:
    """The seed's EMD similarity 1 - D between masked profiles (T, M) (higher is closer)."""
    idx = np.flatnonzero(np.asarray(mask))
    return 1.0 - emd_distance(seed_sequence(sim[:, idx]), seed_sequence(obs[:, idx]))


def rms_similarity(sim: jax.Array, obs: jax.Array, mask: np.ndarray) -> jax.Array:
    """The seed's RMS similarity sqrt(mean(1 - |x - y| / (|x| + |y|))) over masked samples.

    A pair with |x| + |y| = 0 counts as identical (similarity 1).
    """
    idx = np.flatnonzero(np.asarray(mask))
    x, y = sim[:, idx], obs[:, idx]
    den = jnp.abs(x) + jnp.abs(y)
    d = jnp.where(den > 0, 1.0 - jnp.abs(x - y) / jnp.where(den > 0, den, 1.0), 1.0)
    return jnp.sqrt(jnp.mean(d))


# ---------------------------------------------------------------------------- noise model
def difference_matrix(frame_times: np.ndarray) -> np.ndarray:
    """(N-1, N) matrix D with (D p)_k = (p_{k+1} - p_k) / (t_{k+1} - t_k), in 1/s."""
    t = np.asarray(frame_times, np.float64)
    dt = np.diff(t)
    n = t.shape[0]
    d = np.zeros((n - 1, n))
    k = np.arange(n - 1)
    d[k, k] = -1.0 / dt
    d[k, k + 1] = 1.0 / dt
    return d


def velocity_covariance(frame_times: np.ndarray, position_sd: float, sd_model: float,
                        mask: np.ndarray | None = None) -> np.ndarray:
    """Covariance (m, m) of one trace's masked velocity residuals in (m/s)^2.

    C = position_sd^2 D D^T + sd_model^2 I, rows/columns restricted to ``mask`` (module docstring).
    """
    d = difference_matrix(frame_times)
    c = position_sd**2 * d @ d.T + sd_model**2 * np.eye(d.shape[0])
    if mask is not None:
        idx = np.flatnonzero(np.asarray(mask))
        c = c[np.ix_(idx, idx)]
    return c


def whitening(cov: np.ndarray) -> tuple[np.ndarray, float]:
    """(W, logdet) with W = L^-1 for C = L L^T (Cholesky) and logdet = log det C.

    Raises:
        ValueError: C is not positive definite (e.g. zero noise and zero model floor).
    """
    try:
        low = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        raise ValueError("velocity noise covariance is not positive definite; the observation has "
                         "zero position noise: give sd_model > 0") from None
    w = np.linalg.solve(low, np.eye(cov.shape[0]))
    return w, float(2.0 * np.sum(np.log(np.diag(low))))


# ---------------------------------------------------------------------------- the likelihood
@dataclass(frozen=True, eq=False)
class Likelihood:
    """A likelihood (or similarity) of one observation, as a pure function of the simulated profile.

    Build with :func:`make_likelihood`. Call ``lik(sim_profile)`` with a (2n, N-1) simulated
    profile (m/s) for a scalar; ``vmap`` for batches.

    Attributes:
        kind: one of :data:`KINDS`.
        idx: (m,) indices of the masked (used) velocity samples.
        obs: (T, m) observed profile at those samples, m/s.
        whiten: (T, m, m) whitening matrices W_i (Gaussian kinds; None otherwise), 1/(m/s).
        log_norm: sum over traces of -logdet(C_i) / 2 - (m / 2) log 2 pi (Gaussian kinds).
        sd_model: model-error floor in m/s used to build ``whiten``.
    """

    kind: str
    idx: np.ndarray
    obs: jax.Array
    whiten: jax.Array | None
    log_norm: float
    sd_model: float

    @property
    def is_gaussian(self) -> bool:
        """True for the kinds that are Gaussian log-densities (and have residuals)."""
        return self.whiten is not None

    @property
    def n_residuals(self) -> int:
        """Length T * m of :meth:`residuals`."""
        return int(self.obs.shape[0] * self.obs.shape[1])

    def residuals(self, sim: jax.Array) -> jax.Array:
        """Standardised (whitened) residuals W_i (obs_i - sim_i), flattened to (T * m,).

        For the Gaussian kinds log L = -|residuals|^2 / 2 + log_norm, so least squares on
        them is maximum likelihood and their Gauss-Newton curvature J^T J is the Fisher
        information. Python-side error: ValueError for the similarity kinds.
        """
        if not self.is_gaussian:
            raise ValueError(f"likelihood {self.kind!r} has no residuals; use one of gaussian_ma1, gaussian_iid, seed_gaussian")
        r = self.obs - sim[:, self.idx]
        return jnp.einsum("tij,tj->ti", self.whiten, r).reshape(-1)

    def __call__(self, sim: jax.Array) -> jax.Array:
        """Log-likelihood (Gaussian kinds, nats) or similarity (emd, rms) of a (2n, N-1) profile."""
        if self.kind == "emd":
            return 1.0 - emd_distance(seed_sequence(sim[:, self.idx]), seed_sequence(self.obs))
        if self.kind == "rms":
            all_mask = np.ones(self.obs.shape[1], bool)
            return rms_similarity(sim[:, self.idx], self.obs, all_mask)
        w = self.residuals(sim)
        return -0.5 * jnp.sum(w**2) + self.log_norm


def make_likelihood(observation: Observation, kind: str = DEFAULT_KIND, sd_model: float = DEFAULT_SD_MODEL) -> Likelihood:
    """Precompute the likelihood of ``observation``.

    Args:
        observation: the observed profile, its per-trace position noise SD (m) and mask.
        kind: one of :data:`KINDS` (module docstring).
        sd_model: white model-error floor in m/s added in quadrature (Gaussian kinds except
            ``seed_gaussian``), sd_total^2 = sd_noise^2 + sd_model^2; 0 switches it off.

    Returns:
        A :class:`Likelihood`.

    Raises:
        ValueError: unknown kind, negative sd_model, empty mask, NaN in a masked observed
            sample, or a trace with zero noise and zero model floor.
    """
    if kind not in KINDS:
        raise ValueError(f"unknown likelihood {kind!r}; choose one of {', '.join(KINDS)}")
    if not sd_model >= 0:
        raise ValueError(f"sd_model must be >= 0 m/s, got {sd_model}")
    mask = np.asarray(observation.mask, bool)
    profile = np.asarray(observation.profile, np.float64)
    if mask.shape != (profile.shape[1],):
        raise ValueError(f"observation.mask has shape {mask.shape}, expected ({profile.shape[1]},) to match the profile")
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        raise ValueError("observation.mask selects no velocity samples; widen the fit window")
    obs = profile[:, idx]
    if not np.all(np.isfinite(obs)):
        raise ValueError("observed profile has NaN/inf inside the fit window (mask); mask those samples out")
    whiten, log_norm = None, 0.0
    if kind in ("gaussian_ma1", "gaussian_iid", "seed_gaussian"):
        m = idx.size
        mats = []
        for sd_p in np.asarray(observation.position_sd, np.float64):
            if kind == "seed_gaussian":
                cov = SEED_SD**2 * np.eye(m)
            else:
                cov = velocity_covariance(observation.frame_times, float(sd_p), sd_model, mask)
                if kind == "gaussian_iid":
                    cov = np.diag(np.diag(cov))
            w, logdet = whitening(cov)
            mats.append(w)
            log_norm += -0.5 * logdet - 0.5 * m * _LOG_2PI
        whiten = jnp.asarray(np.stack(mats), jnp.float32)
    return Likelihood(kind, idx, jnp.asarray(obs, jnp.float32), whiten, float(log_norm), float(sd_model))
