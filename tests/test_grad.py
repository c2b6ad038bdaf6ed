"""Levenberg-Marquardt fit on a short simulated two-object video, and the FD Jacobian.

One module-scoped problem (1.5 s at 30 fps, known truth, 1 mm position noise) is shared,
so the MJX rollout compiles a few times only.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from galileo_jax.inference.grad import fit_grad
from galileo_jax.inference.problem import Problem, fd_jacobian_fn, simulated_observation
from galileo_jax.inference.summary import summarize_grad
from galileo_jax.scene import scene_from_dict
from galileo_jax.simulate import PhysParams

SCENE2 = scene_from_dict({
    "name": "ramp_20", "ramp": {"angle_deg": 20, "length": 0.6},
    "objects": [{"shape": "box", "size": [0.08, 0.06, 0.04], "start": 0.45},
                {"shape": "box", "size": [0.08, 0.06, 0.04], "start": 0.15}],
    "camera": {"pixels_per_metre": 1692.9}})
TRUTH = {"k1": 0.2, "k2": 0.25, "phi": (0.6 - 0.3) / 0.9}


@pytest.fixture(scope="module")
def problem():
    truth = PhysParams(jnp.array([0.6, 0.3]), jnp.array([TRUTH["k1"], TRUTH["k2"]]))
    obs = simulated_observation(SCENE2, truth, duration=1.5, position_sd=1e-3, seed=0)
    return Problem(SCENE2, obs)


def test_fd_jvp_rule_is_the_central_difference():
    """custom_jvp with central differences: exact for a quadratic, linear in the tangent."""
    f = lambda z: jnp.stack([z[0] ** 2 + 3 * z[1], z[0] * z[1]])  # noqa: E731
    g = fd_jacobian_fn(f, 0.1)
    z = jnp.array([0.7, -1.3])
    assert np.allclose(jax.jacfwd(g)(z), jax.jacfwd(f)(z), atol=1e-5)
    _, lin = jax.linearize(g, z)  # linear in the tangent, so it can be transposed (optimistix needs this)
    t = jnp.array([0.3, 2.0])
    (ct,) = jax.linear_transpose(lin, t)(jnp.array([1.0, -1.0]))
    assert np.allclose(ct, jax.jacfwd(f)(z).T @ jnp.array([1.0, -1.0]), atol=1e-5)


def test_fd_jacobian_matches_central_differences_of_rollout(problem):
    space = problem.space
    h = 0.05
    z = space.to_unconstrained(jnp.array([0.21, 0.3, 0.25]))
    jac = np.asarray(jax.jit(jax.jacfwd(problem.residual_fn("fd", h)))(z))  # (n_res, d)
    d = space.dim
    pts = jnp.concatenate([z + h * jnp.eye(d), z - h * jnp.eye(d)])
    r = np.asarray(problem.residuals(space.from_unconstrained(pts)))  # (2d, n_res)
    manual = ((r[:d] - r[d:]) / (2 * h)).T
    assert jac.shape == (problem.likelihood.n_residuals, d)
    assert np.allclose(jac, manual, rtol=1e-3, atol=1e-2 * np.abs(manual).max())


def test_grad_recovers_truth(problem):
    res = fit_grad(problem, jax.random.key(0), n_starts=3, n_screen=32, max_steps=30)
    est = dict(zip(res.names, res.theta))
    assert abs(est["k1"] - TRUTH["k1"]) < 0.02
    assert abs(est["k2"] - TRUTH["k2"]) < 0.03
    assert abs(est["phi"] - TRUTH["phi"]) < 0.1
    assert np.all(np.isfinite(res.sd)) and np.all(res.sd > 0)
    assert np.all((res.interval90[:, 0] <= res.theta) & (res.theta <= res.interval90[:, 1]))
    assert res.iterations > 0 and res.cost == pytest.approx(res.starts_cost.min())
    summ = summarize_grad(res, problem.space)
    p = summ["parameters"]
    assert set(p) == {"k1", "k2", "phi", "m1", "m2"}
    assert p["k1"]["mean"] == pytest.approx(est["k1"]) and p["k1"]["rhat"] is None
    assert not p["m1"]["identifiable"] and p["m1"]["mean"] is None
    assert summ["diagnostics"]["jacobian"] == "fd"


def test_grad_rejects_bad_arguments(problem):
    with pytest.raises(ValueError, match="init"):
        fit_grad(problem, jax.random.key(0), init=np.array([0.2, 0.3]))
    with pytest.raises(ValueError, match="jacobian"):
        fit_grad(problem, jax.random.key(0), jacobian="bwd")
    with pytest.raises(ValueError, match="n_screen"):
        fit_grad(problem, jax.random.key(0), n_starts=8, n_screen=4)
