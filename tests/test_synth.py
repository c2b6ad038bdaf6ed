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

from galileo_jax import render, synth
from galileo_jax.calibration import calibration
from galileo_jax.errors import GalileoError
from galileo_jax.model import model_index
from galileo_jax.observation import profile_from_positions
from galileo_jax.scene import load_scene
from galileo_jax.simulate import PhysParams, make_simulator, steps_needed, velocity_profile

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
    plain = synth.build_model(scene)[0]
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
])
def test_cli_bad_input_is_one_line(args, message, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    code = synth.main(args)
    err = capsys.readouterr().err.strip()
    assert code != 0
    assert err.startswith("error: ") and "\n" not in err and "Traceback" not in err
    assert message in err
    assert not list(tmp_path.rglob("*.mp4"))
