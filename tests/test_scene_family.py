"""One amortised network for any ramp scene: the scene family (its features, ranges and
one-line errors), the family's rollouts against the C engine and against the closed form of
sliding, the training examples against the input a tracked video gives, the
scene-conditioned network, and its training run."""

from __future__ import annotations

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from galileo_jax.inference import cnn, cnn_training
from galileo_jax.observation import Observation
from galileo_jax.physics.simulate import make_simulator
from galileo_jax.physics.simulate_c import rollout_poses_host
from galileo_jax.physics.simulate_family import FAMILY_DT, family_rollout_poses, family_rollout_poses_host
from galileo_jax.scene import load_scene
from galileo_jax.scene_family import (FEATURES, FOOT_CLEARANCE, OutOfFamily, SceneFamily, family_scene,
                                      scene_features)
from galileo_jax.train import TrainConfig, train

FAMILY = SceneFamily()
G = 9.81


def _features(**kw) -> np.ndarray:
    base = dict(angle_deg=20.0, length_1=0.06, width_1=0.06, height_1=0.06, length_2=0.06, width_2=0.06,
                height_2=0.06, start_1=0.6, start_2=0.3, fps=30.0)
    base.update(kw)
    return np.array([base[f] for f in FEATURES])


def test_drawn_scenes_lie_in_the_family_and_read_back():
    f = np.asarray(FAMILY.draw(jax.random.PRNGKey(3), 200))
    assert np.all(f >= FAMILY.lower - 1e-12) and np.all(f <= FAMILY.upper + 1e-12)
    for obj in ("1", "2"):
        assert np.all(f[:, FEATURES.index("start_" + obj)] >= f[:, FEATURES.index("length_" + obj)] / 2
                      + FOOT_CLEARANCE - 1e-12)
    fps = f[:, FEATURES.index("fps")]
    assert np.mean(fps < math.sqrt(25 * 240)) == pytest.approx(0.5, abs=0.12)  # log-uniform: half below the middle
    for row in f[:20]:
        scene = family_scene(row)
        assert np.allclose(scene_features(scene, row[-1]), row)
        FAMILY.check(row)
    z = FAMILY.normalise(f)
    assert np.all(np.abs(z) <= 1 + 1e-9)


def test_shipped_scene_is_in_the_family_and_others_get_one_line_errors():
    scene = load_scene("scenes/ramp_20.yaml")
    FAMILY.check(scene_features(scene, 30.0))
    with pytest.raises(OutOfFamily, match=r"angle_deg = 60 deg is outside .* 5-45 deg") as err:
        FAMILY.check(_features(angle_deg=60.0))
    assert "\n" not in str(err.value) and "--method grad" in str(err.value)
    with pytest.raises(OutOfFamily, match=r"fps = 1000 fps"):
        FAMILY.check(_features(fps=1000.0))
    with pytest.raises(OutOfFamily, match="1 object"):
        scene_features(load_scene("scenes/sliding_plain_R4.yaml"), 240.0)
    known = scene.model_copy(update={"objects": [scene.objects[0].model_copy(update={"mass": 0.2}),
                                                 scene.objects[1]]})
    with pytest.raises(OutOfFamily, match=r"objects\[0\]\.mass is known"):
        scene_features(known, 30.0)
    board = scene.model_copy(update={"ramp": scene.ramp.model_copy(update={"thickness": 0.02})})
    with pytest.raises(OutOfFamily, match="ramp.thickness"):
        scene_features(board, 30.0)


def test_family_rollouts_are_the_c_engines():
    """Each row's scene simulated by the family's host code is the C engine's rollout of that
    scene, to the last bit, also as a batched host call inside jit."""
    rows = np.stack([_features(), _features(angle_deg=35.0, start_1=0.4, length_2=0.1, fps=120.0)])
    mass = np.array([[1.3, 0.7], [0.5, 1.5]])
    friction = np.array([[0.15, 0.3], [0.4, 0.2]])
    n = 300
    got = family_rollout_poses_host(rows, mass, friction, n)
    for b in range(2):
        sim = make_simulator(family_scene(rows[b]), 30.0, engine="mujoco")  # 8 substeps: dt 1/240 s
        assert sim.dt == pytest.approx(FAMILY_DT)
        want = rollout_poses_host(sim, mass[b:b + 1], friction[b:b + 1], n)[0]
        np.testing.assert_array_equal(got[b], want)
    jitted = jax.jit(jax.vmap(lambda f, m, k: family_rollout_poses(f, m, k, n)))(
        jnp.asarray(rows), jnp.asarray(mass), jnp.asarray(friction))
    np.testing.assert_array_equal(np.asarray(jitted), got)


def test_family_rollouts_slide_at_the_closed_form_acceleration():
    """Object 1 slides down each scene's ramp at g (sin theta - k cos theta) before it reaches
    the foot, whatever the angle and size."""
    angles = np.array([8.0, 25.0, 42.0])
    rows = np.stack([_features(angle_deg=a, start_1=0.9, length_1=0.04 + 0.03 * i) for i, a in enumerate(angles)])
    k1 = np.tan(np.radians(angles)) * 0.5
    poses = family_rollout_poses_host(rows, np.ones((3, 2)), np.stack([k1, np.full(3, 0.3)], 1), 120)
    for b, th in enumerate(np.radians(angles)):
        x = poses[b, :, 0, 0]
        t = np.arange(len(x)) * FAMILY_DT
        travel = (x - x[0]) / math.cos(th)  # along the slope
        a_fit = np.polyfit(t[20:], travel[20:], 2)[0] * 2
        assert a_fit == pytest.approx(G * (math.sin(th) - k1[b] * math.cos(th)), rel=0.01)


def test_slide_friction_reads_each_inputs_ramp_from_its_scene_features():
    """A scene-conditioned network's closed form of the slide takes each input's ramp angle,
    object length and start from its (normalised) scene features: on clean simulated examples of
    three scenes (10, 25 and 40 degrees, other sizes and starts) it gives k1 to 0.003, where the
    family's middle scene's geometry would be off by 0.05 or more."""
    spec = cnn.CNNSpec.for_family(FAMILY, 30.0, n_samples=48, ramp_feature=True)
    noise = cnn_training.NoiseModel((1e-12, 1.001e-12), spec.n_samples, 0)
    rows = np.stack([_features(angle_deg=a, start_1=s1, length_1=l1, fps=60.0)
                     for a, s1, l1 in ((10.0, 1.0, 0.05), (25.0, 0.8, 0.10), (40.0, 1.1, 0.12))])
    k1 = np.tan(np.radians(rows[:, FEATURES.index("angle_deg")])) * np.array([0.3, 0.6, 0.8])
    theta = jnp.asarray(np.stack([k1, np.full(3, 0.3), np.zeros(3), np.zeros(3)], 1))
    x = cnn_training.simulate_family_examples(spec, noise, jnp.asarray(rows), theta, jax.random.PRNGKey(1))
    feature = cnn.SlideFeature.of(spec)
    tan_t, _, _ = feature.geometry(x)
    np.testing.assert_allclose(np.asarray(tan_t), np.tan(np.radians(rows[:, 0])), rtol=1e-5)
    est, _, n = cnn.slide_friction(x, feature)
    assert np.all(np.asarray(n) >= cnn.SLIDE_MIN_SAMPLES)
    np.testing.assert_allclose(np.asarray(est), k1, atol=3e-3)
    middle = feature._replace(scene_features=None)
    assert np.abs(np.asarray(cnn.slide_friction(x, middle)[0]) - k1).max() > 0.05


def test_training_examples_carry_a_camera_scale_error_when_asked():
    """``NoiseModel.scale_error``: the same simulation's clean velocities, with a 5% scale error
    drawn per view, differ from the exact-scale ones by one factor per view, within +-5% and
    not all 1 (the calibration nuisance grad and mh fit; the network's intervals then carry it)."""
    spec = cnn.CNNSpec.for_family(FAMILY, 30.0, n_samples=48)
    exact = cnn_training.NoiseModel((1e-12, 1.001e-12), spec.n_samples, 0)
    scaled = exact._replace(scale_error=0.05)
    row = _features(angle_deg=25.0, fps=60.0)
    theta = jnp.asarray([[0.2, 0.3, 0.1, 0.0]])
    key = jax.random.PRNGKey(4)
    a, b = (np.asarray(cnn_training.simulate_family_examples(spec, n, jnp.asarray(row[None]), theta, key, views=6))
            for n in (exact, scaled))
    T = spec.n_traces
    assert np.array_equal(a[..., T:], b[..., T:])  # scene features and mask unchanged
    moving = np.abs(a[..., :T]) > 0.05
    ratio = b[..., :T][moving] / a[..., :T][moving]
    per_view = [b[i, ..., :T][moving[i]] / a[i, ..., :T][moving[i]] for i in range(6)]
    assert all(np.ptp(r) < 1e-5 for r in per_view)  # one factor per view
    assert np.all(np.abs(ratio - 1) <= 0.05 + 1e-6) and np.std([r[0] for r in per_view]) > 0.005


def _clean_spec_and_noise():
    spec = cnn.CNNSpec.for_family(FAMILY, 30.0, n_samples=48)
    return spec, cnn_training.NoiseModel((1e-12, 1.001e-12), spec.n_samples, 0)


def test_training_examples_match_the_input_of_a_tracked_video():
    """A simulated example (no noise, nothing cut) equals the network input that
    :func:`cnn.family_network_input` makes from the same motion recorded as a video at the
    scene's frame rate: training and a fit resample to the grid the same way."""
    spec, noise = _clean_spec_and_noise()
    space = cnn_training.family_space(spec)
    fps = 120.0
    row = _features(angle_deg=25.0, fps=fps)
    theta = jnp.asarray([[0.2, 0.3, 0.1, 0.03]])  # k1, k2, phi, dt_release
    x = np.asarray(cnn_training.simulate_family_examples(spec, noise, jnp.asarray(row[None]), theta,
                                                         jax.random.PRNGKey(0)))[0]
    L, T = spec.n_samples, spec.n_traces
    assert x.shape == (L, spec.channels)
    np.testing.assert_allclose(x[:, T:T + spec.n_scene], np.repeat(FAMILY.normalise(row)[None], L, 0), rtol=1e-6)
    assert np.all(x[:, -1] == 1.0)
    # the same rollout recorded as a video at 120 fps, released 0.4 s into it
    phys = space.physical(theta)
    n_steps = 800
    poses = family_rollout_poses_host(row[None], np.asarray(phys.mass), np.asarray(phys.friction), n_steps)[0]
    release = 0.4
    times = np.arange(int(3.0 * fps)) / fps
    s = np.clip((times - release) / FAMILY_DT, 0, n_steps)
    i0 = np.minimum(np.floor(s).astype(int), n_steps - 1)
    w = (s - i0)[:, None, None]
    pos = ((1 - w) * poses[i0] + w * poses[i0 + 1])[..., :2]
    prof = (np.diff(pos, axis=0) * fps).reshape(len(times) - 1, -1).T
    # the tracker's release estimate misses the true release by dt_release: true = estimate + dt_release
    obs = Observation(times, pos, np.zeros_like(pos), prof, np.full(4, 1e-4), np.ones(len(times) - 1, bool),
                      release - 0.03, fps, np.ones(2, bool))
    x_obs, shift = cnn.family_network_input(spec, obs, row)
    assert shift == 0.0 and np.all(x_obs[:, -1] == 1.0)
    # m/s. The frames of the two recordings fall at other phases of the grid, and linear
    # interpolation between frames 1/120 s apart rounds off a kink of the velocity (the release,
    # the ramp's foot, the impact) differently: within ~v_jump / 4 * fps / grid-rate there
    diff = np.abs(x_obs[:, :T] - x[:, :T])
    assert np.median(diff) < 5e-4 and np.mean(diff < 2e-3) > 0.85 and diff.max() < 0.03
    np.testing.assert_allclose(x_obs[:, T:], x[:, T:])
    assert np.abs(x[:, 0]).max() > 0.3  # object 1 moved


def test_family_input_masks_what_the_video_does_not_show():
    spec, _ = _clean_spec_and_noise()
    fps = 30.0
    times = np.arange(40) / fps
    pos = np.zeros((40, 2, 2))
    pos[:, 0, 0] = 0.5 * 2.0 * np.maximum(times - 0.5, 0) ** 2
    mask = np.ones(39, bool)
    mask[20] = False
    obs = Observation(times, pos, np.zeros_like(pos), (np.diff(pos, axis=0) * fps).reshape(39, -1).T,
                      np.full(4, 1e-4), mask, 0.5, fps, np.ones(2, bool))
    x, _ = cnn.family_network_input(spec, obs, _features(fps=fps))
    grid = 0.25 + np.arange(spec.n_samples + 1) / spec.fps
    ends_inside = (grid[:-1] >= 0) & (grid[1:] <= times[-1])
    spans_gap = (grid[1:] > times[20]) & (grid[:-1] < times[21])
    np.testing.assert_array_equal(x[:, -1] == 1.0, ends_inside & ~spans_gap)
    with pytest.raises(OutOfFamily, match="fps"):
        cnn.family_network_input(spec, obs, _features(fps=10.0))


def test_scene_conditioned_network_reads_the_scene():
    spec = cnn.CNNSpec.for_family(FAMILY, 30.0, n_samples=32)
    assert spec.channels == spec.n_traces + len(FEATURES) + 1
    graphdef, params = nnx.split(cnn.build_network(spec, 1), nnx.Param)
    x = np.zeros((2, 32, spec.channels), np.float32)
    x[..., -1] = 1.0
    x[:, :, :spec.n_traces] = np.random.default_rng(0).normal(size=(1, 32, spec.n_traces))
    x[0, :, spec.n_traces:-1] = FAMILY.normalise(_features(angle_deg=10.0))
    x[1, :, spec.n_traces:-1] = FAMILY.normalise(_features(angle_deg=40.0))
    pred = cnn.predict(spec, graphdef, params, jnp.asarray(x))
    assert pred.theta.shape == (2, 4)
    assert not np.allclose(np.asarray(pred.mu[0]), np.asarray(pred.mu[1]))  # same profile, other scene
    with pytest.raises(ValueError, match="shape"):
        cnn.predict(spec, graphdef, params, jnp.asarray(x[..., :-1]))


def test_family_training_runs_and_saves_a_family_model(tmp_path):
    cfg = TrainConfig(family={"angle_deg": (15.0, 30.0)}, steps=3, rollouts=4, views=2, n_samples=32,
                      validation=8, log_every=3, checkpoint_every=3, width=4, hidden=8,
                      noise={"min_samples": 8, "prefix": 2})
    info = train(cfg, out=tmp_path / "fam", progress=False)
    assert info["trained_steps"] == 3
    model = json.loads((tmp_path / "fam" / "model.json").read_text())
    assert model["spec"]["family"]["angle_deg"] == [15.0, 30.0]
    assert np.isfinite(info["validation"]["loss"]) and 0 <= info["validation"]["cover90_k1"] <= 1
    with pytest.raises(Exception, match="mjx"):
        train(cfg.model_copy(update={"engine": "mjx"}), out=tmp_path / "x", progress=False)


def test_a_family_network_named_by_path_serves_its_family_and_names_an_input_out_of_range():
    """``fit --cnn-model DIR`` with a scene-conditioned network: a scene of its family gets it
    (whatever the scene's own network), one outside gets the one-line error naming the input.
    (``fit --method cnn`` end to end with the shipped family network: ``tests/test_sweep.py``'s
    10 degree video; the error on the command line: ``tests/test_cli.py``.)"""
    from galileo_jax.inference import cnn_files

    folder = cnn_files.MODELS_DIR / "family_cnn"
    scene = load_scene("scenes/ramp_20.yaml")
    assert cnn_files.find_model(scene, 30.0, folder).spec.family is not None
    steep = scene.model_copy(update={"ramp": scene.ramp.model_copy(update={"angle_deg": 60.0})})
    with pytest.raises(OutOfFamily, match=r"scene 'ramp_20': angle_deg = 60 deg is outside .* 5-45 deg") as err:
        cnn_files.find_model(steep, 30.0, folder)
    assert "\n" not in str(err.value)
    with pytest.raises(OutOfFamily, match="fps = 500"):
        cnn_files.find_model(scene, 500.0, folder)


def test_shipped_family_network_on_a_scene_without_its_own():
    """The shipped scene-conditioned network on noisy simulated videos of the 10 degree scene,
    which has no per-scene network, filmed at 60 fps (the network's grid is 30/s): k1 close, phi
    close, the truth inside most 90% intervals (measured on 1,000 family simulations,
    ``benchmarks/results/cnn_family.md``: k1 0.0026 at 5-15 degrees, 90% coverage 0.88-0.97)."""
    from galileo_jax.inference import cnn_files
    from galileo_jax.inference.problem import simulated_observation
    from galileo_jax.params import ParamSpace
    from galileo_jax.physics.simulate import PhysParams

    scene = load_scene("scenes/ramp_10.yaml")
    model = cnn_files.find_model(scene, 60.0)
    assert model.spec.family is not None and model.path.parent == cnn_files.MODELS_DIR
    space = ParamSpace.from_scene(scene)
    rng = np.random.default_rng(5)
    # k1 below tan(10 deg) = 0.176 (object 1 slides); columns k1, k2, m1, m2
    draws = np.column_stack([rng.uniform(0.02, 0.14, 6), rng.uniform(0.1, 0.5, 6), rng.uniform(0.2, 1.0, (6, 2))])
    truth = np.column_stack([draws[:, 0], draws[:, 1], (draws[:, 2] - draws[:, 3]) / (draws[:, 2] + draws[:, 3]),
                             np.zeros(6)])  # k1, k2, phi, dt_release: the network's coordinates
    assert tuple(space.names) == ("k1", "k2", "phi", "dt_release")
    ests = [cnn.estimate(model, simulated_observation(scene, PhysParams(jnp.asarray(d[2:]), jnp.asarray(d[:2])),
                                                      fps=60.0, duration=3.0, position_sd=5e-4, release_time=0.4,
                                                      seed=i),
                         space, jax.random.PRNGKey(i), features=scene_features(scene, 60.0))
            for i, d in enumerate(draws)]
    errors = np.abs(np.stack([e.theta for e in ests]) - truth)
    bounds = np.stack([e.interval90 for e in ests])
    inside = (bounds[..., 0] <= truth) & (truth <= bounds[..., 1])
    print("family CNN |error| (k1, k2, phi, dt_release):\n", np.round(errors, 4))
    assert np.median(errors[:, 0]) < 0.01
    assert np.median(errors[:, 2]) < 0.15
    assert np.mean(inside) >= 0.6
