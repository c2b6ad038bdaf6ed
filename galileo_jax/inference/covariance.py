"""The fit's uncertainty at the optimum: the Gauss-Newton (Laplace) covariance
(:func:`gauss_newton_covariance`), the heteroscedasticity- and autocorrelation-consistent
sandwich that widens it where the residuals are correlated (:func:`robust_covariance`,
:func:`widened`; Newey & West 1987, Andrews 1991), and draws of the Gaussian approximation
(:func:`gauss_newton_draws`). :mod:`galileo_jax.inference.grad`'s docstring says why and what
was measured.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np

if TYPE_CHECKING:
    from galileo_jax.inference.grad import GradResult

#: Normal quantile for a central 90% interval.
Z90 = 1.6448536269514722


def gauss_newton_covariance(jac: np.ndarray, ridge: float = 1e-9) -> np.ndarray:
    """(J^T J)^-1 for a (n, d) Jacobian of standardised residuals (pseudo-inverse if singular).

    A coordinate whose Jacobian column is not finite (a rollout at its difference step blew
    up, e.g. a stiff contact) gets an infinite variance and no covariance with the others: its
    interval is the prior range, not a made-up number."""
    jac = np.asarray(jac, np.float64)
    d = jac.shape[1]
    good = np.all(np.isfinite(jac), axis=0)
    cov = np.zeros((d, d))
    if good.any():
        j = jac[:, good]
        jtj = j.T @ j
        jtj = jtj + ridge * np.trace(jtj) / max(jtj.shape[0], 1) * np.eye(jtj.shape[0])
        cov[np.ix_(good, good)] = np.linalg.pinv(jtj, hermitian=True)
    bad = np.flatnonzero(~good)
    cov[bad, bad] = np.inf
    return cov


def robust_covariance(jac: np.ndarray, resid: np.ndarray, series, cov_gn: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The Gauss-Newton covariance widened, per coordinate, to the sandwich estimate's SD where
    that is larger (module docstring, "Uncertainty").

    The sandwich (Huber 1967; White 1980) is A S A with A = ``cov_gn`` = (J^T J)^-1 and S the
    Newey-West (1987) long-run covariance of the score contributions g_k = J_k r_k summed over
    each time series (a trace of a video): S = sum_k g_k g_k^T + sum_{l=1..L} (1 - l/(L+1))
    sum_k (g_k g_{k+l}^T + g_{k+l} g_k^T). The bandwidth L is Andrews' (1991, eq. 6.4, Bartlett
    kernel) AR(1) plug-in, 1.1447 (alpha n)^(1/3) with alpha = 4 rho^2 / ((1 - rho)^2 (1 + rho)^2),
    rho the residuals' pooled lag-1 autocorrelation (clipped to +-0.97) and n the used samples
    per series. A coordinate's variance is never taken below White's (1980) heteroscedasticity-
    consistent one (S without the lags): velocities differenced from tracked positions have a
    lag-1 correlation of -1/2, which the iid likelihood already leaves out and which would
    otherwise cancel the widening where the residuals are larger than the noise claimed
    (measured: ``tests/test_coverage_check.py``, half the noise claimed: 90% coverage 0.6 with
    the lags' cancellation, 0.5 without any widening).

    Args:
        jac: (R, d) Jacobian of the standardised residuals.
        resid: (R,) standardised residuals at the estimate (0 at unused samples).
        series: list of (T, M) shapes: the residual vector is their blocks one after the other,
            each T series of M samples (trace-major, :meth:`~galileo_jax.likelihood.Likelihood.residuals`).
        cov_gn: (d, d) :func:`gauss_newton_covariance` of ``jac`` (infinite for coordinates with a
            non-finite Jacobian column, zero for held ones).

    Returns:
        ``(cov, inflation)``: (d, d) covariance D cov_gn D with D = diag(inflation), and (d,)
        inflation = max(1, sd_sandwich / sd_gauss_newton) (1 where either is not finite or zero).

    Raises:
        ValueError: ``series`` does not add up to R.
    """
    jac, resid = np.asarray(jac, np.float64), np.asarray(resid, np.float64)
    R, d = jac.shape
    if sum(t * m for t, m in series) != R or resid.shape != (R,):
        raise ValueError(f"series {list(series)} do not make up {R} residuals (got {resid.shape})")
    var_gn = np.diag(cov_gn)
    good = np.isfinite(var_gn) & (var_gn > 0) & np.all(np.isfinite(jac), axis=0)
    inflation = np.ones(d)
    if not good.any() or not np.all(np.isfinite(resid)):
        return cov_gn, inflation
    blocks, at = [], 0
    for t, m in series:
        blocks.append((resid[at:at + t * m].reshape(t, m), jac[at:at + t * m][:, good].reshape(t, m, -1)))
        at += t * m
    lag0 = sum(float(np.sum(r * r)) for r, _ in blocks)
    lag1 = sum(float(np.sum(r[:, 1:] * r[:, :-1])) for r, _ in blocks)
    rho = float(np.clip(lag1 / lag0, -0.97, 0.97)) if lag0 > 0 else 0.0
    alpha = 4 * rho ** 2 / ((1 - rho) ** 2 * (1 + rho) ** 2)
    n = max(np.count_nonzero(resid) / max(sum(t for t, _ in series), 1), 2.0)  # used samples per series
    L = int(min(max(math.ceil(1.1447 * (alpha * n) ** (1 / 3)), 1), n - 1))
    S0 = np.zeros((int(good.sum()),) * 2)  # White's: the lag-0 term
    lags = np.zeros_like(S0)  # the weighted lag terms of Newey-West
    for r, J in blocks:
        g = J * r[..., None]  # (T, M, d') score contributions
        S0 += np.einsum("tki,tkj->ij", g, g)
        for lag in range(1, min(L, g.shape[1] - 1) + 1):
            c = np.einsum("tki,tkj->ij", g[:, :-lag], g[:, lag:])
            lags += (1 - lag / (L + 1)) * (c + c.T)
    A = cov_gn[np.ix_(good, good)]
    var_hac = np.maximum(np.diag(A @ (S0 + lags) @ A), np.diag(A @ S0 @ A))
    inflation[good] = np.sqrt(np.maximum(var_hac / var_gn[good], 1.0))
    D = np.where(good, inflation, 1.0)
    return np.where(np.isfinite(cov_gn), cov_gn * D[:, None] * D[None, :], cov_gn), inflation


def residual_series(likelihood) -> list[tuple[int, int]] | None:
    """The (T, M) blocks of a likelihood's residual vector (one per video of a joint fit), or
    None where it has none (:func:`robust_covariance`)."""
    parts = getattr(likelihood, "likelihoods", None) or (likelihood,)
    shapes = [tuple(getattr(lik, "obs").shape) for lik in parts if hasattr(lik, "obs")]
    return shapes if len(shapes) == len(parts) and all(len(s) == 2 for s in shapes) else None


def widened(jac: np.ndarray, resid: np.ndarray, likelihood, cov_gn: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`robust_covariance` of a fit whose likelihood's residual layout is known
    (:func:`residual_series`); else ``(cov_gn, None)``."""
    series = residual_series(likelihood)
    if series is None:
        return cov_gn, None
    return robust_covariance(jac, resid, series, cov_gn)


def gauss_newton_draws(res: GradResult, space, key: jax.Array, n: int) -> np.ndarray:
    """(n, d) draws of theta from the Gauss-Newton normal approximation N(z_hat, cov_z) of a fit
    (the held coordinates of ``res.fixed`` stay at their values). Where the profile check
    (:attr:`GradResult.profile`) widened a side of a coordinate's interval, that side of its
    draws is stretched about z_hat (a split normal in z) so their 5% and 95% quantiles are the
    reported interval's ends."""
    from galileo_jax.inference.profile import MAX_Z_DISTANCE

    free = [j for j, name in enumerate(res.names) if name not in res.fixed]
    zf = jax.random.multivariate_normal(key, jnp.asarray(res.z[free]), jnp.asarray(res.cov_z[np.ix_(free, free)]), (n,))
    z = np.array(jnp.asarray(res.z)[None].repeat(n, 0).at[:, free].set(zf), np.float64)
    for name, entry in ((res.profile or {}).get("parameters") or {}).items():
        if entry["method"] != "profile":
            continue
        j = res.names.index(name)
        ends = np.full((2, len(res.names)), np.asarray(res.theta, np.float64))
        ends[:, j] = entry["interval90_profile"]
        z_ends = np.asarray(space.to_unconstrained(jnp.asarray(ends)), np.float64)[:, j]
        # an end at a bound: as far as the check looked
        z_ends = np.clip(z_ends, res.z[j] - MAX_Z_DISTANCE, res.z[j] + MAX_Z_DISTANCE)
        z_gn = res.z[j] + Z90 * np.sqrt(max(float(res.cov_z[j, j]), 0.0)) * np.array([-1.0, 1.0])
        with np.errstate(divide="ignore", invalid="ignore"):
            stretch = np.nan_to_num((z_ends - res.z[j]) / (z_gn - res.z[j]), nan=1.0, posinf=1.0)
        z[:, j] = res.z[j] + (z[:, j] - res.z[j]) * np.where(z[:, j] < res.z[j], stretch[0], stretch[1])
    theta_free = np.asarray(space.from_unconstrained(jnp.asarray(z)))
    out = np.repeat(np.asarray(res.theta, np.float64)[None], n, axis=0)
    out[:, free] = theta_free[:, free]
    return out
