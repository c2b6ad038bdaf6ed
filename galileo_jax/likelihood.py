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
dominates all model error. The roughness itself can be averaged away at a price: a rollout
ensemble over where in a physics step the contact events fall
(:func:`galileo_jax.physics.simulate.ensemble_offsets`, ``fit --ensemble K``, K times the
rollouts) cut it from 4.3 / 2.9 to 1.1 / 1.1 nats along k2 / phi on a held-out render.

The observation is DATA, not code. A :class:`Likelihood` is a JAX pytree: its arrays (the
observed profile, the mask, the whitening matrices, the normalising constant) are leaves and
only the kind and floor are static, so a jitted function that takes the likelihood as an
argument compiles once for every video of the same length (``make_likelihood(...,
n_samples=M)`` pads shorter profiles with masked-out samples). Residual vectors therefore have
the fixed length T * M, with zeros at the samples outside the mask; :meth:`Likelihood.used`
selects the used ones (for tests and reports). The whitening matrices are precomputed in NumPy.
"""

from __future__ import annotations

import functools
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


def emd_distance(a: jax.Array, b: jax.Array, length: jax.Array | int | None = None) -> jax.Array:
    """The seed's "EMD" alignment cost D = M[n][n] between two 1-D sequences (L,).

    M[i][j] = |a[i-1] - b[j-1]| + min(M[i-1][j], M[i][j-1], M[i-1][j-1]), M[0][0] = 0 and
    M = inf elsewhere on the borders (dissertation 4.2.5). Each row is computed in one
    vectorised pass: with c_j the row's costs, a_j = c_j + min(M[i-1][j], M[i-1][j-1]) and
    S_j = c_1 + ... + c_j, M[i][j] = S_j + min_{k <= j} (a_k - S_k).

    Args:
        a, b: (L,) sequences.
        length: n <= L, the number of leading elements that count (may be traced; default L).
            M[n][n] depends only on the first n elements of each, so padding after them is ignored.
    """
    big = jnp.asarray(1e30, a.dtype)
    n_max = b.shape[0]
    n = n_max if length is None else length
    row0 = jnp.concatenate([jnp.zeros(1, a.dtype), jnp.full(n_max, big)])

    def body(carry, inp):
        prev, out = carry
        i, ai = inp
        c = jnp.abs(ai - b)
        best_prev = jnp.minimum(prev[1:], prev[:-1])
        acc = c + best_prev
        s = jnp.cumsum(c)
        row = s + jax.lax.cummin(acc - s)
        row = jnp.minimum(row, big)
        out = jnp.where(i == n - 1, row[jnp.clip(n - 1, 0, n_max - 1)], out)
        return (jnp.concatenate([jnp.full(1, big), row]), out), None

    (_, out), _ = jax.lax.scan(body, (row0, big), (jnp.arange(n_max), a))
    return out


def masked_seed_sequence(profile: jax.Array, mask: jax.Array) -> tuple[jax.Array, jax.Array]:
    """:func:`seed_sequence` of the masked samples of a (T, M) profile, with a traced mask.

    Returns:
        (sequence (T * M,), n): the seed's layout of the masked samples in its first
        n = T * sum(mask) elements, zeros after them.
    """
    t, m_all = profile.shape
    mask = jnp.asarray(mask, bool)
    m = jnp.sum(mask)
    order = jnp.argsort(~mask, stable=True)  # used samples first, in time order
    comp = profile[:, order]
    comp = jnp.concatenate([comp[0::2], comp[1::2]])  # (obj1 x, obj2 x, obj1 y, obj2 y)
    k = jnp.arange(m_all)[None, :]
    pos = jnp.where(k < m, jnp.arange(t)[:, None] * m + k, t * m_all)  # out of range: dropped
    seq = jnp.zeros(t * m_all, profile.dtype).at[pos.reshape(-1)].set(comp.reshape(-1), mode="drop")
    return seq, t * m


def emd_similarity(sim: jax.Array, obs: jax.Array, mask: jax.Array) -> jax.Array:
    """The seed's EMD similarity 1 - D between the masked samples of (T, M) profiles (higher is closer)."""
    a, n = masked_seed_sequence(sim, mask)
    b, _ = masked_seed_sequence(obs, mask)
    return 1.0 - emd_distance(a, b, n)


def rms_similarity(sim: jax.Array, obs: jax.Array, mask: jax.Array) -> jax.Array:
    """The seed's RMS similarity sqrt(mean(1 - |x - y| / (|x| + |y|))) over masked samples.

    A pair with |x| + |y| = 0 counts as identical (similarity 1). ``mask`` (M,) may be traced.
    """
    x, y = sim, obs
    mask = jnp.broadcast_to(jnp.asarray(mask, bool)[None, :], x.shape)
    den = jnp.abs(x) + jnp.abs(y)
    d = jnp.where(den > 0, 1.0 - jnp.abs(x - y) / jnp.where(den > 0, den, 1.0), 1.0)
    return jnp.sqrt(jnp.sum(jnp.where(mask, d, 0.0)) / jnp.sum(mask))


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


# ---------------------------------------------------------------------------- contact events
#: Velocity change (m/s) beyond steady acceleration, within one sample, that marks a contact
#: event (an impact, the ramp's foot, a stop): the second difference |v[k+1] - 2 v[k] + v[k-1]|
#: of an object's velocity vector. Steady sliding gives 0; a stop from friction deceleration
#: k g gives k g / fps (0.16 m/s at k = 0.5, 30 fps), below the threshold.
EVENT_JUMP = 0.2
#: SD (m/s) of the simulator's error around an event, as a fraction of the event's jump, at
#: most :data:`EVENT_CAP`. Measured (rendered two-box videos, C MuJoCo renderer vs the MJX fit
#: at the true parameters, float64): errors of 0.02-0.1 m/s within +-2 samples of the impact
#: and the ramp's foot, where the velocity jumps by 0.5-1.5 m/s, against 0.001-0.002 m/s elsewhere.
EVENT_FRACTION = 0.1
#: Largest event SD (m/s): the fit's own model-error floor (:data:`DEFAULT_SD_MODEL`), so that
#: the samples around an impact still pin the fit down (with SDs of 0.2 m/s a fit in the test
#: likelihood was free to stop object 2 within the impact window: k2 0.90 instead of 0.38).
EVENT_CAP = 0.05


def event_jumps(profile: np.ndarray, threshold: float | np.ndarray = EVENT_JUMP) -> np.ndarray:
    """(n, N-1) size (m/s) of each object's velocity jump per sample, 0 below ``threshold``.

    Args:
        profile: (2n, N-1) velocity profile (rows obj1 x, obj1 y, obj2 x, ...), m/s.
        threshold: scalar or (n,) per-object threshold in m/s.
    """
    v = np.asarray(profile, np.float64)
    n = v.shape[0] // 2
    out = np.zeros((n, v.shape[1]))
    thr = np.broadcast_to(np.asarray(threshold, np.float64), (n,))
    for i in range(n):
        vi = np.nan_to_num(v[2 * i:2 * i + 2])
        if vi.shape[1] < 3:
            continue
        d2 = np.linalg.norm(vi[:, 2:] - 2.0 * vi[:, 1:-1] + vi[:, :-2], axis=0)
        out[i, 1:-1] = np.where(d2 > thr[i], d2, 0.0)
    return out


def event_sd(simulated: np.ndarray, observed: np.ndarray | None = None, velocity_sd: np.ndarray | None = None, *,
             jump: float = EVENT_JUMP, fraction: float = EVENT_FRACTION, cap: float = EVENT_CAP,
             halfwidth: int = 1) -> np.ndarray:
    """(2n, N-1) extra model-error SD (m/s) per velocity sample around contact events.

    A rigid-body simulator gets the moment of an impact or of the ramp's foot right only to
    within a physics step or two, and MJX and C MuJoCo resolve the same contact differently
    (box-box impacts, a box tipping over the foot): near such an event a sample's error is a
    fraction of the velocity jump, far larger than the tracking noise, while between events
    the simulation is accurate to ~0.002 m/s. So the samples within ``halfwidth`` of an event
    (a jump of an object's velocity, :func:`event_jumps`, in the simulated profile, or in the
    observed one where it stands out of the noise: threshold max(jump, 16 velocity_sd), 16 =
    5 x sqrt(10), the SD of a second difference of MA(1) velocity noise being sqrt(10)
    velocity_sd) get SD min(``fraction`` x jump, ``cap``) on both of that object's traces. Used by
    the tests of :mod:`galileo_jax.criticism.diagnosis` (with :func:`galileo_jax.criticism.noise.sample_sd`).

    Args:
        simulated: (2n, N-1) simulated profile (e.g. of the base fit), m/s.
        observed: optional (2n, N-1) observed profile, m/s.
        velocity_sd: (2n,) observed velocity noise SDs (m/s), needed with ``observed``.
        jump, fraction, cap: :data:`EVENT_JUMP`, :data:`EVENT_FRACTION`, :data:`EVENT_CAP` (m/s).
        halfwidth: samples on each side of an event that get its SD.

    Returns:
        (2n, N-1) SDs in m/s, 0 away from events.
    """
    jumps = event_jumps(simulated, jump)
    if observed is not None:
        vsd = np.asarray(velocity_sd, np.float64).reshape(-1, 2).max(axis=1)
        jumps = np.maximum(jumps, event_jumps(observed, np.maximum(jump, 16.0 * vsd)))
    n, m = jumps.shape
    spread = jumps.copy()
    for s in range(1, halfwidth + 1):
        spread[:, s:] = np.maximum(spread[:, s:], jumps[:, :-s])
        spread[:, :-s] = np.maximum(spread[:, :-s], jumps[:, s:])
    return np.repeat(np.minimum(fraction * spread, cap), 2, axis=0)


# ---------------------------------------------------------------------------- the likelihood
@functools.partial(jax.tree_util.register_dataclass, data_fields=["obs", "mask", "whiten", "log_norm"],
                   meta_fields=["kind", "sd_model"])
@dataclass(frozen=True, eq=False)
class Likelihood:
    """A likelihood (or similarity) of one observation, as a pure function of the simulated profile.

    Build with :func:`make_likelihood`. Call ``lik(sim_profile)`` with a (T, M) simulated
    profile (m/s) for a scalar; ``vmap`` for batches. A JAX pytree (module docstring): pass it
    INTO jitted functions so that one compiled program serves every observation of the same size.

    Attributes:
        kind: one of :data:`KINDS` (static).
        sd_model: model-error floor in m/s used to build ``whiten`` (static).
        obs: (T, M) observed profile, m/s, zero at unused samples.
        mask: (M,) bool, the samples that count (the fit window; padding is False).
        whiten: Gaussian kinds: (T, M) inverse SDs 1/(m/s) (independent kinds) or (T, M, M)
            whitening matrices W_i = L_i^-1 embedded at the used samples (``gaussian_ma1``);
            zero at unused samples. Similarity kinds: (T, M) zeros.
        log_norm: () sum over traces of -logdet(C_i) / 2 - (m / 2) log 2 pi (Gaussian kinds; 0 otherwise).
    """

    kind: str
    sd_model: float
    obs: jax.Array
    mask: jax.Array
    whiten: jax.Array
    log_norm: jax.Array

    @property
    def is_gaussian(self) -> bool:
        """True for the kinds that are Gaussian log-densities (and have residuals)."""
        return self.kind in GAUSSIAN_KINDS

    @property
    def idx(self) -> np.ndarray:
        """(m,) indices of the used velocity samples (NumPy; not for traced likelihoods)."""
        return np.flatnonzero(np.asarray(self.mask))

    @property
    def n_residuals(self) -> int:
        """Length T * M of :meth:`residuals` (used and unused samples)."""
        return int(self.obs.shape[0] * self.obs.shape[1])

    @property
    def n_used(self) -> int:
        """Number T * m of residuals at used samples."""
        return int(self.obs.shape[0] * self.idx.size)

    def used(self, r) -> np.ndarray:
        """The used samples of residual vectors: (..., T * M) -> (..., T * m), NumPy, trace-major."""
        r = np.asarray(r)
        t, m = self.obs.shape
        return r.reshape(r.shape[:-1] + (t, m))[..., self.idx].reshape(r.shape[:-1] + (-1,))

    def used_residuals(self, sim) -> np.ndarray:
        """Standardised residuals at the used samples, (T * m,) NumPy, of a (T, N) simulated
        profile with N <= M (padded here): for reports and tests outside jit."""
        sim = np.asarray(sim, np.float64)
        sim = np.pad(sim, ((0, 0), (0, self.obs.shape[1] - sim.shape[1])))
        return self.used(self.residuals(jnp.asarray(sim)))

    def residuals(self, sim: jax.Array) -> jax.Array:
        """Standardised (whitened) residuals W_i (obs_i - sim_i), flattened to (T * M,).

        Zero at unused samples. For the Gaussian kinds log L = -|residuals|^2 / 2 + log_norm,
        so least squares on them is maximum likelihood and their Gauss-Newton curvature
        J^T J is the Fisher information.

        Raises:
            ValueError: (Python-side) for the similarity kinds.
        """
        if not self.is_gaussian:
            raise ValueError(f"likelihood {self.kind!r} has no residuals; use one of {', '.join(GAUSSIAN_KINDS)}")
        r = self.obs - sim[:, :self.obs.shape[1]]
        if self.whiten.ndim == 2:
            return (self.whiten * r).reshape(-1)
        return jnp.einsum("tij,tj->ti", self.whiten, r).reshape(-1)

    def __call__(self, sim: jax.Array) -> jax.Array:
        """Log-likelihood (Gaussian kinds, nats) or similarity (emd, rms) of a (T, M) profile."""
        sim = sim[:, :self.obs.shape[1]]
        if self.kind == "emd":
            return emd_similarity(sim, self.obs, self.mask)
        if self.kind == "rms":
            return rms_similarity(sim, self.obs, self.mask)
        w = self.residuals(sim)
        return -0.5 * jnp.sum(w**2) + self.log_norm


#: The kinds that are Gaussian log-densities.
GAUSSIAN_KINDS = ("gaussian_ma1", "gaussian_iid", "seed_gaussian")


def make_likelihood(observation: Observation, kind: str = DEFAULT_KIND, sd_model: float = DEFAULT_SD_MODEL,
                    n_samples: int | None = None) -> Likelihood:
    """Precompute the likelihood of ``observation``.

    Args:
        observation: the observed profile, its per-trace position noise SD (m) and mask.
        kind: one of :data:`KINDS` (module docstring).
        sd_model: white model-error floor in m/s added in quadrature (Gaussian kinds except
            ``seed_gaussian``), sd_total^2 = sd_noise^2 + sd_model^2; 0 switches it off.
        n_samples: M, the length of the likelihood's arrays (>= the profile's N - 1); the
            samples after the profile's end are padding outside the mask. Default N - 1.

    Returns:
        A :class:`Likelihood`.

    Raises:
        ValueError: unknown kind, negative sd_model, empty mask, NaN in a masked observed
            sample, a trace with zero noise and zero model floor, or n_samples < N - 1.
    """
    if kind not in KINDS:
        raise ValueError(f"unknown likelihood {kind!r}; choose one of {', '.join(KINDS)}")
    if not sd_model >= 0:
        raise ValueError(f"sd_model must be >= 0 m/s, got {sd_model}")
    mask = np.asarray(observation.mask, bool)
    profile = np.asarray(observation.profile, np.float64)
    t, n = profile.shape
    if mask.shape != (n,):
        raise ValueError(f"observation.mask has shape {mask.shape}, expected ({n},) to match the profile")
    m_all = n if n_samples is None else int(n_samples)
    if m_all < n:
        raise ValueError(f"n_samples ({m_all}) is shorter than the profile ({n} samples)")
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        raise ValueError("observation.mask selects no velocity samples; widen the fit window")
    if not np.all(np.isfinite(profile[:, idx])):
        raise ValueError("observed profile has NaN/inf inside the fit window (mask); mask those samples out")
    full_mask = np.zeros(m_all, bool)
    full_mask[idx] = True
    obs = np.zeros((t, m_all))
    obs[:, idx] = profile[:, idx]
    log_norm = 0.0
    whiten = np.zeros((t, m_all))
    if kind in GAUSSIAN_KINDS:
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
        if kind == "gaussian_ma1":
            whiten = np.zeros((t, m_all, m_all))
            for i, w in enumerate(mats):
                whiten[i][np.ix_(idx, idx)] = w
        else:
            for i, w in enumerate(mats):
                whiten[i, idx] = np.diag(w)
    return Likelihood(kind, float(sd_model), jnp.asarray(obs), jnp.asarray(full_mask), jnp.asarray(whiten),
                      jnp.asarray(log_norm))
