"""Gradient-based fit: Levenberg-Marquardt on the standardised residuals, multi-start.

Maximum likelihood for the Gaussian likelihoods is nonlinear least squares,
min_z |r(z)|^2 / 2 with r the whitened residuals (:meth:`Likelihood.residuals`), solved by
Levenberg-Marquardt (Levenberg 1944; Marquardt 1963) from ``optimistix``: each step solves
(J^T J + lambda I) dz = -J^T r with a trust-region update of lambda. Bounds are handled by
reparametrisation: the solver works in the unconstrained z of :class:`~galileo_jax.params.ParamSpace`.

Jacobian. ``jacobian="fd"`` (default) uses central differences in z with step ``fd_step``
through a ``jax.custom_jvp`` (:func:`~galileo_jax.inference.problem.fd_jacobian_fn`);
``jacobian="ad"`` uses forward-mode AD through MJX. AD through the contacts misses how the
parameters move event times (foot of the ramp, the impact), and the simulated profile also
responds non-smoothly to tiny parameter changes (the impact outcome varies by ~0.01 m/s RMS,
up to 0.04 m/s, between k1 values 0.001 apart), so AD Jacobians point the wrong way; a
moderate difference step (0.05 in z, ~0.008 in k1 at k1 = 0.2) averages over that roughness.
Measured (20 degree two-box scene, 1.5 s at 30 fps, 1 mm position noise, truth k1 = 0.2,
k2 = 0.25, phi = 1/3, default likelihood, the same 4 screened starts, 40 steps at most):

    jacobian      best start: error (k1, k2, phi)     cost    steps   starts within (0.02, 0.03, 0.1)
    fd, h = 0.05  -0.0008, +0.0014, -0.0003           34.2    23      2 of 4
    ad            +0.0009, +0.0220, -0.0195           33.0    26      1 of 4 (the others stall, k1 off by 0.003-0.010)

With sd_model = 0.01 the FD steps h = 0.02, 0.05, 0.1 reached costs 77.9, 72.9, 76.8 (AD 75.1);
with 6 unscreened starts FD found the optimum from 1, AD from none (best cost 206.6, k2 and
phi off by 0.15). AD's lower cost at 0.05 is a spike of the rough cost surface, not a
better fit; FD steps average over them, so FD is the default.

Multi-start: ``n_screen`` Latin-hypercube points over the prior box are ranked by likelihood in
one batched rollout, and the best ``n_starts`` (plus an optional given start, e.g. from the CNN)
are solved together, vmapped, so each LM iteration is one batched set of rollouts; the start
with the lowest cost wins. (Unscreened starts mostly stall: where object 1 does not slide,
k1 >= tan(theta), the residuals do not depend on the parameters at all.)

Several videos: a :class:`~galileo_jax.inference.joint.JointProblem` has the same interface
(``space``, ``residual_fn``, ``log_likelihood``, ``likelihood.log_norm``), so the same code
fits them jointly: the screen ranks the summed log-likelihood, LM minimises the concatenated
residuals, and the covariance is that of the joint coordinates.

Uncertainty: the Gauss-Newton (Laplace) approximation at the optimum. With standardised
residuals J^T J is the Fisher information, so Cov(z) = (J^T J)^-1 (J by central differences),
mapped to theta by the delta method Cov(theta) = G Cov(z) G^T with G = diag(d theta / d z);
90% intervals are z_hat +- 1.645 sd_z mapped through the (monotone) transform, so they stay
inside the bounds.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from galileo_jax.inference.problem import DEFAULT_FD_STEP, Problem

if TYPE_CHECKING:
    from galileo_jax.inference.joint import JointProblem

#: Normal quantile for a central 90% interval.
Z90 = 1.6448536269514722


class GradResult(NamedTuple):
    """Result of :func:`fit_grad` (NumPy arrays, ready for reports).

    Attributes:
        names: coordinate names (d,).
        theta: (d,) best estimate in physical coordinates.
        z: (d,) best estimate in unconstrained coordinates.
        cov_z: (d, d) Gauss-Newton covariance of z, (J^T J)^-1.
        cov_theta: (d, d) delta-method covariance of theta.
        sd: (d,) sqrt(diag(cov_theta)).
        interval90: (d, 2) 90% interval (z_hat +- 1.645 sd_z, mapped to theta).
        cost: |r|^2 / 2 at the estimate (standardised residuals).
        loglik: log-likelihood at the estimate (nats).
        iterations: LM steps of the winning start.
        converged: whether the winning start met the tolerances.
        result: optimistix result message of the winning start ("" when successful).
        starts_theta0: (S, d) starting points.
        starts_theta: (S, d) end points.
        starts_cost: (S,) end costs.
        starts_iterations: (S,) LM steps per start.
        starts_converged: (S,) per-start convergence flags.
        jacobian: "fd" or "ad".
        time_s: wall time of the solve (including compilation) in s.
    """

    names: tuple[str, ...]
    theta: np.ndarray
    z: np.ndarray
    cov_z: np.ndarray
    cov_theta: np.ndarray
    sd: np.ndarray
    interval90: np.ndarray
    cost: float
    loglik: float
    iterations: int
    converged: bool
    result: str
    starts_theta0: np.ndarray
    starts_theta: np.ndarray
    starts_cost: np.ndarray
    starts_iterations: np.ndarray
    starts_converged: np.ndarray
    jacobian: str
    time_s: float


def latin_hypercube_starts(problem: "Problem | JointProblem", key: jax.Array, n: int, margin: float = 0.05) -> jax.Array:
    """n starting points theta (n, d), a Latin hypercube over the bounds (shrunk by ``margin``)."""
    d = problem.dim
    k_perm, k_u = jax.random.split(key)
    perms = jnp.stack([jax.random.permutation(k, n) for k in jax.random.split(k_perm, d)], axis=1)
    u = (perms + jax.random.uniform(k_u, (n, d))) / n
    u = margin + (1.0 - 2.0 * margin) * u
    lo, hi = problem.space._bounds()
    return lo + (hi - lo) * u


def gauss_newton_covariance(jac: np.ndarray, ridge: float = 1e-9) -> np.ndarray:
    """(J^T J)^-1 for a (n, d) Jacobian of standardised residuals (pseudo-inverse if singular)."""
    jtj = jac.T @ jac
    jtj = jtj + ridge * np.trace(jtj) / max(jtj.shape[0], 1) * np.eye(jtj.shape[0])
    return np.linalg.pinv(jtj, hermitian=True)


def fit_grad(problem: "Problem | JointProblem", key: jax.Array, *, n_starts: int = 4, n_screen: int = 256,
             init: np.ndarray | None = None,
             jacobian: str = "fd", fd_step: float = DEFAULT_FD_STEP, rtol: float = 1e-4, atol: float = 1e-4,
             max_steps: int = 40) -> GradResult:
    """Multi-start Levenberg-Marquardt maximum-likelihood fit with a Gauss-Newton uncertainty.

    Arguments:
        problem: the :class:`Problem`, or a :class:`~galileo_jax.inference.joint.JointProblem`
            of several videos (shared and per-video parameters; its residuals are all the
            videos' together, ``names`` the joint names). Its likelihood must be Gaussian.
        key: PRNG key for the starting points.
        n_starts: number of starts: the best ``n_starts`` of ``n_screen`` Latin-hypercube
            points over the prior box, ranked by likelihood in one batched call.
        n_screen: number of screened candidate points (>= n_starts).
        init: optional extra start theta (d,) (e.g. from a CNN), tried in addition.
        jacobian: "fd" (central differences, default) or "ad" (forward-mode AD).
        fd_step: difference step in z for "fd" and for the final covariance.
        rtol, atol: optimistix LM tolerances (on z and on the cost).
        max_steps: LM step limit per start.

    Returns:
        :class:`GradResult`.

    Raises:
        ValueError: n_starts < 1 with no init, bad init shape or values outside the bounds,
            unknown jacobian, or a non-Gaussian likelihood.

    References:
        K. Levenberg (1944), Quart. Appl. Math. 2:164-168; D. W. Marquardt (1963),
        J. SIAM 11:431-441.
    """
    space = problem.space
    d = space.dim
    res_fn = problem.residual_fn(jacobian, fd_step)
    res_fd = problem.residual_fn("fd", fd_step)
    if n_starts < 0 or (n_starts == 0 and init is None):
        raise ValueError(f"need at least one start: n_starts = {n_starts}, init = {init}")
    if n_screen < n_starts:
        raise ValueError(f"n_screen ({n_screen}) must be >= n_starts ({n_starts})")
    starts = []
    if init is not None:
        init = np.asarray(init, np.float64)
        if init.shape != (d,):
            raise ValueError(f"init must have shape ({d},) for parameters {list(space.names)}, got {init.shape}")
        lo, hi = np.asarray(space.lower), np.asarray(space.upper)
        if not np.all((init > lo) & (init < hi)):
            raise ValueError(f"init {init.tolist()} is outside the bounds {list(zip(space.lower, space.upper))}")
        starts.append(jnp.asarray(init, jnp.float32)[None])
    t0 = time.perf_counter()
    if n_starts > 0:
        cand = latin_hypercube_starts(problem, key, n_screen)
        ll = np.asarray(problem.log_likelihood(space.to_unconstrained(cand)))
        ll = np.where(np.isfinite(ll), ll, -np.inf)
        starts.append(cand[np.argsort(-ll, kind="stable")[:n_starts]])
    theta0 = jnp.concatenate(starts)
    z0 = space.to_unconstrained(theta0)

    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)

    def solve_one(z_init):
        sol = optx.least_squares(lambda z, _: res_fn(z), solver, z_init, max_steps=max_steps,
                                 throw=False, options={"jac": "fwd"})
        r = res_fn(sol.value)
        cost_end = 0.5 * jnp.sum(r**2)
        # Never end worse than the start: on the rough cost surface an accepted LM step can
        # (rarely) raise the cost, and a refit that starts at the base model's optimum must
        # not report less than the base model.
        cost_start = 0.5 * jnp.sum(res_fn(z_init) ** 2)
        worse = ~(cost_end <= cost_start)
        z_out = jnp.where(worse, z_init, sol.value)
        ok = sol.result == optx.RESULTS.successful
        return z_out, jnp.where(worse, cost_start, cost_end), sol.stats["num_steps"], ok, sol.result._value

    z_end, cost, steps, ok, codes = jax.jit(jax.vmap(solve_one))(z0)
    cost = np.asarray(cost, np.float64)
    cost = np.where(np.isfinite(cost), cost, np.inf)
    best = int(np.argmin(cost))
    z_hat = z_end[best]
    jac = np.asarray(jax.jit(jax.jacfwd(res_fd))(z_hat), np.float64)
    elapsed = time.perf_counter() - t0

    cov_z = gauss_newton_covariance(jac)
    z_hat_np = np.asarray(z_hat, np.float64)
    g = np.asarray(space.dtheta_dz(z_hat), np.float64)
    cov_theta = g[:, None] * cov_z * g[None, :]
    sd_z = np.sqrt(np.maximum(np.diag(cov_z), 0.0))
    ends = np.stack([z_hat_np - Z90 * sd_z, z_hat_np + Z90 * sd_z], axis=-1)  # (d, 2)
    interval = np.asarray(space.from_unconstrained(jnp.asarray(ends.T, jnp.float32)), np.float64).T
    theta_hat = np.asarray(space.from_unconstrained(z_hat), np.float64)
    code = int(np.asarray(codes)[best])
    message = _result_message(code)
    return GradResult(
        names=space.names, theta=theta_hat, z=z_hat_np, cov_z=cov_z, cov_theta=cov_theta,
        sd=np.sqrt(np.maximum(np.diag(cov_theta), 0.0)), interval90=interval,
        cost=float(cost[best]), loglik=float(-cost[best] + problem.likelihood.log_norm),
        iterations=int(np.asarray(steps)[best]), converged=bool(np.asarray(ok)[best]), result=message,
        starts_theta0=np.asarray(theta0, np.float64),
        starts_theta=np.asarray(space.from_unconstrained(z_end), np.float64), starts_cost=cost,
        starts_iterations=np.asarray(steps), starts_converged=np.asarray(ok), jacobian=jacobian,
        time_s=elapsed)


def _result_message(code: int) -> str:
    """Human-readable optimistix result for an integer code ("" = successful)."""
    for name in ("successful", "nonlinear_max_steps_reached", "nonlinear_divergence", "nonfinite"):
        member = getattr(optx.RESULTS, name)
        if int(np.asarray(member._value)) == code:
            return "" if name == "successful" else name
    return f"optimistix result {code}"
