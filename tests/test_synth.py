"""Synthetic videos (galileo_jax.synth): files, calibration, and C MuJoCo against MJX.

One short low-resolution video (160 x 96 px, 45 frames at 30 fps, hand on, noise 2) is
rendered once per module; the tests check that

* the mp4 reads back with OpenCV with the truth's frame count, frame rate and size;
* the truth JSON has its fields and the written scene YAML loads with the exact calibration;
* the truth pixels are the world positions under that calibration (within 0.5 px), and the
  rendered objects' silhouettes are centred on the truth pixels (segmentation render);
* the C MuJoCo motion in the video matches the MJX simulator's velocity profile
  (measured on five parameter sets: overall RMS 0.004-0.010 m/s with MJX in float32, most of
  it float32 round-off amplified by the impact; the bound is 0.02 m/s);
* bad CLI input gives one line on stderr and a non-zero exit code.

Hidden effects (:mod:`galileo_jax.effects`): for every shipped effect with a parameter, the C
MuJoCo motion of :func:`synth.simulate_motion` matches the MJX rollout with the same effect
(RMS bound :data:`EFFECT_RMS_TOL`) and differs clearly from the base model; the ``rolling``
effect gives the rolling acceleration g sin(theta) / (1 + alpha); a rendered video with a hidden
effect has it in its truth and not in its scene file; random draws with effects are
informative; bad ``--effect`` options give one line.

Looks, cameras and blur (:func:`synth.render_video`'s ``look``, ``colours``, ``camera``,
``direction``, ``blur``, ``backdrop``): in perspective, seen from either side, each object's
segmentation mask fills the convex hull of ``View.project`` of its 8 box corners; the written
calibration maps the truth positions to the truth pixels for left and right perspective
views; the near faces (``pixels_front``) look larger by D / (D - w/2); the physics-step states
hold the frames exactly and ``pixels_exposure`` is the mean of the sub-frames' projected
centres; blur changes moving frames only; a plain object is one colour, a checker one is not;
the cluttered backdrop is seeded and visual only; bad look/camera/blur options give one line.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from galileo_jax import render, synth, textures
from galileo_jax.calibration import calibration
from galileo_jax.effects import get_effect
from galileo_jax.effects.runtime import has_step_hooks
from galileo_jax.errors import GalileoError
from galileo_jax.observation import profile_from_positions
from galileo_jax.physics.model import WorldPhysics, build_model, model_index
from galileo_jax.physics.simulate import PhysParams, make_simulator, scene_effects, steps_needed, velocity_profile
from galileo_jax.scene import load_scene, scene_from_dict

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "ramp_20.yaml"
PARAMS = {"m1": 0.6, "k1": 0.2, "m2": 0.3, "k2": 0.25}
FPS, DURATION, REST, W, H = 30.0, 1.5, 6, 160, 96
#: Bound on the overall RMS difference (m/s) of the C and MJX velocity profiles.
PROFILE_RMS_TOL = 0.02


@pytest.fixture(scope="module")
def scene():
    return load_scene(SCENE)


@pytest.fixture(scope="module")
def video(scene, tmp_path_factory):
    path = tmp_path_factory.mktemp("synth") / "clip.mp4"
    truth = synth.render_video(scene, PARAMS, path, fps=FPS, duration=DURATION, width=W, height=H,
                               noise_sd=2.0, hand=True, rest_frames=REST, seed=3, progress=False)
    return path, truth


def test_mp4_reads_back(video):
    path, truth = video
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame)
    fps = cap.get(cv2.CAP_PROP_FPS)
    cap.release()
    assert len(frames) == truth["n_frames"] == round(DURATION * FPS)
    assert fps == pytest.approx(FPS, rel=1e-4)
    assert frames[0].shape == (H, W, 3)
    # The objects move between the first and last frame (pixels change around object 1).
    u, v = (int(round(c)) for c in truth["pixels"][0][0])
    assert np.abs(frames[0][v - 3:v + 4, u - 3:u + 4].astype(int) - frames[-1][v - 3:v + 4, u - 3:u + 4]).mean() > 10


def test_truth_fields(video, scene):
    path, truth = video
    on_disk = json.loads(path.with_suffix(".truth.json").read_text())
    assert on_disk == truth
    for key in ("m1", "k1", "m2", "k2", "phi", "fps", "release_time", "n_frames", "width", "height",
                "noise_sd", "hand", "seed", "pixels", "positions"):
        assert key in truth, key
    assert truth["phi"] == pytest.approx((0.6 - 0.3) / 0.9)
    assert truth["release_time"] == pytest.approx(REST / FPS)
    assert (truth["width"], truth["height"], truth["hand"], truth["noise_sd"]) == (W, H, True, 2.0)
    n = truth["n_frames"]
    assert np.shape(truth["pixels"]) == (n, scene.n_objects, 2)
    assert np.shape(truth["positions"]) == (n, scene.n_objects, 2)
    assert truth["moved"] == [True, True]  # object 1 slid and hit object 2


def test_one_object_truth_has_only_its_parameters(tmp_path):
    one = load_scene(SCENE).model_copy(update={"objects": load_scene(SCENE).objects[:1]})
    truth = synth.render_video(one, {"m1": 0.4, "k1": 0.1}, tmp_path / "one.mp4", duration=0.5, width=64,
                               height=48, noise_sd=0.0, rest_frames=3, progress=False)
    assert {"m1", "k1"} <= truth.keys() and not {"m2", "k2", "phi"} & truth.keys()
    assert (tmp_path / "one.yaml").is_file()


def test_written_calibration_maps_world_to_truth_pixels(video):
    path, truth = video
    written = load_scene(path.with_suffix(".yaml"))
    cam = written.camera
    assert cam.ramp_direction == "right" and cam.roll_deg == 0.0 and cam.foot_pixel is not None
    cal = calibration(cam)
    px = cal.world_to_pixel(np.asarray(truth["positions"]))
    assert np.abs(px - np.asarray(truth["pixels"])).max() < 0.5
    # The pixels move as the world positions do: displacement / scale = world displacement.
    dpx = np.diff(np.asarray(truth["pixels"]), axis=0)
    dw = np.diff(np.asarray(truth["positions"]), axis=0)
    np.testing.assert_allclose(cal.displacement_to_world(dpx), dw, atol=0.5 / cam.scale)


def test_rendered_silhouettes_centred_on_truth_pixels(scene):
    """Segmentation render (no hand, 320 x 192 px): silhouette centroids vs the exact calibration."""
    phys = synth.resolve_params(scene, PARAMS)
    motion = synth.simulate_motion(scene, phys, FPS, REST, round(DURATION * FPS))
    view = render.frame_view(scene, motion.positions, 2 * W, 2 * H)
    model = render.build_render_model(scene, view, 1.0 / 240.0)
    geoms = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"object{i + 1}") for i in range(scene.n_objects)]
    data = mujoco.MjData(model)
    renderer = mujoco.Renderer(model, view.height, view.width)
    renderer.enable_segmentation_rendering()
    truth = view.world_to_pixel(motion.positions)
    gap = np.abs(motion.positions[:, 0, 0] - motion.positions[:, 1, 0]) - 0.5 * sum(o.length for o in scene.objects)
    errors = []
    try:
        # Frames with the objects in contact are left out: at impact the soft contact lets
        # them overlap by a fraction of a millimetre and one hides part of the other.
        for k in np.flatnonzero(gap > 0.005)[::2]:
            data.qpos[:] = motion.qpos[k]
            mujoco.mj_kinematics(model, data)
            mujoco.mj_camlight(model, data)
            renderer.update_scene(data, camera=render.CAMERA)
            seg = renderer.render()
            for j, g in enumerate(geoms):
                v, u = np.nonzero((seg[:, :, 0] == g) & (seg[:, :, 1] == mujoco.mjtObj.mjOBJ_GEOM))
                errors.append([u.mean() - truth[k, j, 0], v.mean() - truth[k, j, 1]])
    finally:
        renderer.close()
    assert np.abs(np.asarray(errors)).max() < 0.5  # measured 0.29 px at 320 x 192


def test_render_model_keeps_the_physics_layout(scene):
    view = render.View((0.0, 0.1), 200.0, 64, 48)
    plain = build_model(scene)[0]
    fancy = render.build_render_model(scene, view, 1.0 / 240.0, hand=True)
    assert model_index(fancy, 2).qpos == model_index(plain, 2).qpos
    assert fancy.nq == plain.nq and fancy.nv == plain.nv and fancy.npair == plain.npair
    assert fancy.nmocap == 1


def test_c_mujoco_matches_mjx_profile(video, scene):
    _, truth = video
    sim = make_simulator(scene, FPS)
    times = np.arange(truth["n_frames"]) / FPS
    params = PhysParams(jnp.asarray([PARAMS["m1"], PARAMS["m2"]]), jnp.asarray([PARAMS["k1"], PARAMS["k2"]]))
    mjx_profile = np.asarray(jax.jit(lambda p: velocity_profile(sim, p, jnp.asarray(times), truth["release_time"],
                                                                steps_needed(sim, times[-1])))(params))
    c_profile = profile_from_positions(np.asarray(truth["positions"]), times)
    assert c_profile.shape == mjx_profile.shape
    rms = math.sqrt(float(np.mean((c_profile - mjx_profile) ** 2)))
    assert rms < PROFILE_RMS_TOL, rms
    assert np.abs(c_profile[0]).max() > 0.5  # object 1 really slid (m/s)


def test_random_draws_let_object_1_slide(scene):
    rng = np.random.default_rng(0)
    tan = math.tan(scene.ramp.angle)
    for _ in range(200):
        p = synth.draw_random_params(scene, rng, fixed={"m2": 0.3})
        assert set(p) == {"m1", "k1", "m2", "k2"} and p["m2"] == 0.3
        assert 0 < p["k1"] < tan - synth.SLIDE_MARGIN and 0 < p["m1"] <= 1 and 0 < p["k2"] < 1


def test_resolve_params_errors(scene):
    with pytest.raises(GalileoError, match="m2 is free"):
        synth.resolve_params(scene, {"m1": 0.5, "k1": 0.1, "k2": 0.1})
    with pytest.raises(GalileoError, match="k1"):
        synth.resolve_params(scene, {"m1": 0.5, "k1": -0.1, "m2": 0.5, "k2": 0.1})
    with pytest.raises(GalileoError, match="unknown parameter"):
        synth.resolve_params(scene, {"m3": 0.5})
    known = scene.model_copy(update={"objects": [scene.objects[0], scene.objects[1].model_copy(update={"mass": 0.2})]})
    assert synth.resolve_params(known, {"m1": 0.5, "k1": 0.1, "k2": 0.1}).mass[1] == 0.2
    with pytest.raises(GalileoError, match="contradicts"):
        synth.resolve_params(known, {"m1": 0.5, "k1": 0.1, "m2": 0.3, "k2": 0.1})


@pytest.mark.parametrize("args, message", [
    (["--scene", "no/such/scene.yaml", "--out", "x.mp4"], "not found"),
    (["--scene", str(SCENE), "--m1", "0.5", "--k1", "0.1", "--m2", "0.5", "--out", "x.mp4"], "k2 is free"),
    (["--scene", str(SCENE), "--m1", "-1", "--k1", "0.1", "--m2", "0.5", "--k2", "0.1", "--out", "x.mp4"], "m1"),
    (["--scene", str(SCENE), "--m1", "abc", "--out", "x.mp4"], "invalid float"),
    (["--scene", str(SCENE), "--random", "2", "--out", "x.mp4"], "folder"),
    (["--scene", str(SCENE), "--random", "1", "--fps", "0", "--out", "d"], "--fps"),
    (["--scene", str(SCENE), "--random", "1", "--ramp-thickness", "0.5", "--out", "d"], "--ramp-thickness"),
    (["--scene", str(SCENE), "--random", "1", "--cone", "round", "--out", "d"], "--cone"),
])
def test_cli_bad_input_is_one_line(args, message, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    code = synth.main(args)
    err = capsys.readouterr().err.strip()
    assert code != 0
    assert err.startswith("error: ") and "\n" not in err and "Traceback" not in err
    assert message in err
    assert not list(tmp_path.rglob("*.mp4"))


# --------------------------------------------------------------------------- physics the model lacks
def test_world_physics_board_and_elliptic_cone(scene):
    """A ramp board 15 mm thick lifts object 1 by its thickness along the ramp's normal; on it
    object 1 slides with the closed-form a = g (sin - k cos) (the elliptic cone is Coulomb's
    exact one), then drops over the board's edge to the floor (centre at h / 2 again)."""
    t, th, k = 0.015, scene.ramp.angle, PARAMS["k1"]
    phys = synth.resolve_params(scene, PARAMS)
    world = WorldPhysics(cone="elliptic", ramp_thickness=t)
    plain = synth.simulate_motion(scene, phys, 240.0, 3, n_frames=40)
    board = synth.simulate_motion(scene, phys, 240.0, 3, n_frames=400, world=world)
    lift = board.positions[0, 0] - plain.positions[0, 0]
    np.testing.assert_allclose(lift, [t * math.sin(th), t * math.cos(th)], atol=1e-4)
    s = np.linalg.norm(board.positions[:, 0] - board.positions[0, 0], axis=-1)
    tt = np.arange(len(s)) / 240.0
    sliding = (s > 0.005) & (s < 0.25)
    accel = 2.0 * np.polyfit(tt[sliding], s[sliding], 2)[0]
    expected = scene.gravity * (math.sin(th) - k * math.cos(th))
    assert accel == pytest.approx(expected, rel=0.02)
    h = scene.objects[0].height
    assert board.positions[-1, 0, 1] == pytest.approx(h / 2, abs=1e-3)  # on the floor, past the edge
    assert np.max(board.positions[:, 0, 0]) > 0.05
    with pytest.raises(ValueError, match="cone"):
        WorldPhysics(cone="round")


# --------------------------------------------------------------------------- hidden effects
#: Value of each shipped effect's parameter in the C-vs-MJX tests (inside its synth range;
#: restitution at 0.6, below the e >= 0.7 where MJX in float32 departs from C MuJoCo).
EFFECT_VALUES = {"quadratic_drag": 1.05, "linear_drag": 1.2, "restitution": 0.6, "ramp_friction": 0.09,
                 "initial_push": 0.375, "velocity_friction": 0.3}
#: Frames (30 fps) of the C-vs-MJX effect tests: 3 at rest, then 1.2 s of motion.
EFFECT_FRAMES, EFFECT_REST = 39, 3
#: Bound on the RMS difference (m/s) of the C and MJX velocity profiles with an effect. Measured
#: on ramp_20 with three base parameter sets x (low, mid, high) of each synth range (restitution
#: only up to 0.6): 0.0001-0.015 m/s, MJX in float32 (float64 MJX: < 0.005, 0 without impact).
EFFECT_RMS_TOL = 0.025


def _rms(a, b) -> float:
    return math.sqrt(float(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


@pytest.mark.parametrize("name", sorted(EFFECT_VALUES))
def test_effect_c_mujoco_matches_mjx(scene, name):
    """simulate_motion with an effect (C MuJoCo, c_step hooks) against the MJX rollout with the
    same effect and value; the effect must also change the profile far more than the tolerance."""
    effect = get_effect(name)
    params = {**PARAMS, effect.params[0].name: EFFECT_VALUES[name]}
    phys = synth.resolve_params(scene, params, [name])
    assert phys.effects is not None and phys.effects.shape == (1,)
    times = np.arange(EFFECT_FRAMES) / FPS
    motion = synth.simulate_motion(scene, phys, FPS, EFFECT_REST, EFFECT_FRAMES, effects=[name])
    c_profile = profile_from_positions(motion.positions, times)
    base = synth.simulate_motion(scene, synth.resolve_params(scene, PARAMS), FPS, EFFECT_REST, EFFECT_FRAMES)
    base_profile = profile_from_positions(base.positions, times)
    sim = make_simulator(scene, FPS, scene_effects(scene, [name]))
    p = PhysParams(jnp.asarray(phys.mass), jnp.asarray(phys.friction), jnp.asarray(phys.effects))
    mjx_profile = np.asarray(jax.jit(lambda q: velocity_profile(sim, q, jnp.asarray(times), motion.release_time,
                                                                steps_needed(sim, times[-1])))(p))
    assert c_profile.shape == mjx_profile.shape
    rms = _rms(c_profile, mjx_profile)
    assert rms < EFFECT_RMS_TOL, (name, rms)
    assert _rms(c_profile, base_profile) > 3 * EFFECT_RMS_TOL, name  # measured 0.09-0.24 m/s
    if not has_step_hooks([effect]):  # the fit's C engine (hooks in JAX, rollouts on the host)
        c_sim = make_simulator(scene, FPS, scene_effects(scene, [name]), "mujoco")
        engine_profile = np.asarray(jax.jit(lambda q: velocity_profile(
            c_sim, q, jnp.asarray(times), motion.release_time, steps_needed(c_sim, times[-1])))(p))
        assert _rms(engine_profile, c_profile) < 1e-9, (name, _rms(engine_profile, c_profile))
    # The values may also come as a dict or through effect_values; the neutral value is the base model.
    same = synth.simulate_motion(scene, synth.resolve_params(scene, PARAMS), FPS, EFFECT_REST, EFFECT_FRAMES,
                                 effects=[name], effect_values={effect.params[0].name: EFFECT_VALUES[name]})
    np.testing.assert_array_equal(same.qpos, motion.qpos)
    neutral = synth.simulate_motion(scene, synth.resolve_params(scene, PARAMS), FPS, EFFECT_REST, EFFECT_FRAMES,
                                    effects=[name])
    assert _rms(profile_from_positions(neutral.positions, times), base_profile) < 1e-6


def _rolling_scene(friction: float):
    r = 0.03
    return scene_from_dict({
        "name": "roll10", "ramp": {"angle_deg": 10, "length": 0.8}, "floor": {"length": 1.0},
        "objects": [{"shape": "box", "size": [0.06, 0.1, 2 * r], "start": 0.6, "friction": friction, "mass": 0.4,
                     "rolling": {"radius": r, "inertia_ratio": 0.5}}],
        "camera": {"pixels_per_metre": 500}})


def _slope_acceleration(scene, effects):
    """(acceleration along the slope in m/s^2 while object 1 is on the ramp, distance travelled in m)."""
    th = scene.ramp.angle
    motion = synth.simulate_motion(scene, synth.resolve_params(scene, {}), FPS, 1, 31, effects=effects)
    x = motion.positions[:, 0, 0]
    s = (x - x[0]) / math.cos(th)  # distance down the slope
    t = motion.frame_times - motion.release_time
    on = (t >= 0) & (x < -0.03)
    return 2.0 * np.polyfit(t[on], s[on], 2)[0], s[-1]


@pytest.mark.parametrize("friction", [0.5, 0.1])
def test_rolling_acceleration(friction):
    """A box declared round (rolling: r = h/2, I = 0.5 m r^2) on a 10 degree ramp: with the
    rolling effect it rolls at g sin / (1 + 0.5) (measured 1.1351 vs 1.1357 m/s^2 at k = 0.5);
    without it, it stays put (k = 0.5 > tan 10 deg) or slides at g (sin - k cos) (k = 0.1)."""
    scene = _rolling_scene(friction)
    g, th = scene.gravity, scene.ramp.angle
    a_roll, _ = _slope_acceleration(scene, ["rolling"])
    assert a_roll == pytest.approx(g * math.sin(th) / 1.5, rel=0.03)
    a_slide, travel = _slope_acceleration(scene, [])
    if friction > math.tan(th):
        assert abs(travel) < 2e-3 and abs(a_slide) < 0.01
    else:
        assert a_slide == pytest.approx(g * (math.sin(th) - friction * math.cos(th)), rel=0.03)


def test_render_model_draws_structural_effects():
    scene = _rolling_scene(0.5)
    view = render.View((0.0, 0.1), 200.0, 64, 48)
    plain = render.build_render_model(scene, view, 1.0 / 240.0)
    rolling = render.build_render_model(scene, view, 1.0 / 240.0, effects=["rolling"])
    gid = mujoco.mj_name2id(rolling, mujoco.mjtObj.mjOBJ_GEOM, "object1")
    assert plain.geom_type[gid] == mujoco.mjtGeom.mjGEOM_BOX
    assert rolling.geom_type[gid] == mujoco.mjtGeom.mjGEOM_CYLINDER
    assert rolling.geom_size[gid][0] == pytest.approx(0.03) and rolling.nq == plain.nq


def test_render_video_with_hidden_effect(scene, tmp_path):
    """mp4 + yaml + truth: the effect is in the truth (by effect and at top level), not in the yaml."""
    params = {**PARAMS, "drag_quadratic": 0.9}
    path = tmp_path / "drag.mp4"
    truth = synth.render_video(scene, params, path, fps=FPS, duration=1.0, width=160, height=90, noise_sd=0.0,
                               rest_frames=3, progress=False, effects=["quadratic_drag"])
    assert path.is_file() and path.with_suffix(".yaml").is_file()
    assert json.loads(path.with_suffix(".truth.json").read_text()) == truth
    assert truth["effects"] == {"quadratic_drag": {"drag_quadratic": 0.9}}
    assert truth["drag_quadratic"] == 0.9 and truth["hidden_effects"] == ["quadratic_drag"]
    text = path.with_suffix(".yaml").read_text()
    assert "drag" not in text and "effects" not in text
    assert load_scene(path.with_suffix(".yaml")).effects == []
    # The video shows the motion with drag, not the base motion.
    with_drag = synth.simulate_motion(scene, synth.resolve_params(scene, params, ["quadratic_drag"]), FPS, 3, 30,
                                      effects=["quadratic_drag"])
    base = synth.simulate_motion(scene, synth.resolve_params(scene, PARAMS), FPS, 3, 30)
    np.testing.assert_allclose(truth["positions"], with_drag.positions, atol=1e-6)
    assert np.abs(np.asarray(truth["positions"]) - base.positions).max() > 0.01


def test_scene_own_effects_stay_in_yaml(tmp_path):
    """A scene that lists its own effect keeps it in the written yaml; only extra ones are hidden."""
    scene = _rolling_scene(0.5).model_copy(update={"effects": ["rolling"]})
    path = tmp_path / "roll.mp4"
    truth = synth.render_video(scene, {"drag_linear": 0.5}, path, fps=FPS, duration=0.5, width=64, height=48,
                               noise_sd=0.0, rest_frames=1, progress=False, effects=["linear_drag"])
    assert truth["effects"] == {"rolling": {}, "linear_drag": {"drag_linear": 0.5}}
    assert truth["hidden_effects"] == ["linear_drag"]
    assert load_scene(path.with_suffix(".yaml")).effects == ["rolling"]
    assert truth["moved"] == [True]  # it rolls (k = 0.5 would hold a sliding box)


def test_truth_of_base_video_has_no_effects(video):
    _, truth = video
    assert truth["effects"] == {} and truth["hidden_effects"] == []


def test_resolve_params_effect_errors(scene):
    with pytest.raises(GalileoError, match="needs a value of drag_quadratic"):
        synth.resolve_params(scene, PARAMS, ["quadratic_drag"])
    with pytest.raises(GalileoError, match="effect 'quadratic_drag', which is not simulated"):
        synth.resolve_params(scene, {**PARAMS, "drag_quadratic": 0.9})
    with pytest.raises(GalileoError, match="unknown parameter 'drag'"):
        synth.resolve_params(scene, {**PARAMS, "drag": 0.9}, ["quadratic_drag"])
    with pytest.raises(GalileoError, match="outside the effect's range"):
        synth.resolve_params(scene, {**PARAMS, "drag_quadratic": 9.0}, ["quadratic_drag"])
    with pytest.raises(GalileoError, match="unknown effect"):
        synth.resolve_params(scene, PARAMS, ["quadratic_dra"])
    p = synth.resolve_params(scene, {**PARAMS, "drag_quadratic": 0.9, "v0": 0.3}, ["quadratic_drag", "initial_push"])
    np.testing.assert_array_equal(p.effects, [0.9, 0.3])
    assert synth.resolve_params(scene, PARAMS).effects is None


def test_random_effect_draws_are_informative(scene):
    """ramp_friction on the 10 degree ramp: k1 + dk_ramp < tan(theta) - margin, and object 2 is hit."""
    ramp10 = load_scene(SCENE.parent / "ramp_10.yaml")
    rng = np.random.default_rng(1)
    lo, hi = get_effect("ramp_friction").params[0].synth_range
    for _ in range(3):
        p = synth.draw_informative_params(ramp10, rng, ["ramp_friction"], fps=FPS, rest_frames=3, n_frames=60)
        assert lo <= p["dk_ramp"] <= hi
        assert p["k1"] + p["dk_ramp"] < math.tan(ramp10.ramp.angle) - synth.SLIDE_MARGIN
        motion = synth.simulate_motion(ramp10, synth.resolve_params(ramp10, p, ["ramp_friction"]), FPS, 3, 60,
                                       effects=["ramp_friction"])
        assert synth.degenerate_motion(ramp10, motion) is None
    # A fixed friction that holds object 1 on the ramp: no informative draw, one clear error.
    with pytest.raises(GalileoError, match="no random draw"):
        synth.draw_informative_params(ramp10, rng, ["ramp_friction"], fps=FPS, rest_frames=3, n_frames=60,
                                      fixed={"k1": 0.15}, fixed_effects={"dk_ramp": 0.1}, attempts=3)


def test_random_velocity_friction_draws_keep_friction_at_rest(scene):
    """The centred velocity friction k + s (|v| - v_ref) is lower at rest: draws whose friction at
    rest falls below MIN_REST_FRICTION (resting objects would drift) are thrown away."""
    from galileo_jax.effects.library import VELOCITY_FRICTION_REF

    rng = np.random.default_rng(3)
    for _ in range(3):
        p = synth.draw_informative_params(scene, rng, ["velocity_friction"], fps=FPS, rest_frames=3, n_frames=60)
        rest = [p[f"k{i}"] - p["dk_dv"] * VELOCITY_FRICTION_REF for i in (1, 2)]
        assert min(rest) >= synth.MIN_REST_FRICTION, p
        k_rest = synth.frictions_at_rest(scene, scene_effects(scene, ["velocity_friction"]), p,
                                         [p["k1"], p["k2"]])
        np.testing.assert_allclose(k_rest, np.repeat(np.array(rest)[:, None], 2, axis=1), atol=1e-6)


def test_cli_random_with_effect(tmp_path, capsys):
    out = tmp_path / "out"
    code = synth.main(["--scene", str(SCENE), "--random", "2", "--effect", "quadratic_drag", "--out", str(out),
                       "--width", "64", "--height", "48", "--duration", "1.5", "--noise", "0", "--quiet"])
    assert code == 0
    truths = [json.loads(p.read_text()) for p in sorted(out.glob("*.truth.json"))]
    assert len(truths) == 2
    lo, hi = get_effect("quadratic_drag").params[0].synth_range
    for t in truths:
        assert lo <= t["drag_quadratic"] <= hi and t["hidden_effects"] == ["quadratic_drag"]
        assert t["moved"] == [True, True]
    assert truths[0]["drag_quadratic"] != truths[1]["drag_quadratic"]
    assert "drag_quadratic=" in capsys.readouterr().out
    code = synth.main(["--scene", str(SCENE), *sum([["--" + k, str(v)] for k, v in PARAMS.items()], []),
                       "--effect", "none", "--out", str(tmp_path / "none.mp4"), "--width", "64", "--height", "48",
                       "--duration", "0.5", "--quiet"])
    assert code == 0 and json.loads((tmp_path / "none.truth.json").read_text())["effects"] == {}


@pytest.mark.parametrize("option, message", [
    (["--effect", "foo"], "unknown effect 'foo'"),
    (["--effect", "quadratic_drag"], "needs a value"),
    (["--effect", "quadratic_drag=abc"], "not a number"),
    (["--effect", "quadratic_drag=1,2"], "takes 1 value"),
    (["--effect", "quadratic_drag=9"], "outside the effect's range"),
    (["--effect", "rolling"], "does not apply"),
    (["--effect", "rolling=1"], "has no parameter"),
    (["--effect", "none", "--effect", "linear_drag=1"], "none"),
    (["--effect", "linear_drag=1", "--effect", "linear_drag=2"], "twice"),
    (["--camera", "fisheye"], "invalid choice"),
    (["--look", "shiny"], "invalid choice"),
    (["--blur", "-1"], "--blur -1"),
    (["--blur", "2.5"], "invalid int"),
    (["--shutter", "0"], "--shutter"),
    (["--colour", "2,0,0"], "colour 2,0,0"),
    (["--colour", "1,0"], "R,G,B"),
    (["--colour", "1,0,0"], "one R,G,B per object"),
    (["--camera", "perspective", "--distance", "0.1"], "--distance"),
    (["--left", "--direction", "right"], "contradicts"),
])
def test_cli_bad_option_is_one_line(option, message, tmp_path, monkeypatch, capsys):
    """Bad --effect, look, camera and blur options: one line on stderr, no video."""
    monkeypatch.chdir(tmp_path)
    args = ["--scene", str(SCENE), *sum([["--" + k, str(v)] for k, v in PARAMS.items()], []), "--out", "x.mp4",
            "--width", "64", "--height", "48", "--duration", "0.5", *option]
    code = synth.main(args)
    err = capsys.readouterr().err.strip()
    assert code != 0
    assert err.startswith("error: ") and "\n" not in err and "Traceback" not in err
    assert message in err
    assert not list(tmp_path.rglob("*.mp4"))


# --------------------------------------------------------------------------- looks, cameras, blur
#: Options of the "world-like" video: perspective (a near camera, so that depth shows), plain
#: objects, seen from behind (object 1 moves left), motion blur, cluttered backdrop.
WORLD = dict(look="plain", camera="perspective", camera_distance=1.0, direction="left", blur=3, shutter=0.8,
             backdrop="clutter")


@pytest.fixture(scope="module")
def motion(scene):
    return synth.simulate_motion(scene, synth.resolve_params(scene, PARAMS), FPS, REST, round(DURATION * FPS))


@pytest.fixture(scope="module")
def world_video(scene, tmp_path_factory):
    path = tmp_path_factory.mktemp("world") / "world.mp4"
    truth = synth.render_video(scene, PARAMS, path, fps=FPS, duration=DURATION, width=W, height=H, noise_sd=0.0,
                               hand=True, rest_frames=REST, seed=3, progress=False, **WORLD)
    return path, truth


def _segment(model, view, qpos, names):
    """Boolean masks (len(names), H, W) of the named geoms in a segmentation render at ``qpos``."""
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    mujoco.mj_camlight(model, data)
    renderer = mujoco.Renderer(model, view.height, view.width)
    try:
        renderer.enable_segmentation_rendering()
        renderer.update_scene(data, camera=render.CAMERA)
        seg = renderer.render()
    finally:
        renderer.close()
    ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, n) for n in names]
    return np.stack([(seg[:, :, 0] == g) & (seg[:, :, 1] == mujoco.mjtObj.mjOBJ_GEOM) for g in ids])


def _box_corners(scene, i):
    """(8, 3) corners of box object ``i`` in its body frame (m)."""
    half = np.asarray(scene.objects[i].size) / 2
    return np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)]) * half


@pytest.mark.parametrize("direction", ["right", "left"])
def test_perspective_silhouettes_fill_projected_boxes(scene, motion, direction):
    """Perspective camera 1 m away (320 x 192 px): each object's segmentation mask lies inside the
    convex hull of View.project of its 8 box corners (grown by 1 px) and covers most of it."""
    view = render.frame_view(scene, motion.positions, 2 * W, 2 * H, projection="perspective", distance=1.0,
                             direction=direction)
    model = render.build_render_model(scene, view, 1.0 / 240.0, look="plain")
    gap = np.abs(motion.positions[:, 0, 0] - motion.positions[:, 1, 0]) - 0.5 * sum(o.length for o in scene.objects)
    for k in (0, int(np.flatnonzero(gap > 0.005)[-1])):
        masks = _segment(model, view, motion.qpos[k], ["object1", "object2"])
        for i, mask in enumerate(masks):
            corners = np.stack([render.body_points(motion.qpos[k], motion.qpos_adr,
                                                   np.broadcast_to(c, (scene.n_objects, 3)))[i]
                                for c in _box_corners(scene, i)])
            hull = cv2.convexHull(view.project(corners).astype(np.float32))
            v, u = np.nonzero(mask)
            inside = [cv2.pointPolygonTest(hull, (float(a), float(b)), True) for a, b in zip(u, v)]
            assert min(inside) > -1.0, (k, i, min(inside))  # measured >= 0 (ortho corners: -2.5 to -4 px)
            # Mask area = hull area within 0.15 px times the perimeter (measured 0.08; corners
            # projected from 1.3 m instead of 1 m: 0.23 to 0.31).
            area = cv2.contourArea(hull)
            assert abs(mask.sum() - area) < 0.15 * cv2.arcLength(hull, True), (k, i)


@pytest.mark.parametrize("direction", ["right", "left"])
def test_perspective_calibration_maps_world_to_truth_pixels(scene, tmp_path, direction):
    path = tmp_path / "p.mp4"
    truth = synth.render_video(scene, PARAMS, path, fps=FPS, duration=0.6, width=96, height=64, noise_sd=0.0,
                               rest_frames=2, progress=False, camera="perspective", direction=direction)
    cam = load_scene(path.with_suffix(".yaml")).camera
    assert cam.ramp_direction == direction and cam.pixels_per_metre == truth["pixels_per_metre"]
    px = calibration(cam).world_to_pixel(np.asarray(truth["positions"]))
    assert np.abs(px - np.asarray(truth["pixels"])).max() < 0.5
    # Object 1 moves to the image's right or left.
    du = truth["pixels"][-1][0][0] - truth["pixels"][0][0][0]
    assert du * (1 if direction == "right" else -1) > 5
    view = render.View((0.0, 0.0), truth["pixels_per_metre"], 96, 64, "perspective", 2.2, direction)
    assert truth["camera"] == {"projection": "perspective", "distance_m": 2.2, "fovy_deg": pytest.approx(view.fovy),
                               "direction": direction}


def test_world_video_truth_and_scene(world_video, scene):
    path, truth = world_video
    assert json.loads(path.with_suffix(".truth.json").read_text()) == truth
    assert {k: truth[k] for k in ("look", "blur", "shutter", "backdrop")} == {
        k: WORLD[k] for k in ("look", "blur", "shutter", "backdrop")}
    assert truth["camera"]["projection"] == "perspective" and truth["camera"]["direction"] == "left"
    assert truth["colours"] == [list(c[:3]) for c in render.OBJECT_COLOURS]
    n = truth["n_frames"]
    for key in ("pixels", "pixels_front", "pixels_exposure", "pixels_silhouette"):
        assert np.shape(truth[key]) == (n, scene.n_objects, 2), key
    written = load_scene(path.with_suffix(".yaml"))
    assert written.camera.ramp_direction == "left"
    px = calibration(written.camera).world_to_pixel(np.asarray(truth["positions"]))
    assert np.abs(px - np.asarray(truth["pixels"])).max() < 0.5
    # The near faces (1 m away, 3 cm nearer) sit 3 % further from the optical axis than the centres.
    axis = np.array([W / 2 - 0.5, H / 2 - 0.5])
    ratio = np.linalg.norm(np.asarray(truth["pixels_front"]) - axis, axis=-1) / np.linalg.norm(
        np.asarray(truth["pixels"]) - axis, axis=-1)
    far = np.linalg.norm(np.asarray(truth["pixels"]) - axis, axis=-1) > 5
    np.testing.assert_allclose(ratio[far], 1.0 / 0.97, rtol=1e-3)


def test_orthographic_front_pixels_are_the_centres(video):
    _, truth = video
    np.testing.assert_allclose(truth["pixels_front"], truth["pixels"], atol=1e-3)
    np.testing.assert_allclose(truth["pixels_silhouette"], truth["pixels"], atol=1e-3)  # a box's outline is symmetric
    assert "pixels_exposure" not in truth and truth["blur"] == 0
    assert truth["camera"] == {"projection": "orthographic", "distance_m": None, "fovy_deg": None, "direction": "right"}


@pytest.mark.parametrize("shape, size", [("box", [0.06, 0.05, 0.04]), ("cylinder", [0.03, 0.05]), ("sphere", [0.03])])
def test_silhouette_of_a_convex_object_against_its_closed_form(shape, size):
    """The silhouette (convex hull of the projected outline points) of an object: centred on the
    optical axis, its centroid is the axis in both projections; its area is the orthographic
    cross-section (box: length x height, cylinder: 2 r x height, sphere: pi r^2), and in
    perspective at least that (a box's: its near face's, magnified by D / (D - depth)); off the axis, a
    perspective camera sees the side facing the axis too, so the centroid sits nearer the axis
    than the near face's centre."""
    base = load_scene(SCENE)
    sc = base.model_copy(update={"objects": [base.objects[0].model_copy(update={"shape": shape, "size": size})]})
    local = render.outline_points(sc, 0)
    D, f = 2.0, 500.0
    ortho = render.View((0.0, 0.0), f, 640, 480)
    persp = render.View((0.0, 0.0), f, 640, 480, "perspective", D)
    axis = np.array([319.5, 239.5])
    c, a = render.silhouettes(ortho, local)
    np.testing.assert_allclose(c, axis, atol=0.02)  # (round outlines: polygons of 48 points)
    extent = {"box": lambda: size[0] * size[2], "cylinder": lambda: 2 * size[0] * size[1],
              "sphere": lambda: math.pi * size[0] ** 2}[shape]()
    assert a == pytest.approx(extent * f * f, rel=0.01)
    c, a = render.silhouettes(persp, local)
    np.testing.assert_allclose(c, axis, atol=0.02)
    half_depth = size[1] / 2 if shape == "box" else 0.0  # a round object's outline: its tangents, not its near side
    assert a >= extent * f * f * (D / (D - half_depth)) ** 2 * 0.99
    if shape == "box":  # 0.4 m right of the axis: the side facing the axis shows (about 5 px wide)
        off = np.array([0.4, 0.0, 0.0])
        c, _ = render.silhouettes(persp, local + off)
        front = persp.project(off + np.array([0.0, -half_depth, 0.0]))
        assert front[0] - 3.0 < c[0] < front[0] - 1.0


def test_motion_steps_hold_the_frames(motion, scene):
    """Per physics step qpos: row (k - release) * substeps is frame k; qpos_at the frame times is qpos."""
    sub = scene.simulation.substeps
    assert motion.substeps == sub and motion.steps.shape[0] == (motion.n_frames - REST) * sub + 1
    for k in range(REST, motion.n_frames):
        np.testing.assert_array_equal(motion.steps[(k - REST) * sub], motion.qpos[k])
    np.testing.assert_array_equal(motion.qpos_at(motion.frame_times), motion.qpos)
    times = synth.exposure_times(motion.n_frames, FPS, 4, 0.5)
    assert times.shape == (motion.n_frames, 4)
    np.testing.assert_allclose(times.mean(axis=1), motion.frame_times)
    np.testing.assert_allclose(np.ptp(times, axis=1), 0.5 * 3 / 4 / FPS)
    rest = motion.qpos_at(times[:REST])
    assert np.all(rest == motion.qpos[0])
    # between two physics steps: positions on the straight line between them, unit quaternions
    dt = 1.0 / (FPS * sub)
    j = (motion.n_frames - REST) * sub // 2  # a step while object 1 moves
    t = motion.release_time + (j + np.array([0.25, 0.5])) * dt
    between = motion.qpos_at(t)
    a, b = motion.steps[j], motion.steps[j + 1]
    adr = motion.qpos_adr[0]
    np.testing.assert_allclose(between[:, adr:adr + 3], [0.75 * a[adr:adr + 3] + 0.25 * b[adr:adr + 3],
                                                          0.5 * (a[adr:adr + 3] + b[adr:adr + 3])], atol=1e-12)
    assert np.linalg.norm(b[adr:adr + 3] - a[adr:adr + 3]) > 1e-4  # it does move in that step
    np.testing.assert_allclose(np.linalg.norm(between[:, adr + 3:adr + 7], axis=-1), 1.0, atol=1e-12)
    # sub-frames finer than the physics steps show distinct poses (a continuous streak, not copies)
    fine = motion.qpos_at(motion.release_time + (j + np.linspace(0, 1, 5)) * dt)[:, adr]
    assert np.all(np.diff(fine) != 0)


def test_blurred_exposure_pixels_lie_on_the_subframe_path(world_video, motion, scene):
    """pixels_exposure is the mean of the sub-frames' projected centres: the pixels at rest, and
    between the first and last sub-frame's pixels while moving."""
    _, truth = world_video
    cam = truth["camera"]
    view = render.frame_view(scene, motion.positions, W, H, projection=cam["projection"], distance=cam["distance_m"],
                             direction=cam["direction"])
    assert view.foot_pixel == pytest.approx(truth["foot_pixel"])
    sub = motion.qpos_at(synth.exposure_times(motion.n_frames, FPS, WORLD["blur"], WORLD["shutter"]))
    sub_px = view.project(render.body_points(sub, motion.qpos_adr, np.zeros((scene.n_objects, 3))))  # (N, S, n, 2)
    exposure, pixels = np.asarray(truth["pixels_exposure"]), np.asarray(truth["pixels"])
    np.testing.assert_allclose(exposure, sub_px.mean(axis=1), atol=1e-3)
    np.testing.assert_array_equal(exposure[:REST], pixels[:REST])
    lo, hi = sub_px.min(axis=1), sub_px.max(axis=1)
    assert np.all((exposure >= lo - 1e-3) & (exposure <= hi + 1e-3))
    assert (hi - lo).max() > 2.0  # the sub-frames really spread along the path (measured 2.9 px)


def test_blur_smears_moving_objects_only(scene, motion):
    """noise 0: a frame at rest renders the same with and without blur; a moving one does not."""
    view = render.frame_view(scene, motion.positions, W, H)
    model = render.build_render_model(scene, view, 1.0 / 240.0)
    speed = np.linalg.norm(np.gradient(motion.positions[:, 0], axis=0), axis=-1)
    frames = np.array([0, int(np.argmax(speed))])
    times = synth.exposure_times(motion.n_frames, FPS, 4, 1.0)[frames]
    sharp = list(synth.render_frames(model, view, motion.qpos[frames]))
    blurred = list(synth.render_frames(model, view, motion.qpos_at(times)))
    np.testing.assert_array_equal(sharp[0], blurred[0])
    assert np.abs(sharp[1].astype(int) - blurred[1]).max() > 50


@pytest.mark.parametrize("look, spread", [("plain", (0, 4)), ("checker", (20, 255))])
def test_object_look_colour_spread(scene, motion, look, spread):
    """Inside an object's silhouette (eroded by 2 px): a plain object is one colour (SD < 4 grey
    levels), a checker one is not; given colours are used."""
    colours = [(0.1, 0.7, 0.2), (0.7, 0.2, 0.6)]
    view = render.frame_view(scene, motion.positions, 2 * W, 2 * H)
    model = render.build_render_model(scene, view, 1.0 / 240.0, look=look, colours=colours)
    image = next(synth.render_frames(model, view, motion.qpos[:1]))[:, :, ::-1]  # RGB
    for i, mask in enumerate(_segment(model, view, motion.qpos[0], ["object1", "object2"])):
        inner = cv2.erode(mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
        assert inner.sum() > 100
        pix = image[inner].astype(float)
        assert spread[0] <= pix.std(axis=0).max() <= spread[1], (look, i)
        assert np.argmax(pix.mean(axis=0)) == np.argmax(colours[i])


def test_clutter_backdrop_is_seeded_and_visual_only(scene):
    a, b = (textures.clutter_texture(200, 120, 400.0, seed=s) for s in (1, 2))
    assert a.shape == (120, 200, 3) and a.dtype == np.uint8
    np.testing.assert_array_equal(a, textures.clutter_texture(200, 120, 400.0, seed=1))
    assert np.abs(a.astype(int) - b).mean() > 10 and a.std() > 20
    view = render.View((0.0, 0.1), 200.0, 64, 48, "perspective", 2.2, "left")
    plain = build_model(scene)[0]
    fancy = render.build_render_model(scene, view, 1.0 / 240.0, hand=True, backdrop="clutter", look="plain")
    assert model_index(fancy, 2).qpos == model_index(plain, 2).qpos and fancy.nq == plain.nq


def test_view_projection():
    """Orthographic: depth does not matter; perspective: the plane y = 0 keeps the scale, nearer
    points spread out from the optical axis; left views mirror u."""
    xz = np.array([[0.1, 0.05], [-0.2, 0.3]])
    for direction in ("right", "left"):
        ortho = render.View((0.0, 0.1), 500.0, 320, 240, direction=direction)
        persp = ortho._replace(projection="perspective", distance=2.0)
        near = np.insert(xz, 1, -ortho.sign * 0.1, axis=1)  # 0.1 m nearer the camera
        np.testing.assert_allclose(ortho.project(near), ortho.world_to_pixel(xz))
        np.testing.assert_allclose(persp.project(np.insert(xz, 1, 0.0, axis=1)), ortho.world_to_pixel(xz))
        axis = np.array([159.5, 119.5])
        np.testing.assert_allclose(persp.project(near) - axis, (ortho.world_to_pixel(xz) - axis) * 2.0 / 1.9)
        assert persp.fovy == pytest.approx(math.degrees(2 * math.atan(120 / 1000)))
    right, left = render.View((0.0, 0.1), 500.0, 320, 240), render.View((0.0, 0.1), 500.0, 320, 240, direction="left")
    np.testing.assert_allclose(right.world_to_pixel(xz)[:, 0] - 159.5, 159.5 - left.world_to_pixel(xz)[:, 0])
    assert left.camera_block().ramp_direction == "left"


def test_cli_world_options(tmp_path, capsys):
    out = tmp_path / "w.mp4"
    code = synth.main(["--scene", str(SCENE), *sum([["--" + k, str(v)] for k, v in PARAMS.items()], []),
                       "--out", str(out), "--width", "96", "--height", "64", "--duration", "0.5", "--rest", "0.1",
                       "--camera", "perspective", "--look", "plain", "--left", "--blur", "3", "--backdrop", "clutter",
                       "--colour", "0.9,0.8,0.1", "--colour", "0.1,0.2,0.9", "--quiet"])
    assert code == 0, capsys.readouterr().err
    assert out.is_file() and out.with_suffix(".yaml").is_file()
    truth = json.loads(out.with_suffix(".truth.json").read_text())
    assert (truth["look"], truth["blur"], truth["backdrop"]) == ("plain", 3, "clutter")
    assert truth["camera"]["projection"] == "perspective" and truth["camera"]["direction"] == "left"
    assert truth["colours"] == [[0.9, 0.8, 0.1], [0.1, 0.2, 0.9]] and "pixels_exposure" in truth
    assert load_scene(out.with_suffix(".yaml")).camera.ramp_direction == "left"


def test_render_video_bad_world_options(scene, tmp_path):
    for kwargs, message in [({"camera": "fisheye"}, "camera 'fisheye'"), ({"direction": "up"}, "direction 'up'"),
                            ({"backdrop": "jungle"}, "backdrop"), ({"blur": 1.5}, "--blur"),
                            ({"colours": [(0.1, 0.2)]}, "R,G,B")]:
        with pytest.raises(GalileoError, match=message):
            synth.render_video(scene, PARAMS, tmp_path / "x.mp4", duration=0.5, progress=False, **kwargs)
    assert not list(tmp_path.iterdir())
