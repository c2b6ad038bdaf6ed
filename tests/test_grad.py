"""Levenberg-Marquardt fit on a short simulated two-object video, and the FD Jacobian.

One module-scoped problem (1.5 s at 30 fps, known truth, 1 mm position noise) is shared,
so the MJX rollout compiles a few times only. The recovery test fits the same video on the C
engine, the one ``fit`` picks on a CPU: cold, the MJX problem's screen, LM, Jacobian and polish
programs took ~200 s to compile there, against ~20 s on the C engine (the MJX LM stays tested
with held parameters, in chunks and from a CMA-ES start).
"""

from types import SimpleNamespace
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from galileo_jax.inference.grad import count_rollouts, fit_grad
from galileo_jax.inference.problem import Problem, cached_jit, fd_jacobian_fn, simulated_observation
from galileo_jax.inference.summary import summarize_grad
from galileo_jax.params import ParamSpace
from galileo_jax.physics.simulate import PhysParams
from galileo_jax.scene import scene_from_dict

SCENE2 = scene_from_dict({
    "name": "ramp_20", "ramp": {"angle_deg": 20, "length": 0.6},
    "objects": [{"shape": "box", "size": [0.08, 0.06, 0.04], "start": 0.45},
                {"shape": "box", "size": [0.08, 0.06, 0.04], "start": 0.15}],
    "camera": {"pixels_per_metre": 1692.9},
    "simulation": {"fit_release": False}})  # the release-time nuisance is covered by test_recovery
TRUTH = {"k1": 0.2, "k2": 0.25, "phi": (0.6 - 0.3) / 0.9}


@pytest.fixture(scope="module")
def problem():
    truth = PhysParams(jnp.array([0.6, 0.3]), jnp.array([TRUTH["k1"], TRUTH["k2"]]))
    obs = simulated_observation(SCENE2, truth, duration=1.5, position_sd=1e-3, seed=0)
    return Problem(SCENE2, obs)


def test_fd_jvp_rule_is_the_central_difference():
    """custom_jvp with central differences: exact for a quadratic, linear in the tangent."""
    f = lambda z, c: jnp.stack([z[0] ** 2 + 3 * z[1], z[0] * z[1] * c])  # noqa: E731
    g = fd_jacobian_fn(f, 0.1)
    z, c = jnp.array([0.7, -1.3]), jnp.asarray(2.0)
    assert np.allclose(jax.jacfwd(g)(z, c), jax.jacfwd(f)(z, c), atol=1e-5)
    _, lin = jax.linearize(lambda zz: g(zz, c), z)  # linear in the tangent: transposable (optimistix needs this)
    t = jnp.array([0.3, 2.0])
    (ct,) = jax.linear_transpose(lin, t)(jnp.array([1.0, -1.0]))
    assert np.allclose(ct, jax.jacfwd(f)(z, c).T @ jnp.array([1.0, -1.0]), atol=1e-5)


def test_fd_jacobian_matches_central_differences_of_rollout(problem):
    space = problem.space
    h = 0.05
    z = space.to_unconstrained(jnp.array([0.21, 0.3, 0.25]))
    jac = np.asarray(jax.jit(jax.jacfwd(problem.residual_fn("fd", h)))(z, problem.data))  # (n_res, d)
    d = space.dim
    pts = jnp.concatenate([z + h * jnp.eye(d), z - h * jnp.eye(d)])
    r = np.asarray(problem.residuals(space.from_unconstrained(pts)))  # (2d, n_res)
    manual = ((r[:d] - r[d:]) / (2 * h)).T
    assert jac.shape == (problem.likelihood.n_residuals, d)
    assert np.allclose(jac, manual, rtol=1e-3, atol=1e-2 * np.abs(manual).max())


@pytest.fixture(scope="module")
def problem_c(problem):
    """The same video on the C engine (module docstring)."""
    return Problem(SCENE2, problem.observation, engine="mujoco")


@pytest.mark.slow
def test_grad_recovers_truth(problem_c):
    res = fit_grad(problem_c, jax.random.key(0), n_starts=3, n_screen=32, max_steps=30)
    est = dict(zip(res.names, res.theta))
    assert abs(est["k1"] - TRUTH["k1"]) < 0.02
    assert abs(est["k2"] - TRUTH["k2"]) < 0.03
    assert abs(est["phi"] - TRUTH["phi"]) < 0.1
    assert np.all(np.isfinite(res.sd)) and np.all(res.sd > 0)
    assert np.all((res.interval90[:, 0] <= res.theta) & (res.theta <= res.interval90[:, 1]))
    assert res.iterations > 0 and res.cost <= res.starts_cost.min() + 1e-9  # polish may only lower it
    summ = summarize_grad(res, problem_c.space)
    p = summ["parameters"]
    assert set(p) == {"k1", "k2", "phi", "m1", "m2"}
    assert p["k1"]["mean"] == pytest.approx(est["k1"]) and p["k1"]["rhat"] is None
    assert not p["m1"]["identifiable"] and p["m1"]["mean"] is None
    assert summ["diagnostics"]["jacobian"] == "fd"
    # simulated data with white noise and the model's own floor: no interval widened much
    assert res.inflation is not None and np.all(res.inflation >= 1.0) and np.all(res.inflation < 1.5)
    assert set(summ["diagnostics"]["interval_widening"]) == set(problem_c.names)


def _counted_rollouts(monkeypatch) -> list[int]:
    """A list that receives the batch size of every rollout call of the C engine's host callback
    from now on (its cache of recent rollouts off)."""
    from galileo_jax.physics import simulate_c

    monkeypatch.setattr(simulate_c, "CACHE_ROLLOUTS", 0)
    ran = []
    real = simulate_c.rollout_poses_host

    def counting(sim, mass, *args, **kw):
        ran.append(int(np.shape(mass)[0]))
        return real(sim, mass, *args, **kw)

    monkeypatch.setattr(simulate_c, "rollout_poses_host", counting)
    return ran


def test_rollout_counter_counts_what_the_engine_ran(problem_c, monkeypatch):
    """``count_rollouts`` (the benchmarks' one counter) equals the rollouts the C engine's host
    callback was asked for during ``fit_grad`` (its cache of recent rollouts off), polish included."""
    ran = _counted_rollouts(monkeypatch)
    res = fit_grad(problem_c, jax.random.key(1), n_starts=2, n_screen=16, max_steps=6)
    assert sum(ran) == count_rollouts(res, n_screen=16) > 16


def test_search_after_lm_only_lowers_the_cost_and_is_counted(problem_c, monkeypatch):
    """``search_generations``: CMA-ES from the LM end, then LM from its best, kept only where it
    ends lower; its rollouts are counted by ``count_rollouts`` (within the polish's one
    uncertain Jacobian, see its docstring) and reported in the summary."""
    from galileo_jax.inference.grad import SEARCH_POPSIZE

    kw = dict(n_starts=1, n_screen=8, max_steps=3)  # a short LM: room for the search
    plain = fit_grad(problem_c, jax.random.key(3), **kw)
    ran = _counted_rollouts(monkeypatch)
    res = fit_grad(problem_c, jax.random.key(3), **kw, search_generations=4)
    assert plain.search is None
    assert res.search["generations"] == 4 and res.search["evaluations"] == 4 * SEARCH_POPSIZE + 1
    assert res.cost <= plain.cost + 1e-9
    assert res.search["kept"] == (res.cost < plain.cost - 1e-9)
    d = len(res.z)
    assert abs(sum(ran) - count_rollouts(res, n_screen=8)) <= 2 * d + 1
    assert summarize_grad(res, problem_c.space)["diagnostics"]["search"] == res.search


def test_a_nuisance_stopped_at_its_window_end_is_fitted_again_from_inside(problem):
    """A fit whose scale_error ended at an end of its window (here: held at -3% on a video whose
    distances are 2% too large) is fitted again from inside the window (from_inside): the refit
    is kept only because it lowers the cost, leaves the scale off the window's ends, and is
    recorded; a fit with every nuisance inside is returned as it is."""
    from galileo_jax.inference.grad import INSIDE_STARTS, from_inside
    from galileo_jax.params import nuisances_at_edge

    obs = problem.observation
    prob = Problem(SCENE2.with_scale_tolerance(0.03), obs._replace(positions=obs.positions * 1.02,
                                                                   profile=obs.profile * 1.02), engine="mujoco")
    kw = dict(n_starts=1, n_screen=8, max_steps=15, init=np.array([0.2, 0.25, 1 / 3, 0.0]))
    stuck = fit_grad(prob, jax.random.key(1), fixed={"scale_error": -0.03}, **kw)
    assert list(nuisances_at_edge(prob.space, stuck.theta).values()) == ["lower"]
    res = from_inside(stuck, prob, max_steps=15)
    assert res.inside["nuisances"] == ["scale_error"] and res.inside["starts"] == len(INSIDE_STARTS)
    assert res.inside["kept"] and res.cost < stuck.cost - 1.0 and res.inside["cost_drop"] > 1.0
    assert not nuisances_at_edge(prob.space, res.theta)
    assert summarize_grad(res, prob.space)["diagnostics"]["inside"] == res.inside
    again = from_inside(res, prob, max_steps=15)
    assert again is res


def test_grad_rejects_bad_arguments(problem):
    with pytest.raises(ValueError, match="init"):
        fit_grad(problem, jax.random.key(0), init=np.array([0.2, 0.3]))
    with pytest.raises(ValueError, match="jacobian"):
        fit_grad(problem, jax.random.key(0), jacobian="bwd")
    with pytest.raises(ValueError, match="n_screen"):
        fit_grad(problem, jax.random.key(0), n_starts=8, n_screen=4)


def test_problems_of_one_scene_share_compiled_functions_but_not_data(problem):
    """A second video of the same scene reuses the first one's jitted functions (the
    observation is an argument), and gets ITS OWN likelihood, not the first video's."""
    truth = PhysParams(jnp.array([0.4, 0.5]), jnp.array([0.15, 0.3]))
    other_obs = simulated_observation(SCENE2, truth, duration=1.4, position_sd=2e-3, seed=3, release_time=0.2)
    other = Problem(SCENE2, other_obs)
    assert other.engine is problem.engine and other.static_key == problem.static_key
    theta = jnp.array([[0.15, 0.3, -0.1111], [0.2, 0.25, 1 / 3]])
    z = problem.space.to_unconstrained(theta)
    ll_first = np.asarray(problem.log_likelihood(z))
    fn = problem.jitted("log_likelihood", None)  # the cached function (fn argument unused once cached)
    n_traces = fn._cache_size()
    ll_other = np.asarray(other.log_likelihood(z))
    assert fn._cache_size() == n_traces  # no new trace for the second video
    # reference: the other video's likelihood evaluated directly on its simulated profiles
    sims = np.asarray(other.profiles_physical(other.space.physical(theta)))
    pad = other.likelihood.obs.shape[1] - sims.shape[-1]
    ref = [float(other.likelihood(jnp.pad(jnp.asarray(s), ((0, 0), (0, pad))))) for s in sims]
    assert np.allclose(ll_other, ref, rtol=1e-5, atol=1e-2)  # z -> theta round trip: ~1e-16 in theta
    assert not np.allclose(ll_other, ll_first)
    assert ll_other[0] > ll_other[1]  # its own truth is the better point


def test_grad_runs_more_starts_than_a_chunk_in_chunks(problem, monkeypatch):
    """More LM starts than ``MAX_LM_STARTS`` run as several calls of ONE compiled solver (the
    last chunk padded to the same shape) and give exactly the unchunked answer. (64 vmapped
    MJX starts deadlocked; the C engine keeps this test cheap, the chunking is the same.)"""
    import galileo_jax.inference.grad as grad

    c_problem = Problem(SCENE2, problem.observation, engine="mujoco")
    kw = dict(n_starts=5, n_screen=16, max_steps=4, polish_rounds=0)
    whole = fit_grad(c_problem, jax.random.key(2), **kw)  # 5 <= MAX_LM_STARTS: one call
    solver = c_problem.jitted(("lm", "fd", grad.DEFAULT_FD_STEP, 1e-4, 1e-4, 4), None)  # the cached solver
    shapes = solver._cache_size()
    monkeypatch.setattr(grad, "MAX_LM_STARTS", 2)
    chunked = fit_grad(c_problem, jax.random.key(2), **kw)  # chunks of 2, 2, 1 (+1 copy)
    assert solver._cache_size() == shapes + 1  # one new shape, (2, d), for all three chunks
    assert chunked.starts_theta.shape == (5, 3)
    np.testing.assert_array_equal(chunked.starts_theta0, whole.starts_theta0)
    np.testing.assert_allclose(chunked.starts_theta, whole.starts_theta, rtol=0, atol=1e-12)
    np.testing.assert_allclose(chunked.starts_cost, whole.starts_cost, rtol=1e-12)
    np.testing.assert_array_equal(chunked.starts_iterations, whole.starts_iterations)
    np.testing.assert_array_equal(chunked.starts_converged, whole.starts_converged)
    np.testing.assert_allclose(chunked.theta, whole.theta, rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="chunk"):
        grad.solve_starts(solver, jnp.zeros((3, 3)), c_problem.data, chunk=0)


def test_c_engine_batches_of_every_size_run_one_compiled_program(problem):
    """The C engine's programs hold a host callback, so JAX compiles them in every process: its
    problems pad each batch to ``max_batch`` rows (copies of the last; the rollout cache
    simulates them once), so that batches of every size run one program, with the values the
    rows have alone. MJX problems pad less (the next test)."""
    c_problem = Problem(SCENE2, problem.observation, engine="mujoco")
    assert c_problem.pads_batches and not problem.pads_batches
    mb = c_problem.max_batch
    z = np.random.default_rng(0).normal(0.0, 0.5, (mb + 3, c_problem.dim))
    whole = np.asarray(c_problem.log_likelihood(z))
    program = c_problem.jitted("log_likelihood", None)  # the cached jitted function
    for b in (1, 3, mb):
        np.testing.assert_array_equal(np.asarray(c_problem.log_likelihood(z[:b])), whole[:b])
    np.testing.assert_array_equal(np.asarray(c_problem.log_likelihood(z[-1:])), whole[-1:])
    assert whole.shape == (mb + 3,) and np.isfinite(whole).all() and program._cache_size() == 1
    assert np.asarray(c_problem.log_likelihood(z[:0])).shape == (0,)
    theta = np.asarray(c_problem.space.from_unconstrained(jnp.asarray(z[:2])))
    sims = np.asarray(c_problem.simulate(theta))
    np.testing.assert_array_equal(np.asarray(c_problem.simulate(theta[1])), sims[1])
    assert np.isfinite(sims).all()


def test_mjx_batches_run_as_powers_of_two_with_the_values_rows_have_alone(problem):
    """MJX problems pad a batch to the next power of two (at most ``max_batch``) and run bigger
    ones in chunks of ``max_batch``: a few compiled programs (6-10 s each on a CPU) serve every
    batch size, and each row's value is the one it has in any other batch."""
    mb = problem.max_batch
    assert not problem.pads_batches
    assert [problem.batch_size(n) for n in (1, 2, 3, 4, 5, mb - 1, mb)] == \
        [1, 2, 4, 4, 8, min(mb, 1 << (mb - 2).bit_length()), mb]
    z = np.random.default_rng(1).normal(0.0, 0.5, (mb, problem.dim))  # max_batch: the size the screens compile
    whole = np.asarray(problem.log_likelihood(z))
    program = problem.jitted("log_likelihood", None)  # the cached jitted function
    before = program._cache_size()
    n = problem.batch_size(mb // 2) + 1  # pads up to max_batch
    part = np.asarray(problem.log_likelihood(z[:n]))
    assert program._cache_size() == before  # no program of its own
    np.testing.assert_allclose(part, whole[:n], rtol=1e-12)
    assert part.shape == (n,) and np.isfinite(whole).all()


@pytest.mark.slow
def test_grad_with_held_parameters(problem):
    """fit_grad(fixed=...) fits only the free coordinates and reports the held one exactly."""
    res = fit_grad(problem, jax.random.key(1), n_starts=2, n_screen=16, max_steps=30, fixed={"phi": TRUTH["phi"]},
                   polish_rounds=0)
    est = dict(zip(res.names, res.theta))
    assert res.names == problem.names and res.fixed == ("phi",)
    assert est["phi"] == pytest.approx(TRUTH["phi"])
    j = problem.names.index("phi")
    assert res.sd[j] == 0.0 and res.interval90[j, 0] == res.interval90[j, 1]
    assert abs(est["k1"] - TRUTH["k1"]) < 0.02 and abs(est["k2"] - TRUTH["k2"]) < 0.03
    assert np.all(res.sd[[0, 1]] > 0)
    with pytest.raises(ValueError, match="bounds"):
        fit_grad(problem, jax.random.key(1), fixed={"k1": 5.0})  # outside [0, 1]
    with pytest.raises(ValueError, match="cannot hold"):
        fit_grad(problem, jax.random.key(1), fixed={"drag": 0.1})


def test_local_screen_draws_near_the_start_except_effect_parameters():
    """``latin_hypercube_starts(around=...)``: base coordinates within +-spread of their range
    around the start (clipped to the bounds), effect parameters over their whole range, one
    point per stratum of every coordinate (a Latin hypercube)."""
    from galileo_jax.inference.starts import latin_hypercube_starts
    from galileo_jax.params import ParamSpace

    scene = scene_from_dict({"ramp": {"angle_deg": 20, "length": 2.0},
                             "objects": [{"shape": "box", "size": [0.08, 0.06, 0.04], "start": 0.5},
                                         {"shape": "box", "size": [0.08, 0.06, 0.04], "start": 0.15}],
                             "camera": {"pixels_per_metre": 500}})
    from galileo_jax.effects import get_effect

    space = ParamSpace.from_scene(scene, (get_effect("ramp_friction"),))
    assert space.names == ("k1", "k2", "phi", "dt_release", "dk_ramp")

    class P:
        dim = space.dim

    P.space = space
    around = np.array([0.9, 0.3, 0.0, 0.0, 0.0])
    x = np.asarray(latin_hypercube_starts(P, jax.random.key(0), 200, around=around, spread=0.25))
    lo, hi = np.asarray(space.lower), np.asarray(space.upper)
    assert np.all(x >= lo) and np.all(x <= hi)
    span = hi - lo
    assert np.all(np.abs(x[:, :3] - around[:3]) <= 0.25 * span[:3] + 1e-12)
    assert x[:, 0].min() > 0.9 - 0.25 * span[0] - 1e-12 and x[:, 0].max() <= hi[0]
    assert x[:, 4].min() < lo[4] + 0.1 * span[4] and x[:, 4].max() > hi[4] - 0.1 * span[4]  # the effect: whole range
    strata = np.floor(((x[:, 4] - lo[4]) / span[4] - 0.05) / 0.9 * 200)  # the default 5% margin
    assert len(np.unique(strata)) == 200


def test_gauss_newton_covariance_gives_a_blown_up_coordinate_no_made_up_interval():
    from galileo_jax.inference.covariance import gauss_newton_covariance

    rng = np.random.default_rng(0)
    jac = rng.normal(size=(50, 3))
    full = gauss_newton_covariance(jac)
    jac_bad = jac.copy()
    jac_bad[7, 2] = np.nan  # the rollout at coordinate 2's difference step blew up
    cov = gauss_newton_covariance(jac_bad)
    assert np.isinf(cov[2, 2]) and np.all(cov[2, :2] == 0) and np.all(cov[:2, 2] == 0)
    np.testing.assert_allclose(cov[:2, :2], gauss_newton_covariance(jac[:, :2]))
    assert np.all(np.isfinite(full))  # all finite: the usual (J^T J)^-1
    np.testing.assert_allclose(full, np.linalg.inv(jac.T @ jac), rtol=1e-6)


def _ar1(rng, shape, rho):
    """(T, M) AR(1) series with unit marginal variance and lag-1 correlation ``rho``."""
    e = rng.normal(size=shape)
    out = np.empty(shape)
    out[:, 0] = e[:, 0]
    for k in range(1, shape[1]):
        out[:, k] = rho * out[:, k - 1] + np.sqrt(1 - rho ** 2) * e[:, k]
    return out


def test_sandwich_widens_intervals_by_the_residuals_autocorrelation_only():
    """The mean of T series of M samples (a constant fitted by least squares, J = 1): with
    independent unit residuals the Gauss-Newton SD is right (no widening); with AR(1)
    residuals of lag-1 correlation rho the mean's true variance is (1 + rho) / (1 - rho) times
    the Gauss-Newton one (x19 at rho 0.9: SD x4.4), which the sandwich recovers, in part (a
    finite bandwidth); residuals smaller than the claimed noise never narrow an interval."""
    from galileo_jax.inference.covariance import gauss_newton_covariance, robust_covariance

    T, M = 4, 200
    rng = np.random.default_rng(3)
    jac = np.ones((T * M, 1))
    gn = gauss_newton_covariance(jac)
    white = [robust_covariance(jac, rng.normal(size=T * M), [(T, M)], gn)[1][0] for _ in range(20)]
    assert 1.0 <= np.median(white) < 1.15
    corr = [robust_covariance(jac, _ar1(rng, (T, M), 0.9).ravel(), [(T, M)], gn)[1][0] for _ in range(20)]
    assert 2.5 < np.median(corr) < 5.0, np.median(corr)
    small = robust_covariance(jac, 0.3 * _ar1(rng, (T, M), 0.5).ravel(), [(T, M)], gn)
    assert small[1][0] == 1.0 and np.array_equal(small[0], gn)
    # two blocks (a joint fit's videos) of other lengths, a coordinate the residuals do not
    # depend on and a blown-up one
    jac3 = np.ones((T * M + 2 * 50, 3))
    jac3[:, 1] = 0.0
    jac3[5, 2] = np.nan
    cov3 = gauss_newton_covariance(jac3)
    r = np.concatenate([_ar1(rng, (T, M), 0.9).ravel(), _ar1(rng, (2, 50), 0.9).ravel()])
    cov, infl = robust_covariance(jac3, r, [(T, M), (2, 50)], cov3)
    assert infl[0] > 2.0 and infl[1] == infl[2] == 1.0
    assert cov[1, 1] == cov3[1, 1] and np.isinf(cov[2, 2])
    assert cov[0, 0] == pytest.approx(cov3[0, 0] * infl[0] ** 2)
    with pytest.raises(ValueError, match="do not make up"):
        robust_covariance(jac, np.zeros(T * M), [(T, M + 1)], gn)


@pytest.mark.slow
def test_cma_search_climbs_from_a_far_start_and_keeps_held_parameters(problem):
    """CMA-ES (pycma, batched likelihood calls) from a start far from the truth ends near it, with
    a log-likelihood no lower than the start's; a held parameter stays exactly at its value."""
    from galileo_jax.inference.search import cma_search

    start = np.array([0.45, 0.05, TRUTH["phi"]])
    seen = []
    found = cma_search(problem, start, popsize=16, generations=30, fixed={"phi": TRUTH["phi"]},
                       progress=lambda g, ll: seen.append((g, ll)))
    est = dict(zip(problem.names, found.theta))
    assert est["phi"] == pytest.approx(TRUTH["phi"], abs=1e-12)
    assert abs(est["k1"] - TRUTH["k1"]) < 0.02 and abs(est["k2"] - TRUTH["k2"]) < 0.03
    assert found.loglik > found.loglik_start
    z = problem.space.to_unconstrained(jnp.asarray(found.theta)[None])
    assert float(problem.log_likelihood(z)[0]) == pytest.approx(found.loglik, abs=1e-2)  # batch-size numerics
    assert found.evaluations == 1 + 16 * found.generations and found.generations == len(seen) <= 30
    assert all(b[1] >= a[1] for a, b in zip(seen, seen[1:]))  # the best so far never falls
    # patience: generations without progress (here none can count: min_gain too large) end it
    idle = cma_search(problem, start, popsize=16, generations=30, patience=3, min_gain=1e9)
    assert idle.stop == {"patience": 3} and idle.generations == 3 and idle.evaluations == 1 + 16 * 3
    with pytest.raises(ValueError, match="bounds"):
        cma_search(problem, np.array([1.5, 0.2, 0.0]))
    with pytest.raises(ValueError, match="popsize"):
        cma_search(problem, start, popsize=2)


def test_diverse_best_keeps_a_start_in_each_region_best_first():
    """``diverse_best``: the best screened point first, then the next best that lies at least
    the separation away from every chosen one (release-time coordinates not compared); a
    cluster of good points in one region gives one start, not all of them; too few distinct
    regions are filled up with the best of the rest."""
    from galileo_jax.inference.starts import diverse_best, unit_box

    lo, hi = np.array([0.0, 0.0, -1.0, -0.1]), np.array([1.0, 1.0, 1.0, 0.1])
    kinds = ("friction", "friction", "phi", "release")
    cand = np.array([[0.2, 0.70, 0.70, 0.0],    # 0: best, in the high-k2 region
                     [0.2, 0.75, 0.72, 0.1],    # 1: second best, same region (release differs only)
                     [0.2, 0.80, 0.75, -0.1],   # 2: same region
                     [0.2, 0.10, 0.30, 0.0],    # 3: another region
                     [0.2, 0.12, 0.32, 0.0],    # 4: next to 3
                     [0.9, 0.50, -0.80, 0.0]])  # 5: a third region, worst
    ll = np.array([-10.0, -11.0, -12.0, -13.0, -14.0, -30.0])
    u = unit_box(cand, lo, hi, kinds)
    assert u.shape == (6, 3)
    assert np.asarray(diverse_best(u, ll, 3)).tolist() == [0, 3, 5]
    assert np.asarray(diverse_best(u, ll, 4)).tolist() == [0, 3, 5, 1]  # filled up with the best left
    assert np.asarray(diverse_best(u, ll, 2, separation=0.0)).tolist() == [0, 1]  # plain ranking
    ll_fail = ll.copy()
    ll_fail[3] = -np.inf  # a failed rollout is chosen only when nothing else is left
    assert np.asarray(diverse_best(u, ll_fail, 3)).tolist() == [0, 4, 5]
    ll_one = np.array([-10.0, -11.0, -12.0, -np.inf, -np.inf, -np.inf])
    assert np.asarray(diverse_best(u, ll_one, 3)).tolist() == [0, 1, 2]  # no start where rollouts fail
    batched = jax.vmap(diverse_best, in_axes=(None, 0, None))(u, np.stack([ll, ll_fail]), 3)  # as solve_batch
    assert np.asarray(batched).tolist() == [[0, 3, 5], [0, 4, 5]]


def test_competing_optima_name_other_end_points_that_fit_about_as_well():
    """A multi-start fit whose starts end at other optima: an end point within 2 nats of the
    best and outside its 90% interval is reported (once, however many starts reach it), with
    the parameters it disagrees on; one 10 nats worse, or one inside the intervals, is not. The
    console's warning names it."""
    from types import SimpleNamespace

    from galileo_jax.inference.summary import competing_optima, optima_warning

    best = np.array([0.401, 0.087])  # k1, scale_error: a ridge along which they trade
    ends = np.array([best, [0.376, -0.086], [0.3761, -0.0859], [0.402, 0.086], [0.300, 0.0]])
    cost = np.array([23.0, 24.1, 24.15, 23.01, 33.0])  # nats; the second optimum 1.1 lower in log-likelihood
    result = SimpleNamespace(names=("k1", "scale_error"), starts_theta=ends, starts_cost=cost, cost=23.0)
    parameters = {"k1": {"interval90": [0.398, 0.404], "sd": 0.0018, "identifiable": True},
                  "scale_error": {"interval90": [0.060, 0.108], "sd": 0.015, "identifiable": True},
                  "m1": {"interval90": None, "sd": None, "identifiable": False}}
    optima = competing_optima(result, None, parameters)
    assert len(optima) == 1, optima
    assert optima[0]["theta"]["k1"] == pytest.approx(0.376)
    assert optima[0]["delta_loglik"] == pytest.approx(1.1)
    assert optima[0]["outside_interval90"] == ["k1", "scale_error"]
    warning = optima_warning({"competing_optima": optima})
    assert "k1 0.376" in warning and "local to the best optimum" in warning
    assert competing_optima(result, None, parameters, max_delta=1.0) == []
    assert optima_warning({"competing_optima": []}) is None


class _Curve(NamedTuple):
    """A least-squares problem with the interface :func:`with_profile` uses, and no simulator:
    a curve y(t) = z0 + z1 t + z2 t^2 + 0.3 sin(z0 + z1) through 40 samples with noise SD 0.05
    (mildly non-linear, so the profile and the Gauss-Newton intervals differ a little), in
    SCENE2's parameter space (k1, k2, phi)."""

    space: ParamSpace
    data: jax.Array
    likelihood: SimpleNamespace
    static_key: tuple = ("test_curve",)
    pads_batches: bool = False  # no host callback: its programs are cached like MJX's

    @staticmethod
    def residuals(z, y):
        t = jnp.linspace(-1.0, 1.0, y.shape[0])
        return (z[0] + z[1] * t + z[2] * t**2 + 0.3 * jnp.sin(z[0] + z[1]) - y) / 0.05

    def residual_fn(self, jacobian="fd", fd_step=0.05):
        return fd_jacobian_fn(self.residuals, fd_step)

    def jitted(self, name, fn):
        return cached_jit(self.static_key, name, fn)


def test_profile_check_fits_again_where_the_fit_stopped_short():
    """A result whose estimate sits 3 SD off the maximum in k2 (as if LM had stopped short):
    the profile check's held fit at the interval's end nearer the maximum rises above it by
    more than PROFILE_REFIT_GAIN, so with_profile fits again from there. The refit ends back
    at the maximum (k2 within 0.1 SD), its cost far below the stuck one's and within 1e-3 nats
    of the first fit's, the refit's start is kept among the starts, and the report lists the
    gain that led to it. (On a simulated problem the same logic runs in ``fit --method grad``:
    test_cli; here a curve fit keeps the test to seconds.)"""
    from galileo_jax.inference.grad import DEFAULT_FD_STEP, PROFILE_REFIT_GAIN, grad_result, refit_from, with_profile

    space = ParamSpace.from_scene(SCENE2)
    z_true = np.array([-0.4, 0.6, 0.2])
    y = _Curve.residuals(jnp.asarray(z_true), jnp.zeros(40)) * 0.05  # the curve at z_true
    y = y + 0.05 * jnp.asarray(np.random.default_rng(0).normal(size=40))
    problem = _Curve(space, y, SimpleNamespace(log_norm=0.0))
    res_fn = problem.residual_fn("fd", DEFAULT_FD_STEP)

    def result_at(z):  # a one-start result at z (no covariance yet)
        r = np.asarray(res_fn(jnp.asarray(z), problem.data))
        theta = np.asarray(space.from_unconstrained(jnp.asarray(z)))
        return grad_result(space, 0.0, z, np.eye(3), 0.5 * float(r @ r), theta[None], np.asarray(z)[None],
                           np.array([0.5 * float(r @ r)]), np.zeros(1, int), np.ones(1, bool), np.zeros(1, int), 0,
                           "fd", 0.0)

    res = refit_from(result_at(np.zeros(3)), problem, np.zeros(3))  # the maximum, with its covariance
    assert res is not None and res.inflation is None
    j = problem.space.names.index("k2")
    sd = np.sqrt(np.diag(res.cov_z))
    z_off = np.array(res.z)
    z_off[j] += 3 * sd[j]
    r = np.asarray(res_fn(jnp.asarray(z_off), problem.data))
    stuck = res._replace(z=z_off, cost=0.5 * float(r @ r))
    assert stuck.cost > res.cost + 2.0
    out = with_profile(stuck, problem)
    assert out.profile["refitted_from_gain"][0] > PROFILE_REFIT_GAIN
    assert out.cost < stuck.cost - 2.0 and out.cost <= res.cost + 1e-3
    assert abs(out.z[j] - res.z[j]) < 0.1 * sd[j], (out.z - res.z) / sd
    assert len(out.starts_cost) == len(res.starts_cost) + 1 and out.starts_cost[-1] == pytest.approx(out.cost)
    # the fit at the maximum has nothing to refit: the check leaves its estimate as it is
    same = with_profile(res, problem)
    assert "refitted_from_gain" not in same.profile and np.array_equal(same.z, res.z)
