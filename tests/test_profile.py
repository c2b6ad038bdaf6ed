"""Profile-likelihood check of grad's intervals (galileo_jax.inference.profile), against the
profile computed by brute force on models whose inner maximisation has a closed form."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from galileo_jax.inference.covariance import Z90, gauss_newton_covariance
from galileo_jax.inference.problem import fd_jacobian_fn
from galileo_jax.inference.profile import PROFILE_TOLERANCE, held_lm_solver, profile_check

X = np.linspace(0.0, 1.0, 40)


def _fit(res_fn, data, z0):
    """The least-squares optimum, its cost and Gauss-Newton covariance (the held solver with a
    dummy third coordinate held would do; plain LM through optimistix here)."""
    import optimistix as optx

    sol = optx.least_squares(lambda z, a: res_fn(z, a), optx.LevenbergMarquardt(rtol=1e-10, atol=1e-10),
                             jnp.asarray(z0), args=data, max_steps=200)
    z = np.asarray(sol.value)
    r = np.asarray(res_fn(sol.value, data))
    jac = np.asarray(jax.jacfwd(lambda zz: res_fn(zz, data))(sol.value))
    return z, 0.5 * float(r @ r), gauss_newton_covariance(jac)


def _brute_profile_end(cost_at, z_hat, cost_hat, side, lo=1e-3, hi=12.0):
    """Where 2 (cost_p(v) - cost_hat) reaches 1.645^2 on one side, by bisection on a closed-form profile."""
    f = lambda dist: np.sqrt(max(2 * (cost_at(z_hat + side * dist) - cost_hat), 0.0)) - Z90  # noqa: E731
    if f(hi) < 0:
        return np.inf
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if f(mid) < 0 else (lo, mid)
    return 0.5 * (lo + hi)


def test_a_quadratic_log_likelihood_keeps_the_gauss_newton_interval():
    """Residuals linear in z: the profile's root deviance at the Gauss-Newton ends is exactly
    1.645 and nothing is searched or replaced."""
    rng = np.random.default_rng(0)
    y = 0.3 + 1.2 * X + 0.1 * rng.standard_normal(len(X))

    def res(z, data):
        return (data - z[0] - z[1] * X) / 0.1

    z, cost, cov = _fit(res, jnp.asarray(y), [0.0, 0.0])
    solve = jax.jit(held_lm_solver(res, 1e-10, 1e-10, 50))
    chk = profile_check(solve, jnp.asarray(y), z, cost, cov, None, [0, 1])
    np.testing.assert_allclose(chk.root_deviance_gn, Z90, rtol=1e-4)
    assert not chk.disagrees.any()
    sd = np.sqrt(np.diag(cov))
    np.testing.assert_allclose(chk.interval_z, np.stack([z - Z90 * sd, z + Z90 * sd], axis=1), rtol=1e-9)
    assert abs(chk.loglik_gain) < 1e-6 and chk.solves == 4


def test_a_skewed_profile_is_widened_where_flatter_and_matches_brute_force():
    """y = exp(z0) x + z1 with a weak slope: the log-likelihood in z0 is far from quadratic,
    flatter towards small slopes (z0 -> -inf), steeper towards large ones. The check searches
    the flatter side and finds the profile's end within 3% of the interval's width of the
    brute-force one (z1 profiled out in closed form); the steeper side keeps its Gauss-Newton
    end (wider than the profile's: the check never narrows), and the linear coordinate z1 is
    left alone. Through the FD Jacobian the fit uses (step 0.05 in z), with and without an
    inflation (the deviance is then scaled by it). With a weaker slope the flatter side is not
    bounded by the data: its end is carried far out, towards the prior's bound."""
    sigma = 0.25
    for slope, tolerance, bounded in ((0.35, 1.2, True), (0.2, PROFILE_TOLERANCE, False)):
        y = slope * X + 0.2 + sigma * np.random.default_rng(3).standard_normal(len(X))

        def res_exact(z, data):
            return (data - jnp.exp(z[0]) * X - z[1]) / sigma

        z, cost, cov = _fit(res_exact, jnp.asarray(y), [np.log(0.3), 0.0])
        solve = jax.jit(held_lm_solver(fd_jacobian_fn(res_exact, 0.05), 1e-10, 1e-10, 50))
        for c in (1.0, 1.3):
            chk = profile_check(solve, jnp.asarray(y), z, cost, cov, np.array([c, 1.0]), [0, 1], tolerance=tolerance)
            assert chk.disagrees.tolist() == [[True, False], [False, False]]
            assert chk.root_deviance_gn[0, 0] < Z90 / tolerance and chk.root_deviance_gn[0, 1] > Z90 * tolerance

            def cost_at(v):  # z1 profiled out (the intercept of y - exp(v) x), the deviance scaled by 1 / c^2
                r = y - np.exp(v) * X
                return cost + (0.5 * np.sum(((r - r.mean()) / sigma) ** 2) - cost) / c ** 2

            sd = np.sqrt(cov[0, 0]) * c
            lower, upper = _brute_profile_end(cost_at, z[0], cost, -1), _brute_profile_end(cost_at, z[0], cost, 1)
            assert chk.interval_z[0, 1] == pytest.approx(z[0] + Z90 * sd) and Z90 * sd > upper
            if bounded:
                assert chk.bounded[0, 0] and abs((z[0] - chk.interval_z[0, 0]) - lower) < 0.03 * 2 * Z90 * sd
            else:
                # not bounded by the data: the end is carried far out (to the search's limit, or
                # extrapolated near it)
                assert not np.isfinite(lower) and z[0] - chk.interval_z[0, 0] > 4 * Z90 * sd
            assert chk.loglik_gain < 1e-6
        # padded (the C engine's way): every batch of held fits the first one's size, one
        # compiled program where the plain check compiled one per batch size; the same check
        padded = jax.jit(held_lm_solver(fd_jacobian_fn(res_exact, 0.05), 1e-10, 1e-10, 50))
        chk_p = profile_check(padded, jnp.asarray(y), z, cost, cov, np.array([1.3, 1.0]), [0, 1],
                              tolerance=tolerance, pad_batches=True)
        assert padded._cache_size() == 1 < solve._cache_size()
        np.testing.assert_array_equal(chk_p.interval_z, chk.interval_z)
        assert chk_p.solves == chk.solves


def test_a_rough_profile_ends_beyond_its_farthest_point_inside():
    """A held fit that stops short overstates the deviance: on a profile whose root deviance is
    0.5 x distance / SD (the end at 3.29 SD) but 3 in a spike at 3.19-3.39 SD, where the first
    secant step lands, the end is searched on from the farthest point found inside, to the
    spike's edge, not read between the GN end and the spike (2.27 SD)."""
    sd = 0.2

    def root(dist):
        return 3.0 if abs(dist / sd - 2 * Z90) < 0.1 else 0.5 * dist / sd

    def solve(z0, j, v, data):
        z = np.array(z0)
        z[np.arange(len(z)), np.asarray(j)] = np.asarray(v)
        return jnp.asarray(z), jnp.asarray([0.5 * root(abs(float(x))) ** 2 for x in np.asarray(v)])

    chk = profile_check(solve, None, np.zeros(2), 0.0, np.diag([sd ** 2, 1.0]), None, [0], rounds=6)
    np.testing.assert_allclose(chk.root_deviance_gn, [[0.5 * Z90, 0.5 * Z90]])
    ends = np.abs(chk.interval_z[0]) / sd
    assert np.all((ends > 3.0) & (ends < 3.2)), ends
    assert chk.bounded.all() and all(len(pts) > 3 for pts in chk.searched.values())


def test_a_profile_that_dips_after_rising_is_still_bounded():
    """Held fits on a rough likelihood: the root deviance rises to 1.4 and falls back to 1.24 a
    step farther (a ripple), with no point outside yet when the rounds run out. The end is
    extrapolated along the mean rise from the optimum (about 1.33 x the farthest point inside),
    not taken as unbounded (the prior's bound: a friction interval from 0 to the estimate)."""
    sd = 0.2
    pts = {1.0: 1.073 / Z90, 1.5: 1.416 / Z90, 2.0: 1.237 / Z90}  # root deviance / 1.645 at distance / (1.645 SD)

    def root(dist):
        x = dist / (Z90 * sd)
        for k in sorted(pts):
            if x <= k * 1.001:
                return Z90 * pts[k]
        return 1.237  # flat beyond: no point outside within the rounds

    def solve(z0, j, v, data):
        z = np.array(z0)
        z[np.arange(len(z)), np.asarray(j)] = np.asarray(v)
        return jnp.asarray(z), jnp.asarray([0.5 * root(abs(float(x))) ** 2 for x in np.asarray(v)])

    chk = profile_check(solve, None, np.zeros(2), 0.0, np.diag([sd ** 2, 1.0]), None, [0], rounds=2)
    assert chk.disagrees[0].all()
    assert chk.bounded[0].all(), chk.searched
    ends = np.abs(chk.interval_z[0])
    assert np.all(ends < 4.0 * Z90 * sd), ends  # not the search's limit (8 in z)
    far_inside = [max(d for d, r in pts_ if r <= Z90) for pts_ in ({abs(z): r for z, r in v}.items()
                                                                  for v in chk.searched.values())]
    assert np.all(ends >= np.array(far_inside) - 1e-9), (ends, far_inside)


def test_profile_check_refuses_a_coordinate_without_variance():
    solve = jax.jit(held_lm_solver(lambda z, d: z - d, 1e-8, 1e-8, 10))
    with pytest.raises(ValueError, match="finite positive"):
        profile_check(solve, jnp.zeros(2), np.zeros(2), 0.0, np.diag([1.0, np.inf]), None, [1])
