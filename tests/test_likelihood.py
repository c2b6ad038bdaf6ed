"""Likelihoods against scipy, the noise model against Monte Carlo, and the parameter space.

No MJX here: observations are built by hand, so the whole file runs in seconds.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from galileo_jax.likelihood import (KINDS, SEED_SD, emd_distance, gaussian_loglik, make_likelihood,
                                    rms_similarity, velocity_covariance)
from galileo_jax.observation import Observation, profile_from_positions
from galileo_jax.params import ParamSpace
from galileo_jax.scene import scene_from_dict

FPS = 30.0


def make_obs(n_frames=13, n_objects=2, sd=(1e-3, 2e-3, 5e-4, 1e-3), mask=None, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames) / FPS
    pos = np.cumsum(rng.normal(0, 0.01, (n_frames, n_objects, 2)), axis=0)
    prof = profile_from_positions(pos, t)
    mask = np.ones(n_frames - 1, bool) if mask is None else mask
    return Observation(frame_times=t, positions=pos, pixels=pos * 1000, profile=prof,
                       position_sd=np.asarray(sd[:2 * n_objects], float), mask=mask, release_time=0.0,
                       fps=FPS, moved=np.ones(n_objects, bool))


def test_gaussian_iid_matches_scipy():
    mask = np.ones(12, bool)
    mask[:3] = False
    obs = make_obs(mask=mask)
    sim = obs.profile + np.random.default_rng(1).normal(0, 0.05, obs.profile.shape)
    sd_model = 0.02
    lik = make_likelihood(obs, "gaussian_iid", sd_model)
    sd = np.sqrt(obs.velocity_sd**2 + sd_model**2)
    expected = stats.norm.logpdf(obs.profile[:, mask], sim[:, mask], sd[:, None]).sum()
    assert float(lik(jnp.asarray(sim))) == pytest.approx(expected, rel=1e-5)
    # the pure eq. 4.3 function agrees too
    got = gaussian_loglik(jnp.asarray(sim), jnp.asarray(obs.profile), jnp.asarray(sd), jnp.asarray(mask))
    assert float(got) == pytest.approx(expected, rel=1e-5)


def test_seed_gaussian_matches_scipy():
    obs = make_obs()
    sim = obs.profile + 0.03
    expected = stats.norm.logpdf(obs.profile, sim, SEED_SD).sum()
    assert float(make_likelihood(obs, "seed_gaussian")(jnp.asarray(sim))) == pytest.approx(expected, rel=1e-5)


def test_gaussian_ma1_matches_scipy_multivariate_normal():
    mask = np.ones(12, bool)
    mask[-2:] = False
    obs = make_obs(mask=mask)
    sim = obs.profile + np.random.default_rng(2).normal(0, 0.05, obs.profile.shape)
    sd_model = 0.01
    lik = make_likelihood(obs, "gaussian_ma1", sd_model)
    m = 12
    tri = 2 * np.eye(m) - np.eye(m, k=1) - np.eye(m, k=-1)  # D D^T for unit frame spacing
    expected = 0.0
    for i, sd_p in enumerate(obs.position_sd):
        cov = (sd_p * FPS) ** 2 * tri + sd_model**2 * np.eye(m)
        cov = cov[np.ix_(mask, mask)]
        expected += stats.multivariate_normal(sim[i, mask], cov).logpdf(obs.profile[i, mask])
    assert float(lik(jnp.asarray(sim))) == pytest.approx(expected, rel=1e-5)
    # residuals are the whitened residuals: log L = -|r|^2 / 2 + log_norm
    r = lik.residuals(jnp.asarray(sim))
    assert r.shape == (4 * 12,)  # fixed length: every sample, zero where unused
    assert np.all(np.asarray(r).reshape(4, 12)[:, ~mask] == 0)
    assert lik.used(r).shape == (4 * mask.sum(),)
    assert float(-0.5 * jnp.sum(r**2) + lik.log_norm) == pytest.approx(expected, rel=1e-5)


@pytest.mark.parametrize("kind", KINDS)
def test_padding_and_traced_observation_give_the_same_value(kind):
    """Padding a profile with unused samples changes nothing, and one jitted function of
    (profile, likelihood) serves observations with different masks and values."""
    mask = np.ones(12, bool)
    mask[:2] = False
    obs = make_obs(mask=mask)
    sim = obs.profile + np.random.default_rng(5).normal(0, 0.03, obs.profile.shape)
    plain = float(make_likelihood(obs, kind, 0.02)(jnp.asarray(sim)))
    padded_lik = make_likelihood(obs, kind, 0.02, n_samples=20)
    padded_sim = np.concatenate([sim, np.full((4, 8), 7.0)], axis=1)  # garbage in the padding
    assert float(padded_lik(jnp.asarray(padded_sim))) == pytest.approx(plain, rel=1e-6)
    fn = jax.jit(lambda s, lik: lik(s))
    other = make_obs(mask=np.r_[np.zeros(5, bool), np.ones(7, bool)], seed=9)
    other_lik = make_likelihood(other, kind, 0.02, n_samples=20)
    assert float(fn(jnp.asarray(padded_sim), padded_lik)) == pytest.approx(plain, rel=1e-6)
    expected_other = float(make_likelihood(other, kind, 0.02)(jnp.asarray(sim)))
    assert float(fn(jnp.asarray(padded_sim), other_lik)) == pytest.approx(expected_other, rel=1e-6)
    assert fn._cache_size() == 1  # one trace for both observations


def test_velocity_covariance_matches_monte_carlo():
    """Differenced iid position noise has the MA(1) covariance of the likelihood."""
    rng = np.random.default_rng(3)
    t = np.arange(8) / FPS
    sd_p = 2e-3
    e = rng.normal(0, sd_p, (200_000, 8))
    v = np.diff(e, axis=1) * FPS
    emp = np.cov(v.T)
    model = velocity_covariance(t, sd_p, 0.0)
    assert np.allclose(emp, model, atol=0.03 * model[0, 0])
    assert model[0, 1] / model[0, 0] == pytest.approx(-0.5)


def test_emd_matches_reference_dynamic_programme():
    rng = np.random.default_rng(4)
    a, b = rng.normal(size=9), rng.normal(size=9)
    n = len(a)
    big = 1e30
    mm = np.full((n + 1, n + 1), big)
    mm[0, 0] = 0.0
    for i in range(1, n + 1):
        for j in range(1, n + 1):
            mm[i, j] = abs(a[i - 1] - b[j - 1]) + min(mm[i - 1, j], mm[i, j - 1], mm[i - 1, j - 1])
    assert float(emd_distance(jnp.asarray(a), jnp.asarray(b))) == pytest.approx(mm[n, n], rel=1e-5)
    assert float(emd_distance(jnp.asarray(a), jnp.asarray(a))) == pytest.approx(0.0, abs=1e-6)


def test_rms_similarity_formula_and_selection_by_name():
    obs = make_obs()
    sim = obs.profile * 1.1
    x, y = sim, obs.profile
    den = np.abs(x) + np.abs(y)
    expected = np.sqrt(np.mean(1 - np.abs(x - y) / den))
    assert float(rms_similarity(jnp.asarray(sim), jnp.asarray(obs.profile), obs.mask)) == pytest.approx(expected, rel=1e-5)
    for kind in KINDS:
        lik = make_likelihood(obs, kind)
        best, worse = float(lik(jnp.asarray(obs.profile))), float(lik(jnp.asarray(sim + 0.1)))
        assert best > worse, kind  # higher is closer for every kind
        jax.jit(jax.vmap(lik))(jnp.stack([jnp.asarray(sim)] * 2))  # jittable and vmappable


def test_likelihood_errors():
    obs = make_obs()
    with pytest.raises(ValueError, match="unknown likelihood"):
        make_likelihood(obs, "gauss")
    with pytest.raises(ValueError, match="no velocity samples"):
        make_likelihood(obs._replace(mask=np.zeros(12, bool)), "gaussian_iid")
    bad = obs.profile.copy()
    bad[0, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        make_likelihood(obs._replace(profile=bad), "gaussian_iid")
    with pytest.raises(ValueError, match="positive definite"):
        make_likelihood(obs._replace(position_sd=np.zeros(4)), "gaussian_ma1", sd_model=0.0)
    with pytest.raises(ValueError, match="no residuals"):
        make_likelihood(obs, "emd").residuals(jnp.asarray(obs.profile))


# ---------------------------------------------------------------------------- parameter space
def _scene(objects, fit_release=False):
    return scene_from_dict({"ramp": {"angle_deg": 20, "length": 0.6}, "objects": objects,
                            "camera": {"pixels_per_metre": 1000}, "simulation": {"fit_release": fit_release}})


BOX1 = {"shape": "box", "size": [0.08, 0.06, 0.04], "start": 0.45}
BOX2 = {"shape": "box", "size": [0.08, 0.06, 0.04], "start": 0.15}


def test_param_space_layouts():
    assert ParamSpace.from_scene(_scene([BOX1, BOX2])).names == ("k1", "k2", "phi")
    sp = ParamSpace.from_scene(_scene([BOX1, {**BOX2, "mass": 0.3}]))
    assert sp.names == ("k1", "k2", "m1") and sp.mass_identifiable
    sp1 = ParamSpace.from_scene(_scene([BOX1]))
    assert sp1.names == ("k1",) and sp1.mass_mode == "none"
    with pytest.raises(ValueError, match="no free parameter"):
        ParamSpace.from_scene(_scene([{**BOX1, "friction": 0.2}]))
    p = sp.physical(jnp.array([[0.2, 0.3, 0.7]]))
    assert np.allclose(p.mass, [[0.7, 0.3]]) and np.allclose(p.friction, [[0.2, 0.3]])
    # the default scene also fits the release time: a uniform nuisance on +-release_window s
    spr = ParamSpace.from_scene(_scene([BOX1, BOX2], fit_release=True))
    assert spr.names == ("k1", "k2", "phi", "dt_release") and spr.n_physical == 4
    j = spr.index("dt_release")
    assert (spr.lower[j], spr.upper[j]) == (-0.2, 0.2)
    assert float(spr.release_offset(jnp.array([0.2, 0.3, 0.1, -0.05]))) == pytest.approx(-0.05)
    assert float(sp.release_offset(jnp.array([0.2, 0.3, 0.7]))) == 0.0
    draws = np.asarray(spr.sample_prior(jax.random.key(0), 4000))[:, j]
    assert draws.min() >= -0.2 and draws.max() <= 0.2 and stats.kstest((draws + 0.2) / 0.4, "uniform").pvalue > 1e-3


def test_phi_at_its_bounds_gives_masses_mujoco_can_simulate():
    """The default mass prior (0, 1) kg allows phi in (-1, 1); a draw at phi = +-1 (saturated
    Gauss-Newton draws of a wide posterior) must not give an object of zero mass, which MuJoCo
    cannot simulate: |phi| is clipped to PHI_SIMULATED_MAX, and inside it nothing changes."""
    from galileo_jax.params import PHI_SIMULATED_MAX, REFERENCE_TOTAL_MASS

    sp = ParamSpace.from_scene(_scene([BOX1, BOX2]))
    j = sp.index("phi")
    theta = np.tile([0.2, 0.3, 0.0], (4, 1))
    theta[:, j] = [-1.0, 1.0, 0.5, -PHI_SIMULATED_MAX]
    mass = np.asarray(sp.physical(jnp.asarray(theta)).mass)
    assert mass.min() > 0.0
    assert np.allclose(mass[1], REFERENCE_TOTAL_MASS * np.array([1 + PHI_SIMULATED_MAX, 1 - PHI_SIMULATED_MAX]) / 2)
    assert np.allclose(mass[0], mass[1, ::-1]) and np.allclose(mass[0], mass[3])
    assert np.allclose(mass[2], REFERENCE_TOTAL_MASS * np.array([0.75, 0.25]))


def test_phi_prior_is_induced_by_uniform_masses():
    sp = ParamSpace.from_scene(_scene([BOX1, BOX2]))
    j = sp.index("phi")
    # density (1 + |phi|)^-2 on (-1, 1), normalised
    phi = np.linspace(-0.999, 0.999, 2001)
    th = np.zeros((phi.size, 3)) + 0.5
    th[:, j] = phi
    dens = np.exp(np.asarray(sp.log_prior_theta(jnp.asarray(th))))
    assert np.allclose(dens, (1 + np.abs(phi)) ** -2 * 1.0, rtol=1e-4)  # frictions uniform on (0, 1)
    assert np.trapezoid(dens, phi) == pytest.approx(1.0, abs=2e-3)
    # prior draws of phi follow it, and masses drawn given phi are uniform on (0, 1)^2
    theta = sp.sample_prior(jax.random.key(0), 20000)
    cdf = lambda x: np.where(x < 0, 1 / (1 - x) - 0.5, 1.5 - 1 / (1 + x))  # noqa: E731  (integral of the density)
    assert stats.kstest(np.asarray(theta[:, j]), cdf).pvalue > 1e-3
    m = np.asarray(sp.masses_for_report(theta, jax.random.key(1)))
    assert stats.kstest(m[:, 0], "uniform").pvalue > 1e-3 and stats.kstest(m[:, 1], "uniform").pvalue > 1e-3
    assert abs(np.corrcoef(m.T)[0, 1]) < 0.03
    phi_back = (m[:, 0] - m[:, 1]) / (m[:, 0] + m[:, 1])
    assert np.allclose(phi_back, theta[:, j], atol=1e-5)


def test_unconstrained_transform_and_jacobian():
    sp = ParamSpace.from_scene(_scene([BOX1, {**BOX2, "mass": 0.3}]))
    theta = sp.sample_prior(jax.random.key(2), 5)
    assert np.allclose(sp.from_unconstrained(sp.to_unconstrained(theta)), theta, atol=1e-5)
    # exp(log_prior(z)) integrates to 1 over z (1-D check on each coordinate)
    sp1 = ParamSpace.from_scene(_scene([BOX1]))
    z = np.linspace(-25, 25, 20001)[:, None]
    assert np.trapezoid(np.exp(np.asarray(sp1.log_prior(jnp.asarray(z)))), z[:, 0]) == pytest.approx(1.0, abs=1e-3)
    sp2 = ParamSpace.from_scene(_scene([BOX1, BOX2]))
    zz = np.zeros((20001, 3))
    zz[:, 2] = z[:, 0]
    dens = np.exp(np.asarray(sp2.log_prior(jnp.asarray(zz))))  # frictions at z = 0 contribute log(1/4)
    assert np.trapezoid(dens, z[:, 0]) == pytest.approx(1.0 / 16.0, rel=1e-3)
    assert math.isinf(float(sp2.log_prior_theta(jnp.array([0.2, 0.3, 1.5]))))


def test_event_sd_marks_velocity_jumps_of_simulation_and_observation():
    """Contact events: the samples around a jump of an object's velocity get SD fraction x jump
    (capped); steady acceleration, a small kink and noise get none."""
    from galileo_jax.likelihood import EVENT_CAP, EVENT_FRACTION, event_jumps, event_sd

    n = 30
    t = np.arange(n) / FPS
    sim = np.zeros((4, n))
    sim[0] = 2.0 * t                       # object 1: steady acceleration ...
    sim[0, 15:] = 0.4 * sim[0, 15:]        # ... until an impact at sample 15 (jump ~0.6 m/s)
    sim[2, 15:] = 0.7                      # object 2 starts at the impact
    sim[2, 22:] = 0.7 - 0.1                # a small kink (0.1 m/s): not an event
    jumps = event_jumps(sim)
    assert jumps.shape == (2, n)
    assert np.flatnonzero(jumps[0]).tolist() == [14, 15] and np.flatnonzero(jumps[1]).tolist() == [14, 15]
    sd = event_sd(sim, halfwidth=1)
    assert sd.shape == sim.shape
    assert np.all(sd[0] == sd[1]) and np.all(sd[2] == sd[3])      # both traces of an object
    assert np.flatnonzero(sd[0]).tolist() == [13, 14, 15, 16]       # events +- 1 sample
    assert sd[2, 15] == pytest.approx(min(EVENT_FRACTION * jumps[1].max(), EVENT_CAP))
    assert np.all(sd[:, :12] == 0) and np.all(sd[:, 18:] == 0)
    # the observed profile adds its own jumps only where they stand out of its noise
    rng = np.random.default_rng(0)
    obs = sim + rng.normal(0, 0.003, sim.shape)
    obs[0, 25:] += 0.5                                            # an impact the simulation lacks
    sd2 = event_sd(sim, obs, np.full(4, 0.003), halfwidth=1)
    assert np.flatnonzero(sd2[0]).tolist() == [13, 14, 15, 16, 23, 24, 25, 26]
    noisy = event_sd(sim, sim + rng.normal(0, 0.05, sim.shape), np.full(4, 0.05), halfwidth=1)
    assert np.array_equal(noisy, sd)                               # 0.05 m/s noise: threshold 0.8 m/s
