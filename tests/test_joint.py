"""Joint fits of several simulated videos of one setup (galileo_jax.inference.joint).

One object on ramps at two angles, the same true friction, 1 s videos at 30 fps with 1 mm
position noise, the default 8 physics substeps per frame (with 4, the sliding box's contact
chatter at 35 degrees made log L jump by ~200 nats between k1 values 0.005 apart, and the
fit stopped 0.027 from the truth). Problems are module-scoped so each rollout program
compiles once, and run on the C engine, the one ``fit`` picks on a CPU (the joint code is the
same for both engines; cold, MJX's LM programs made this module take 512 s in the suite, and
115 s alone on the C engine).

Tolerance on the shared k1 (0.01): the Gauss-Newton SD of the joint k1 here is ~0.002
(velocity SD per sample sqrt(0.042^2 + 0.05^2) m/s with the default model floor, 2 x 30
samples, d v / d k1 = -g cos(theta) t), so 0.01 is ~5 SD, and it is still ten times smaller
than the gap between the apparent frictions that the rolling test has to tell apart.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from galileo_jax.inference.grad import fit_grad
from galileo_jax.inference.joint import JointProblem
from galileo_jax.inference.problem import Problem, simulated_observation
from galileo_jax.physics.simulate import PhysParams
from galileo_jax.scene import scene_from_dict

K1 = 0.25
MU = 0.3  # rolling test: pipe-board friction
ANGLES = (20.0, 35.0)
ROLL_ANGLES = (20.0, 45.0)  # rolls without slipping (tan 0.36 < 3 mu) / rolls and slips (tan 1 > 3 mu = 0.9)
#: The engine of the fits (module docstring).
ENGINE = "mujoco"


def _scene(angle, rolling=False):
    h = 0.08 if rolling else 0.04
    obj = {"shape": "box", "size": [0.08, 0.06, h], "start": 3.2}
    if rolling:
        obj["rolling"] = {"radius": h / 2, "inertia_ratio": 0.5}
    return scene_from_dict({"name": f"ramp_{angle:g}", "ramp": {"angle_deg": angle, "length": 3.5},
                            "objects": [obj], "camera": {"pixels_per_metre": 1000.0},
                            "simulation": {"fit_release": False}})


def _problems(angles, k1, rolling=False, fit_effects=()):
    out = []
    for j, a in enumerate(angles):
        scene = _scene(a, rolling)
        truth = PhysParams(jnp.array([0.5]), jnp.array([k1]))
        obs = simulated_observation(scene, truth, duration=1.0, position_sd=1e-3, seed=j,
                                    effects=("rolling",) if rolling else ())
        out.append(Problem(scene, obs, effects=fit_effects, engine=ENGINE))
    return out


@pytest.fixture(scope="module")
def problems():
    return _problems(ANGLES, K1)


@pytest.fixture(scope="module")
def joint(problems):
    return JointProblem(problems)


@pytest.fixture(scope="module")
def joint_fit(joint):
    return fit_grad(joint, jax.random.key(0), n_starts=1, n_screen=8, max_steps=10, polish_rounds=0)


@pytest.mark.slow
def test_joint_fit_recovers_shared_friction(joint, joint_fit):
    res = joint_fit
    assert res.names == ("k1",) and joint.names == ("k1",)
    assert abs(res.theta[0] - K1) < 0.01
    assert 0 < res.sd[0] < 0.005
    assert res.interval90[0, 0] <= res.theta[0] <= res.interval90[0, 1]
    assert res.loglik == pytest.approx(-res.cost + joint.likelihood.log_norm)
    assert joint.likelihood.log_norm == pytest.approx(sum(p.likelihood.log_norm for p in joint.problems))
    profiles = joint.simulate(res.theta)
    assert [p.shape for p in profiles] == [(2, 30), (2, 30)]


def test_joint_loglik_is_the_sum_of_the_videos(problems, joint, joint_fit):
    """Same theta, same batch shape (a vmapped rollout's contact noise depends a little on
    the batch size, so batched and unbatched values differ by float noise)."""
    theta = jnp.linspace(0.2, 0.3, 8)[:, None]  # the screen's batch shape: the compiled program is reused
    z = joint.space.to_unconstrained(theta)
    singles = sum(np.asarray(p.log_likelihood(p.space.to_unconstrained(theta))) for p in problems)
    assert np.allclose(np.asarray(joint.log_likelihood(z)), singles, rtol=1e-6, atol=1e-3)
    # per-video copies read the right coordinate: k1@0 -> video 0, k1@1 -> video 1
    jp = JointProblem(problems, per_video=["k1"])
    assert jp.names == ("k1@0", "k1@1")
    theta2 = jnp.stack([theta[:, 0], theta[::-1, 0]], axis=1)
    want = (np.asarray(problems[0].log_likelihood(problems[0].space.to_unconstrained(theta2[:, :1])))
            + np.asarray(problems[1].log_likelihood(problems[1].space.to_unconstrained(theta2[:, 1:]))))
    assert np.allclose(np.asarray(jp.log_likelihood(jp.space.to_unconstrained(theta2))), want, rtol=1e-6, atol=1e-3)


def test_per_video_parameters_get_one_copy_per_video(problems):
    probs = [Problem(p.scene, p.observation, effects=("initial_push",), engine=ENGINE) for p in problems]
    jp = JointProblem(probs)  # v0 (initial_push) is per-video by default
    assert jp.names == ("k1", "v0@0", "v0@1")
    assert jp.space.maps == ((0, 1), (0, 2))
    theta = jnp.array([0.25, 0.1, 0.4])
    assert np.allclose(jp.theta_for(1, theta), [0.25, 0.4])
    jp2 = JointProblem(probs, per_video=["k1"])
    assert jp2.names == ("k1@0", "v0@0", "k1@1", "v0@1") and jp2.dim == 4
    assert jp2.space.index("k1@1") == 2
    # the transforms are ParamSpace's
    z = jnp.array([0.3, -1.0, 2.0, 0.1])
    assert np.allclose(jp2.theta_for(1, jp2.space.from_unconstrained(z)),
                       probs[1].space.from_unconstrained(jp2.theta_for(1, z)))
    one = JointProblem(probs[:1])  # one video: the joint space is the video's own
    z1 = jnp.array([[0.3, -1.0], [1.2, 0.4]])
    assert one.names == ("k1", "v0@0")
    assert np.allclose(one.space.log_prior(z1), probs[0].space.log_prior(z1))
    assert np.allclose(one.space.dtheta_dz(z1), probs[0].space.dtheta_dz(z1))
    # the release-time correction is per video by default (each clip has its own release)
    from galileo_jax.inference.joint import JointSpace
    from galileo_jax.params import ParamSpace

    spaces = [ParamSpace.from_scene(p.scene.model_copy(update={"simulation": p.scene.simulation.model_copy(
        update={"fit_release": True})})) for p in problems]
    js = JointSpace.from_spaces(spaces)
    assert js.names == ("k1", "dt_release@0", "dt_release@1") and js.maps == ((0, 1), (0, 2))
    with pytest.raises(ValueError, match="per_video"):
        JointProblem(probs, per_video=["k3"])
    with pytest.raises(TypeError, match="Problem"):
        JointProblem([probs[0], "video.mp4"])
    with pytest.raises(ValueError, match="at least one"):
        JointProblem([])


@pytest.mark.slow
def test_rolling_joint_fit_finds_mu_and_beats_sliding():
    """Truth: a solid cylinder (I = m r^2 / 2) that rolls without slipping at 20 deg and rolls
    and slips at 45 deg (tan 45 = 1 > mu (1 + 1/alpha) = 0.9), one mu = 0.3. Only the 45 deg
    video depends on mu (the 20 deg one just says mu > tan(20)/3). The rolling model
    recovers mu; the sliding block would need apparent frictions tan(20)/3 = 0.12 and
    ~0.23, so its best shared k1 fits far worse.

    (45 deg, not steeper: a slipping cylinder in MuJoCo hops off the plane by up to 4 mm at
    60 deg with 8 substeps, which makes log L jump by tens of nats between mu values 0.005
    apart; at 45 deg and mu = 0.3 the hop is < 1 mm and log L is smooth in mu.)

    The sliding model's best log L is taken on a grid over k1 (one batched call instead of a
    second LM fit, to keep the test short): 1-D, spacing 0.01 over all k1 that let the
    block slide; LM could gain at most the curvature over 0.005 (tens of nats) on it, far
    below the ~800-nat gap asserted against."""
    roll = JointProblem(_problems(ROLL_ANGLES, MU, rolling=True, fit_effects=("rolling",)))
    r_roll = fit_grad(roll, jax.random.key(1), n_starts=1, n_screen=8, max_steps=10, polish_rounds=0)
    assert abs(r_roll.theta[0] - MU) < 0.01
    slide = JointProblem([Problem(p.scene, p.observation, engine=ENGINE) for p in roll.problems])
    grid = jnp.linspace(0.02, 0.6, 59)[:, None]
    ll_slide = np.asarray(slide.log_likelihood(slide.space.to_unconstrained(grid)))
    assert r_roll.loglik > ll_slide.max() + 400.0


def test_scale_error_stretches_the_simulation_as_the_camera_would():
    """camera.scale_tolerance adds the nuisance ``scale_error`` (per video in a joint fit): a
    video whose calibration is 6% off (observed displacements 1.06x the true ones) is matched
    exactly by the simulation at scale_error = 0.06, and missed by 6% without it."""

    scene = _scene(20.0)
    tol_scene = scene.model_copy(update={"camera": scene.camera.model_copy(update={"scale_tolerance": 0.1})})
    truth = PhysParams(jnp.array([0.5]), jnp.array([K1]))
    obs = simulated_observation(scene, truth, duration=1.0, position_sd=1e-6, seed=0)
    start = obs.positions[:1]
    stretched = obs._replace(positions=start + 1.06 * (obs.positions - start), profile=1.06 * obs.profile)
    plain, tol = Problem(scene, stretched), Problem(tol_scene, stretched)
    assert "scale_error" not in plain.names
    assert tol.names == ("k1", "scale_error") and tol.space.lower[1] == -0.1 and tol.space.upper[1] == 0.1
    moving = np.abs(stretched.profile[0]) > 0.1
    sim = np.asarray(tol.simulate(np.array([K1, 0.06])))
    assert np.max(np.abs(sim - stretched.profile)[:, moving]) < 1e-4
    sim0 = np.asarray(plain.simulate(np.array([K1])))
    assert np.allclose(sim0[:, moving] * 1.06, stretched.profile[:, moving], atol=1e-4)
    poses = tol.poses(np.array([K1, 0.06]))
    assert np.allclose(poses[-1, 0, :2] - poses[0, 0, :2], stretched.positions[-1, 0] - start[0, 0], atol=1e-4)
    joint = JointProblem([tol, Problem(tol_scene, obs)])
    assert {"scale_error@0", "scale_error@1"} <= set(joint.names) and "k1" in joint.names
