"""Tests for structure in standardised residuals (a run of one sign, lag-1 correlation, a drift,
too large a spread): each returns a p-value under the noise model (:mod:`.noise`).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import linalg, special

from galileo_jax.criticism.noise import residual_correlation

#: Tests run on every row, in the order of the row's p-value fields.
TESTS = ("runs", "lag1", "cusum", "chi2")


#: Names of the tests as the verdict writes them.
TEST_LABELS = {"runs": "runs test", "lag1": "lag-1 autocorrelation", "cusum": "CUSUM", "chi2": "chi-square"}


def runs_test(z: np.ndarray) -> float:
    """One-sided (too few runs) exact Wald-Wolfowitz runs test on the signs of ``z``.

    With n1 positive and n2 negative signs (zeros dropped) and R runs, under exchangeability
    (Swed & Eisenhart, *Ann. Math. Stat.* 14, 1943), with C = binomial coefficient:
    P(R = 2k) = 2 C(n1-1, k-1) C(n2-1, k-1) / C(n1+n2, n1),
    P(R = 2k+1) = [C(n1-1, k) C(n2-1, k-1) + C(n1-1, k-1) C(n2-1, k)] / C(n1+n2, n1).

    Returns:
        p = P(R <= R_observed); 1.0 when all signs agree (one arrangement) or n < 2.
    """
    z = np.asarray(z, np.float64)
    s = np.sign(z[np.isfinite(z) & (z != 0)])
    n1, n2 = int(np.sum(s > 0)), int(np.sum(s < 0))
    if n1 == 0 or n2 == 0:
        return 1.0
    r_obs = 1 + int(np.sum(s[1:] != s[:-1]))
    lg = special.gammaln(np.arange(n1 + n2 + 2, dtype=np.float64))  # lg[m] = log (m - 1)!

    def log_comb(a: int, b: np.ndarray) -> np.ndarray:
        """log C(a, b) for integer a >= 0 and an integer array b; -inf where b < 0 or b > a."""
        ok = (b >= 0) & (b <= a)
        bb = np.where(ok, b, 0)
        return np.where(ok, lg[a + 1] - lg[bb + 1] - lg[a - bb + 1], -np.inf)

    r = np.arange(2, r_obs + 1)
    k = r // 2
    logp = np.where(r % 2 == 0, math.log(2.0) + log_comb(n1 - 1, k - 1) + log_comb(n2 - 1, k - 1),
                    np.logaddexp(log_comb(n1 - 1, k) + log_comb(n2 - 1, k - 1),
                                 log_comb(n1 - 1, k - 1) + log_comb(n2 - 1, k)))
    total = lg[n1 + n2 + 1] - lg[n1 + 1] - lg[n2 + 1]
    return float(min(1.0, np.exp(np.logaddexp.reduce(logp) - total)))


def lag1_test(z: np.ndarray, idx: np.ndarray, rho: float) -> tuple[float, float]:
    """Lag-1 autocorrelation of ``z`` against its model value ``rho``, one-sided for excess.

    r1 = [sum over adjacent pairs (z_k - zbar)(z_{k+1} - zbar) / n_pairs] / [sum (z - zbar)^2 / n],
    pairs only where the sample indices differ by one; z = (r1 - rho) sqrt(n_pairs / w),
    w = 1 - 3 rho^2 + 4 rho^4 (Bartlett, MA(1); module docstring).

    Args:
        z: (m,) standardised residuals, in time order.
        idx: (m,) their sample indices (to find adjacent pairs).
        rho: expected lag-1 correlation under the model.

    Returns:
        (r1, p); (nan, nan) with fewer than 2 adjacent pairs or zero spread.
    """
    z = np.asarray(z, np.float64)
    idx = np.asarray(idx)
    pairs = np.flatnonzero(np.diff(idx) == 1)
    if pairs.size < 2:
        return math.nan, math.nan
    d = z - z.mean()
    var = np.mean(d**2)
    if var <= 0:
        return math.nan, math.nan
    r1 = float(np.mean(d[pairs] * d[pairs + 1]) / var)
    w = 1.0 - 3.0 * rho**2 + 4.0 * rho**4
    stat = (r1 - rho) * math.sqrt(pairs.size / w)
    return r1, float(special.ndtr(-stat))


def sup_brownian_sf(x: float) -> float:
    """P(sup_{0<=t<=1} |W(t)| >= x) for standard Brownian motion W (module docstring)."""
    if x <= 0:
        return 1.0
    if x < 1.0:
        k = np.arange(50)
        terms = (-1.0) ** k / (2 * k + 1) * np.exp(-(np.pi**2) * (2 * k + 1) ** 2 / (8.0 * x * x))
        return float(min(1.0, max(0.0, 1.0 - 4.0 / np.pi * np.sum(terms))))
    j = np.arange(50)
    return float(min(1.0, 4.0 * np.sum((-1.0) ** j * special.ndtr(-(2 * j + 1) * x))))


def cusum_test(z: np.ndarray, idx: np.ndarray, rho: float) -> tuple[float, float]:
    """CUSUM of the residuals against Brownian motion: (max_k |S_k| / sqrt(n), p).

    S_k are the partial sums of the whitened residuals e = L^-1 z, R = L L^T the model
    correlation (:func:`~galileo_jax.criticism.noise.residual_correlation`) at ``idx``; equivalent for large n to
    max|sum z| / sqrt(n (1 + 2 rho)) (module docstring).
    """
    z = np.asarray(z, np.float64)
    if z.size < 2:
        return math.nan, math.nan
    low = np.linalg.cholesky(residual_correlation(idx, rho))
    e = linalg.solve_triangular(low, z, lower=True)
    stat = float(np.max(np.abs(np.cumsum(e))) / math.sqrt(z.size))
    return stat, sup_brownian_sf(stat)


def chi2_test(z: np.ndarray, idx: np.ndarray, rho: float) -> tuple[float, float]:
    """Excess size: (T = sum z^2, p) with T ~ c chi2(nu) (Satterthwaite; module docstring)."""
    z = np.asarray(z, np.float64)
    n = z.size
    if n == 0:
        return math.nan, math.nan
    n_pairs = int(np.sum(np.diff(np.asarray(idx)) == 1))
    tr_r2 = n + 2.0 * n_pairs * rho**2
    c, nu = tr_r2 / n, n * n / tr_r2
    t = float(np.sum(z**2))
    return t, float(special.chdtrc(nu, t / c))
