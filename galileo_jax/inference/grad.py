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

Polish: after LM a few rounds of batched random search around the end point (:func:`~galileo_jax.inference.polish.polish`)
move it out of the shallow local minima that the rough cost surface leaves.

Search: the rough surface also has basins that no screened start reaches, 40-70 nats apart on
videos where object 1 pushes object 2 at speed (the simulator resolves that contact
chaotically). With ``search_generations`` (``fit``'s default 40) CMA-ES
(:func:`~galileo_jax.inference.search.cma_search`: 32 points a generation, one batched call
each, so it averages over the ripples LM stops in) runs from the LM (and polish) end, and LM
again from its best point (:func:`searched`). Measured on a held-out blurred world video
(coverage benchmark ``world_35``: plain cubes, perspective, k1 0.040, k2 0.096, phi 0.546),
three screen seeds: log-likelihood 775 / 750 / 773 -> 825 / 816 / 814 (LM started at the truth:
820), k2 0.152 / 0.147 / 0.138 -> 0.098 / 0.107 / 0.100, phi 0.545 / 0.709 / 0.645 -> 0.578 /
0.630 / 0.607, for up to 1,281 more rollouts (the search stops after :data:`SEARCH_PATIENCE`
generations without progress).

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

That covariance holds if the standardised residuals are independent with unit variance. Where
the model misfits (tracking errors a few px long during motion blur, a missing effect, the
simulator's roughness at the impact) they are correlated over many frames, and the data hold
fewer independent pieces of information than samples. Each coordinate's variance is therefore
also estimated by the heteroscedasticity-
and autocorrelation-consistent "sandwich" (J^T J)^-1 S (J^T J)^-1 (:func:`~galileo_jax.inference.covariance.robust_covariance`:
Newey & West 1987, Bartlett weights, the bandwidth from the residuals' lag-1 autocorrelation
by Andrews 1991), and where it is larger the coordinate's interval is widened by the ratio of
the two SDs (:attr:`GradResult.inflation`), keeping the Gauss-Newton correlations. Where the
residuals are smaller than the likelihood's noise (the model-error floor dominates) the
sandwich is smaller, and the Gauss-Newton covariance stands. Measured: a likelihood claiming
half the noise there is, 90% coverage 0.50 -> 0.85 (``tests/test_coverage_check.py``); on the
coverage benchmark (``benchmarks/results/coverage.md``: 90% coverage 0.68 / 0.72 / 0.72 of the
truths of k1 / k2 / phi) the widening moves coverage by at most 0.04 (its ``grad-plain`` rows,
the same fits unwidened): the floor keeps most videos' residuals below the noise, and the
misses there are biases of many SDs, which no covariance estimate covers.

Both covariances assume the log-likelihood is quadratic out to the interval's ends. With
``profile=True`` (``fit``'s default, ``grad.profile``) each physical parameter's interval is
checked against its profile likelihood (:mod:`galileo_jax.inference.profile`: held fits at the
interval's ends, batched) and widened to the profile's 90% end on a side where the profile is
flatter; the result says which interval each parameter got (:attr:`GradResult.profile`).
"""

from __future__ import annotations

import time
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from galileo_jax.inference.covariance import Z90, gauss_newton_covariance, widened
from galileo_jax.inference.polish import polish
from galileo_jax.inference.problem import DEFAULT_FD_STEP, pad_rows
from galileo_jax.inference.starts import diverse_best, latin_hypercube_starts, start_point, unit_box
from galileo_jax.params import nuisances_at_edge


class GradResult(NamedTuple):
    """Result of :func:`fit_grad` (NumPy arrays, ready for reports).

    Attributes:
        names: coordinate names (d,).
        theta: (d,) best estimate in physical coordinates.
        z: (d,) best estimate in unconstrained coordinates.
        cov_z: (d, d) Gauss-Newton covariance of z, (J^T J)^-1 (zero rows/columns for held parameters).
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
        fixed: names of the parameters held at given values (not fitted).
        inflation: (d,) factor by which each coordinate's Gauss-Newton SD was widened to the
            sandwich estimate's (:func:`~galileo_jax.inference.covariance.robust_covariance`; 1 where it was not), or None.
        profile: the profile-likelihood check of the intervals (:func:`profile_check`, as
            :meth:`ProfileCheck.report` gives it), or None where it was not run. Where it
            disagreed with the Gauss-Newton interval, ``interval90`` holds the profile's end.
        search: the CMA-ES search after LM (:func:`searched`): ``evaluations`` (rollouts),
            ``generations``, ``loglik_gain`` (nats the search gained over its start),
            ``kept`` (whether LM from its best replaced the fit) and then ``cost_drop`` (nats)
            and ``refit_steps`` (that LM's steps); None where none ran.
        inside: the refits from inside the window of a calibration nuisance that had ended at
            one of its ends (:func:`from_inside`): ``nuisances``, ``starts``, ``cost_drop``
            (nats), ``kept``; None where none was at an end.
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
    fixed: tuple[str, ...] = ()
    inflation: np.ndarray | None = None
    profile: dict | None = None
    search: dict | None = None
    inside: dict | None = None


#: Most Levenberg-Marquardt starts vmapped into one solve; more run as several calls of the same
#: jitted solver, chunks of exactly this many starts (the last padded with copies of its last
#: start, so one compiled shape serves every chunk). Why: on the MJX engine each LM step of S
#: starts is one batch of S (2d + 1) rollouts, and jaxlib 0.10.2's batched LAPACK Cholesky in
#: MJX's solver deadlocked (every XLA thread asleep) at 64 starts (576 rollouts; d = 4) on
#: 2 cores, where 32 ran; 16 keeps a batch at <= 16 (2d + 1) rollouts (144 for d = 4), and
#: MJX's throughput is flat above batch 16 (:data:`~galileo_jax.inference.problem.DEFAULT_MAX_BATCH`).
MAX_LM_STARTS = 16


#: On the C engine (``problem.pads_batches``) a call of S <= :data:`MAX_LM_STARTS` starts is
#: padded to a multiple of this many (``fit``'s default number of starts): a refit from one
#: point then runs the main fit's compiled program instead of compiling its own (about 1.5 s the
#: first time, then from the persistent cache).
LM_PAD = 4


def solve_starts(solve, z0: jax.Array, data, chunk: int | None = None, pad_to: int = 1) -> tuple:
    """Run a jitted ``solve(z0s (S, d), data)`` (:func:`_lm_solver`) over all starts, at most
    ``chunk`` (default :data:`MAX_LM_STARTS`) per call.

    Arguments:
        solve: the jitted vmapped solver; its outputs all have the starts as leading axis.
        z0: (S, d) starting points in z.
        data: the problem's data pytree (passed through).
        chunk: starts per call; S <= chunk runs as one call of shape (S, d), padded with copies
            of the last start to a multiple of ``pad_to`` (at most ``chunk``).
        pad_to: see ``chunk`` (:data:`LM_PAD` where the problem pads its batches, else 1).

    Returns:
        ``solve``'s outputs for all S starts, in order (JAX arrays, as ``solve`` returns them).

    Raises:
        ValueError: chunk < 1.
    """
    chunk = MAX_LM_STARTS if chunk is None else int(chunk)
    if chunk < 1:
        raise ValueError(f"chunk must be >= 1, got {chunk}")
    n = int(z0.shape[0])
    if n <= chunk:
        size = min(-(-n // max(int(pad_to), 1)) * max(int(pad_to), 1), chunk)
        if size == n:
            return solve(z0, data)
        return tuple(jnp.asarray(np.asarray(o)[:n]) for o in solve(jnp.asarray(pad_rows(z0, size)), data))
    z0 = np.asarray(z0)
    parts = []
    for i in range(0, n, chunk):
        zc = z0[i:i + chunk]  # padded with copies of the last start: same shape, same compiled program
        parts.append([np.asarray(o)[:zc.shape[0]] for o in solve(jnp.asarray(pad_rows(zc, chunk)), data)])
    return tuple(jnp.asarray(np.concatenate(p)) for p in zip(*parts))


def residual_jacobian(res_fn: Callable) -> Callable:
    """Pure ``f(z (d,), data) -> (r (R,), jac (R, d))``: ``res_fn(z, data)`` and its Jacobian
    at z (``jacfwd``; with :func:`~galileo_jax.inference.problem.fd_jacobian_fn`'s residuals,
    the finite-difference Jacobian)."""
    def both(z, data):  # one evaluation of the residuals: jacfwd returns them as its auxiliary output
        jac, r = jax.jacfwd(lambda zz: (res_fn(zz, data),) * 2, has_aux=True)(z)
        return r, jac

    return both


def lm_no_worse(res_fn, solver, z_init, args, max_steps: int):
    """Levenberg-Marquardt from ``z_init`` on ``res_fn(z, args)`` that never ends worse than it
    started: on the rough cost surface an accepted LM step can (rarely) raise the cost, and a
    refit that starts at the base model's optimum must not report less than the base model.
    Returns ``(z, cost |r|^2 / 2, optimistix solution)`` (pure; vmappable)."""
    sol = optx.least_squares(lambda z, a: res_fn(z, a), solver, z_init, args=args, max_steps=max_steps,
                             throw=False, options={"jac": "fwd"})
    cost_end = 0.5 * jnp.sum(res_fn(sol.value, args) ** 2)
    cost_start = 0.5 * jnp.sum(res_fn(z_init, args) ** 2)
    worse = ~(cost_end <= cost_start)
    return jnp.where(worse, z_init, sol.value), jnp.where(worse, cost_start, cost_end), sol


def _lm_solver(res_fn, rtol: float, atol: float, max_steps: int):
    """Pure ``solve(z0s (S, d), data)``: vmapped Levenberg-Marquardt from S starts."""
    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)

    def solve_one(z_init, data):
        z_out, cost, sol = lm_no_worse(res_fn, solver, z_init, data, max_steps)
        ok = sol.result == optx.RESULTS.successful
        return z_out, cost, sol.stats["num_steps"], ok, sol.result._value

    return jax.vmap(solve_one, in_axes=(0, None))


def fit_grad(problem, key: jax.Array, *, n_starts: int = 4, n_screen: int = 256,
             init: np.ndarray | None = None, fixed: dict[str, float] | None = None,
             jacobian: str = "fd", fd_step: float = DEFAULT_FD_STEP, rtol: float = 1e-4, atol: float = 1e-4,
             max_steps: int = 40, polish_rounds: int = 3, polish_points: int = 64,
             local_screen: float | np.ndarray | None = None, profile: bool = False,
             search_generations: int = 0, inside: bool = False) -> GradResult:
    """Multi-start Levenberg-Marquardt maximum-likelihood fit with a Gauss-Newton uncertainty.

    Arguments:
        problem: the :class:`~galileo_jax.inference.problem.Problem`, or a
            :class:`~galileo_jax.inference.joint.JointProblem` of several videos (shared and
            per-video parameters; its residuals are all the videos' together, ``names`` the
            joint names). Its likelihood must be Gaussian.
        key: PRNG key for the starting points.
        n_starts: number of starts: the best ``n_starts`` of ``n_screen`` Latin-hypercube
            points over the prior box, ranked by likelihood in one batched call.
        n_screen: number of screened candidate points (>= n_starts).
        init: optional extra start theta (d,) (e.g. from a CNN or an earlier fit), tried in
            addition (the entries of held parameters are ignored). Entries on or within
            :data:`~galileo_jax.inference.starts.INIT_MARGIN` of the range of a bound are moved to that distance: the
            logistic transform is flat at the bounds, so LM could not leave a start there.
        fixed: optional {name: value}: parameters held at these values, not fitted
            (:class:`~galileo_jax.inference.fixed.FixedProblem`); the result is still in the
            problem's full coordinates, held ones with zero variance.
        jacobian: "fd" (central differences, default) or "ad" (forward-mode AD).
        fd_step: difference step in z for "fd" and for the final covariance.
        rtol, atol: optimistix LM tolerances (on z and on the cost).
        max_steps: LM step limit per start.
        polish_rounds, polish_points: after LM, rounds of a batched local random search
            (:func:`~galileo_jax.inference.polish.polish`; 0 rounds switch it off).
        local_screen: with ``init``, screen the starts within +-``local_screen`` (a fraction,
            or (d,) fractions, one per coordinate) of each range around ``init`` instead of
            over the whole prior box, effect parameters excepted (:func:`~galileo_jax.inference.starts.latin_hypercube_starts`).
        profile: check each physical parameter's interval against its profile likelihood
            (:func:`~galileo_jax.inference.profile.profile_check`); where they disagree the
            profile's 90% end replaces the Gauss-Newton one (:attr:`GradResult.profile` says
            which was used).
        search_generations: after LM and the polish, this many generations of CMA-ES
            (:func:`~galileo_jax.inference.search.cma_search`, :data:`SEARCH_POPSIZE` points
            each, step :data:`SEARCH_SIGMA` in z) from the best point, then LM from the
            search's best (:func:`refit_from`), kept where it ends lower (module docstring,
            "Search"); 0: none. ``fit``'s default is ``GradConfig.search_generations``.
        inside: fit again from inside the window of a calibration nuisance that ended at one of
            its ends (:func:`from_inside`), after the search. ``fit``'s default is
            ``GradConfig.inside`` (on); ``diagnose``'s refits leave it off.

    Returns:
        :class:`GradResult`.

    Raises:
        ValueError: n_starts < 1 with no init, bad init shape or values outside the bounds,
            unknown jacobian, a non-Gaussian likelihood, or bad ``fixed`` names/values.

    References:
        K. Levenberg (1944), Quart. Appl. Math. 2:164-168; D. W. Marquardt (1963),
        J. SIAM 11:431-441.
    """
    if jacobian == "ad" and getattr(problem, "simulator_engine", "mjx") != "mjx":
        raise ValueError(f"jacobian 'ad' needs the MJX engine (the {problem.simulator_engine} engine has no "
                         "derivatives); use jacobian 'fd' or engine 'mjx'")
    if fixed:
        from galileo_jax.inference.fixed import FixedProblem

        sub = FixedProblem(problem, fixed)
        if init is not None:
            init = np.asarray(init, np.float64)
            if init.shape != (problem.dim,):
                raise ValueError(f"init must have shape ({problem.dim},) for parameters {list(problem.names)}, "
                                 f"got {init.shape}")
            init = init[list(sub.free)]
        res = fit_grad(sub, key, n_starts=n_starts, n_screen=n_screen, init=init, jacobian=jacobian,
                       fd_step=fd_step, rtol=rtol, atol=atol, max_steps=max_steps, polish_rounds=polish_rounds,
                       polish_points=polish_points, local_screen=local_screen, profile=profile,
                       search_generations=search_generations, inside=inside)
        return _expand(res, sub)
    space = problem.space
    res_fn = problem.residual_fn(jacobian, fd_step)
    if n_starts < 0 or (n_starts == 0 and init is None):
        raise ValueError(f"need at least one start: n_starts = {n_starts}, init = {init}")
    if n_screen < n_starts:
        raise ValueError(f"n_screen ({n_screen}) must be >= n_starts ({n_starts})")
    starts = []
    if init is not None:
        init = start_point(space, init)
        starts.append(jnp.asarray(init)[None])
    t0 = time.perf_counter()
    if n_starts > 0:
        around = None if (local_screen is None or init is None) else init
        spread = 0.25 if local_screen is None else jnp.asarray(local_screen, jnp.float64)
        cand = latin_hypercube_starts(problem, key, n_screen, around=around, spread=spread)
        ll = problem.log_likelihood(space.to_unconstrained(cand))  # failed rollouts: diverse_best ranks them last
        starts.append(cand[np.asarray(diverse_best(unit_box(cand, *space._bounds(), space.kinds), ll, n_starts))])
    theta0 = jnp.concatenate(starts)
    z0 = space.to_unconstrained(theta0)

    solve = problem.jitted(("lm", jacobian, fd_step, rtol, atol, max_steps), _lm_solver(res_fn, rtol, atol, max_steps))
    z_end, cost, steps, ok, codes = solve_starts(solve, z0, problem.data,  # chunked: MAX_LM_STARTS
                                                 pad_to=LM_PAD if problem.pads_batches else 1)
    cost = np.asarray(cost, np.float64)
    cost = np.where(np.isfinite(cost), cost, np.inf)
    best = int(np.argmin(cost))
    z_hat = z_end[best]
    r, jac, cov_z = _linearised(problem, z_hat, fd_step)
    best_cost = float(cost[best])
    if polish_rounds > 0:
        z_pol, cost_pol = polish(problem, jax.random.fold_in(key, 7), np.asarray(z_hat, np.float64), best_cost, cov_z,
                                 rounds=polish_rounds, points=polish_points)
        if cost_pol < best_cost:
            z_hat, best_cost = jnp.asarray(z_pol), cost_pol
            r, jac, cov_z = _linearised(problem, z_hat, fd_step)
    cov_z, inflation = widened(jac, r, problem.likelihood, cov_z)
    res = grad_result(space, problem.likelihood.log_norm, z_hat, cov_z, best_cost, theta0, z_end, cost, steps, ok,
                      codes, best, jacobian, 0.0, inflation)
    res = after_lm(res, problem, key, search_generations=search_generations, profile=profile, inside=inside,
                   fd_step=fd_step, rtol=rtol, atol=atol, max_steps=max_steps)
    return res._replace(time_s=time.perf_counter() - t0)


def after_lm(res: GradResult, problem, key: jax.Array, *, search_generations: int = 0, profile: bool = False,
             inside: bool = False, fd_step: float = DEFAULT_FD_STEP, rtol: float = 1e-4, atol: float = 1e-4,
             max_steps: int = 40) -> GradResult:
    """The stages of :func:`fit_grad` after LM and the polish, for one fit ``res`` of ``problem``
    (also one video's of a batch, :func:`~galileo_jax.inference.batch.fit_grad_batch`, with the
    batch's ``key``): the search (:func:`searched`, ``search_generations`` > 0, its key folded
    from ``key``), the refits from inside a nuisance's window (:func:`from_inside`, ``inside``),
    then the profile check (:func:`with_profile`, ``profile``), whose refit keeps the records of
    both."""
    if search_generations > 0:
        res = searched(res, problem, jax.random.fold_in(key, 13), search_generations, fd_step=fd_step, rtol=rtol,
                       atol=atol, max_steps=max_steps)
    if inside:
        res = from_inside(res, problem, fd_step=fd_step, rtol=rtol, atol=atol, max_steps=max_steps)
    if profile:
        res = with_profile(res, problem, fd_step=fd_step, rtol=rtol, atol=atol, max_steps=max_steps)._replace(
            search=res.search, inside=res.inside)
    return res


#: Where in its window (shares of its width from the lower end) a calibration nuisance that
#: ended at an end of it is put to fit again from (:func:`from_inside`).
INSIDE_STARTS = (0.25, 0.5, 0.75)


def from_inside(res: GradResult, problem, *, fd_step: float = DEFAULT_FD_STEP, rtol: float = 1e-4,
                atol: float = 1e-4, max_steps: int = 40) -> GradResult:
    """``res`` fitted again from inside the window of each calibration nuisance (``dt_release``,
    ``scale_error``) that ended at one of its ends
    (:func:`~galileo_jax.params.nuisances_at_edge`): Levenberg-Marquardt (:func:`refit_from`)
    from ``res``'s end point with that nuisance moved to each of :data:`INSIDE_STARTS` of its
    window, the lowest end kept where it is below ``res.cost``. A ridge of friction, release
    time and scale lets LM slide to a window's end, and from there the logistic transform's
    flat tail holds it. Measured on the coverage benchmark's world_29 (grad ended with
    scale_error at -3%, cost 63.4, k1 0.0220, phi -0.085; truth 0.0206, -0.138): from inside,
    cost 28.1, k1 0.0209 [0.0200, 0.0218], k2 0.0239 (truth 0.0239), phi -0.131, scale +2.9%.
    ``res.inside`` records the nuisances, the starts tried, the cost drop and whether a refit
    was kept; None where no nuisance was at an end (nothing is fitted again)."""
    space = problem.space
    edges = nuisances_at_edge(space, res.theta)
    if not edges:
        return res
    best = res
    for j in edges:
        lo, hi = float(space.lower[j]), float(space.upper[j])
        for share in INSIDE_STARTS:
            start = np.asarray(res.theta, np.float64).copy()
            start[j] = lo + share * (hi - lo)
            z = np.asarray(space.to_unconstrained(jnp.asarray(start)), np.float64)
            better = refit_from(best, problem, z, fd_step=fd_step, rtol=rtol, atol=atol, max_steps=max_steps)
            if better is not None:
                best = better
    info = {"nuisances": [space.names[j] for j in edges], "starts": len(edges) * len(INSIDE_STARTS),
            "cost_drop": float(res.cost - best.cost), "kept": best is not res}
    # a profile check of res (if one ran) was of its old end point: not carried over to a refit
    return best._replace(search=res.search, inside=info)


#: CMA-ES points per generation of the search after LM (:func:`searched`).
SEARCH_POPSIZE = 32
#: CMA-ES initial step in z of that search (0.5: about 12% of a range around its middle).
SEARCH_SIGMA = 0.5
#: The search stops after this many generations in a row that raised its best log-likelihood by
#: at most 0.5 nats. Measured on world_35 (module docstring, "Search"; three seeds): the gains
#: come every 1-10 generations until about the 30th; where there is nothing to find (the README
#: example) the search then costs 12 generations instead of 40.
SEARCH_PATIENCE = 12


def searched(res: GradResult, problem, key: jax.Array, generations: int, *, fd_step: float = DEFAULT_FD_STEP,
             rtol: float = 1e-4, atol: float = 1e-4, max_steps: int = 40) -> GradResult:
    """``res`` improved by a global search: at most ``generations`` generations of CMA-ES
    (:func:`~galileo_jax.inference.search.cma_search`, :data:`SEARCH_POPSIZE` points each,
    step :data:`SEARCH_SIGMA` in z, seeded from ``key``, stopped early by
    :data:`SEARCH_PATIENCE` generations without progress) from ``res.theta``, then
    Levenberg-Marquardt from the search's best point (:func:`refit_from`); the refit where it
    ends below ``res.cost``, else ``res`` itself. The search's rollouts (at most
    ``generations * SEARCH_POPSIZE + 1``) and its gain are in ``res.search``."""
    from galileo_jax.inference.search import cma_search

    seed = int(jax.random.randint(key, (), 0, 2**31 - 1))
    # the start rounded to 1e-6 in z: LM ends that differ by floating-point order only (a video
    # fitted alone or in a batch, 1e-9) then start the same search, which would otherwise part
    # in the rough likelihood
    z0 = np.round(np.asarray(res.z, np.float64), 6)
    start = np.asarray(problem.space.from_unconstrained(jnp.asarray(z0)), np.float64)
    found = cma_search(problem, start, sigma=SEARCH_SIGMA, popsize=SEARCH_POPSIZE,
                       generations=generations, seed=seed, patience=SEARCH_PATIENCE)
    info = {"evaluations": int(found.evaluations), "generations": int(found.generations),
            "loglik_gain": float(found.loglik - found.loglik_start), "kept": False}
    better = None
    if found.loglik > found.loglik_start:
        z = np.asarray(problem.space.to_unconstrained(jnp.asarray(found.theta)), np.float64)
        better = refit_from(res, problem, z, fd_step=fd_step, rtol=rtol, atol=atol, max_steps=max_steps)
    if better is None:
        return res._replace(search=info)
    info.update(kept=True, cost_drop=float(res.cost - better.cost), refit_steps=int(better.iterations))
    return better._replace(search=info)


#: Levenberg-Marquardt steps at most per held fit of the profile check (each starts at the
#: Gauss-Newton conditional mean, near its optimum).
PROFILE_MAX_STEPS = 20


#: A held fit of the profile check that ends this far (nats) above the fit's own maximum of the
#: log-likelihood shows that the fit stopped short: :func:`with_profile` fits again from that
#: point (a deviance of 1, a shift of about one standard deviation: enough to move an interval).
PROFILE_REFIT_GAIN = 0.5


def with_profile(res: GradResult, problem, *, fd_step: float = DEFAULT_FD_STEP, rtol: float = 1e-4,
                 atol: float = 1e-4, max_steps: int = PROFILE_MAX_STEPS, refits: int = 1) -> GradResult:
    """``res`` (a fit of ``problem``, or one video's of a batch) with its physical parameters'
    intervals checked against the profile likelihood
    (:func:`~galileo_jax.inference.profile.profile_check`; held fits on the FD residuals with
    step ``fd_step``, LM tolerances ``rtol``, ``atol``, at most ``max_steps`` (capped at
    :data:`PROFILE_MAX_STEPS`) steps each): ``interval90`` takes the profile's end on each side
    where the two disagree, and :attr:`GradResult.profile` the check's report. A result with
    held parameters (``res.fixed``) is returned as it is (:func:`fit_grad` checks such a fit on
    its sub-problem).

    Where a held fit ends more than :data:`PROFILE_REFIT_GAIN` nats above the fit's maximum,
    the fit had stopped short: up to ``refits`` times, Levenberg-Marquardt (FD Jacobian, at most
    ``max_steps`` steps) fits all parameters again from that point (:func:`refit_from`), and the
    new optimum is checked in turn; the report's ``refitted_from_gain`` lists the gains that
    led to a refit."""
    from galileo_jax.inference.profile import checked_coords, held_lm_solver, profile_check

    if res.fixed:  # fit_grad checks a fit with held parameters on its sub-problem
        return res
    space = problem.space
    infl = np.ones(space.dim) if res.inflation is None else np.asarray(res.inflation, np.float64)
    with np.errstate(invalid="ignore"):
        cov_gn = np.asarray(res.cov_z, np.float64) / np.outer(infl, infl)  # the Gauss-Newton covariance
    coords = checked_coords(space, cov_gn)
    if not coords:
        return res
    lm = (rtol, atol, min(int(max_steps), PROFILE_MAX_STEPS))
    solve = problem.jitted(("lm_held", fd_step) + lm, held_lm_solver(problem.residual_fn("fd", fd_step), *lm))
    check = profile_check(solve, problem.data, res.z, res.cost, cov_gn, infl, coords,
                          pad_batches=problem.pads_batches)
    if check.loglik_gain > PROFILE_REFIT_GAIN and refits > 0:
        better = refit_from(res, problem, check.best_z, fd_step=fd_step, rtol=rtol, atol=atol, max_steps=max_steps)
        if better is not None:
            out = with_profile(better, problem, fd_step=fd_step, rtol=rtol, atol=atol, max_steps=max_steps,
                               refits=refits - 1)
            if out.profile is not None:
                out.profile["refitted_from_gain"] = [float(check.loglik_gain)] + out.profile.get("refitted_from_gain", [])
            return out
    z = np.asarray(res.z, np.float64)

    def to_theta(j, zj):
        pts = np.repeat(z[None], len(zj), axis=0)
        pts[:, j] = zj
        return np.asarray(space.from_unconstrained(jnp.asarray(pts)), np.float64)[:, j]

    interval = np.array(res.interval90, copy=True)
    for row, j in enumerate(check.coords):
        if check.disagrees[row].any():
            interval[j] = np.where(check.disagrees[row], to_theta(int(j), check.interval_z[row]), interval[j])
    return res._replace(interval90=interval, profile=check.report(space.names, to_theta, res.interval90))


def refit_from(res: GradResult, problem, z_start: np.ndarray, *, fd_step: float = DEFAULT_FD_STEP,
               rtol: float = 1e-4, atol: float = 1e-4, max_steps: int = 40) -> GradResult | None:
    """``res`` fitted again by Levenberg-Marquardt (FD Jacobian with step ``fd_step``,
    tolerances ``rtol``, ``atol``, at most ``max_steps`` steps) from ``z_start`` ((d,) in z; a
    better point met after the fit, e.g. by the profile check's held fits), with a new
    Gauss-Newton (and sandwich) covariance; the start is added to the result's starts. None
    where it does not end below ``res.cost`` (LM never ends above its start's cost)."""
    space = problem.space
    res_fd = problem.residual_fn("fd", fd_step)
    solve = problem.jitted(("lm", "fd", fd_step, rtol, atol, max_steps), _lm_solver(res_fd, rtol, atol, max_steps))
    z_end, cost, steps, ok, codes = solve_starts(solve, jnp.asarray(z_start, jnp.float64)[None], problem.data,
                                                 pad_to=LM_PAD if problem.pads_batches else 1)
    cost = float(np.asarray(cost, np.float64)[0])
    if not (np.isfinite(cost) and cost < res.cost):
        return None
    z_hat = np.asarray(z_end, np.float64)[0]
    r, jac, cov_gn = _linearised(problem, z_hat, fd_step)
    cov_z, inflation = widened(jac, r, problem.likelihood, cov_gn)
    theta_start = np.asarray(space.from_unconstrained(jnp.asarray(z_start, jnp.float64)), np.float64)
    z_all = np.concatenate([np.asarray(space.to_unconstrained(jnp.asarray(res.starts_theta)), np.float64), z_end])
    n = len(res.starts_cost)
    codes_all = np.concatenate([np.zeros(n, int), np.asarray(codes).reshape(1)])  # only the best's code is read
    return grad_result(space, problem.likelihood.log_norm, z_hat, cov_z, cost,
                       np.concatenate([res.starts_theta0, theta_start[None]]), z_all,
                       np.append(res.starts_cost, cost), np.append(res.starts_iterations, np.asarray(steps)[0]),
                       np.append(res.starts_converged, np.asarray(ok)[0]), codes_all, n, res.jacobian, res.time_s,
                       inflation)


def _linearised(problem, z, fd_step: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """At ``z`` ((d,) in z): the standardised residuals (R,), their finite-difference Jacobian
    (R, d) (step ``fd_step``; one jitted program per problem structure) and its
    :func:`~galileo_jax.inference.covariance.gauss_newton_covariance` (d, d)."""
    jac_fn = problem.jitted(("residuals_jacobian_fd", fd_step), residual_jacobian(problem.residual_fn("fd", fd_step)))
    # z as an uncommitted array always: a committed one (an earlier program's output) is another
    # cache entry of the same program, compiled again (C engine: in every process)
    r, jac = (np.asarray(a, np.float64) for a in jac_fn(jnp.asarray(np.asarray(z, np.float64)), problem.data))
    return r, jac, gauss_newton_covariance(jac)


def grad_result(space, log_norm, z_hat, cov_z: np.ndarray, best_cost: float, theta0, z_end, cost, steps, ok, codes,
                best: int, jacobian: str, elapsed: float, inflation: np.ndarray | None = None) -> GradResult:
    """Assemble a :class:`GradResult` from one video's LM end points (shared by :func:`fit_grad`
    and :func:`~galileo_jax.inference.batch.fit_grad_batch`).

    Arguments:
        space: the parameter space; log_norm: the likelihood's normalising constant (nats).
        z_hat: (d,) best point in z; cov_z: (d, d) its Gauss-Newton covariance; best_cost: its cost.
        theta0: (S, d) starts in theta; z_end: (S, d) LM end points in z; cost, steps, ok,
            codes: (S,) per-start cost, LM steps, convergence flag and optimistix result code.
        best: index of the winning start; jacobian: "fd" or "ad"; elapsed: wall time in s.
        inflation: (d,) :attr:`GradResult.inflation` (already applied to ``cov_z``), or None.
    """
    z_hat_np = np.asarray(z_hat, np.float64)
    g = np.asarray(space.dtheta_dz(jnp.asarray(z_hat_np)), np.float64)
    cov_theta = g[:, None] * cov_z * g[None, :]
    sd_z = np.sqrt(np.maximum(np.diag(cov_z), 0.0))
    ends = np.stack([z_hat_np - Z90 * sd_z, z_hat_np + Z90 * sd_z], axis=-1)  # (d, 2)
    interval = np.asarray(space.from_unconstrained(jnp.asarray(ends.T)), np.float64).T
    theta_hat = np.asarray(space.from_unconstrained(jnp.asarray(z_hat_np)), np.float64)
    message = _result_message(int(np.asarray(codes)[best]))
    return GradResult(
        names=space.names, theta=theta_hat, z=z_hat_np, cov_z=cov_z, cov_theta=cov_theta,
        sd=np.sqrt(np.maximum(np.diag(cov_theta), 0.0)), interval90=interval,
        cost=best_cost, loglik=float(-best_cost + log_norm),
        iterations=int(np.asarray(steps)[best]), converged=bool(np.asarray(ok)[best]), result=message,
        starts_theta0=np.asarray(theta0, np.float64),
        starts_theta=np.asarray(space.from_unconstrained(jnp.asarray(z_end)), np.float64), starts_cost=cost,
        starts_iterations=np.asarray(steps), starts_converged=np.asarray(ok), jacobian=jacobian,
        time_s=elapsed, inflation=None if inflation is None else np.asarray(inflation, np.float64))


def count_rollouts(res: GradResult, *, n_screen: int, polish_rounds: int = 3, polish_points: int = 64) -> int:
    """Rollouts the batched programs of one :func:`fit_grad` call asked for (the project's one
    rollout counter: benchmarks compare methods and tools by it). The C engine simulates fewer:
    it remembers recent rollouts (:func:`~galileo_jax.physics.simulate_c.cached_rollout_poses`), and
    a finished start asks for the same ones at every later step.

    The S starts run as one vmapped optimistix while-loop, so every start computes until the
    last one stops: S x max(steps) LM steps, each one central-difference residual Jacobian
    (2d + 1 rollouts, the centre giving the residual), plus the start's and the end point's
    residuals (2 per start); then the screen, the final FD Jacobian (2d + 1) and the polish
    (rounds x points, and the Jacobian again if the polish moved the point); then the search
    (``res.search``: its evaluations and, where LM from its best was kept, that LM's steps x
    (2d + 1) + 2 and the Jacobian; the polish then counts as having moved the point, which
    it may not have: up to 2d + 1 too many). Checked against a callback that counts the rollouts the
    compiled programs ask for, to the rollout (``benchmarks/sysid.py``; without the search). The
    profile-likelihood check (``profile=True``) is not counted.

    Args:
        res: the fit's result (d = ``len(res.z)``).
        n_screen: Latin-hypercube points the fit screened (0 when it started only from ``init``).
        polish_rounds, polish_points: the fit's polish settings.

    Returns:
        the number of rollouts.
    """
    d = len(res.z)
    search = res.search or {}
    kept = bool(search.get("kept"))
    iters = np.asarray(res.starts_iterations)[:-1] if kept else np.asarray(res.starts_iterations)
    costs = np.asarray(res.starts_cost)[:-1] if kept else np.asarray(res.starts_cost)
    s = len(iters)
    lm = s * int(np.max(iters)) * (2 * d + 1) + 2 * s
    moved = polish_rounds > 0 and (kept or res.cost < float(np.min(costs)))
    total = n_screen + lm + (2 * d + 1) * (2 if moved else 1) + polish_rounds * polish_points
    if search:
        total += int(search["evaluations"])
        if kept:
            total += int(search["refit_steps"]) * (2 * d + 1) + 2 + (2 * d + 1)
    return int(total)


def _expand(res: GradResult, sub) -> GradResult:
    """A FixedProblem's result in its parent's coordinates (held parameters: zero variance)."""
    parent = sub.parent.space
    free = list(sub.free)
    dim = parent.dim

    def square(a):
        out = np.zeros((dim, dim))
        out[np.ix_(free, free)] = a
        return out

    theta = sub.full_theta(res.theta)
    interval = np.stack([theta, theta], axis=-1)
    interval[free] = res.interval90
    z = np.asarray(parent.to_unconstrained(jnp.asarray(theta)), np.float64)
    inflation = None
    if res.inflation is not None:
        inflation = np.ones(dim)
        inflation[free] = res.inflation
    return res._replace(names=parent.names, theta=theta, z=z, cov_z=square(res.cov_z), inflation=inflation,
                        cov_theta=square(res.cov_theta), sd=np.sqrt(np.maximum(np.diag(square(res.cov_theta)), 0.0)),
                        interval90=interval, starts_theta0=sub.full_theta(res.starts_theta0),
                        starts_theta=sub.full_theta(res.starts_theta), fixed=tuple(sub.fixed))


def _result_message(code: int) -> str:
    """Human-readable optimistix result for an integer code ("" = successful)."""
    for name in ("successful", "nonlinear_max_steps_reached", "nonlinear_divergence", "nonfinite"):
        member = getattr(optx.RESULTS, name)
        if int(np.asarray(member._value)) == code:
            return "" if name == "successful" else name
    return f"optimistix result {code}"
