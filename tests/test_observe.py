"""The observation stage: video reading, object finding, KLT tracking, profiles and noise.

Synthetic clips are drawn here with OpenCV: checker-textured boxes moving with known
trajectories (a box sliding down a 20 degree ramp, onto the floor, into a second box), image
noise, optional positional jitter of known SD, and a textured "hand" that covers part of
object 1 in the first frames and leaves upwards before the release; also a rolling disc.
One test tracks a MuJoCo-rendered video with a hand (``galileo_jax.synth``; skipped where
no OpenGL context can be made). All run in about 10 s.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import pytest

from galileo_jax.calibration import calibration
from galileo_jax.errors import TrackingError, VideoError
from galileo_jax.physics.model import object_start_pose
from galileo_jax.observation import profile_from_positions
from galileo_jax.observe import (clip_from_frames, estimate_noise_sd, find_objects, object_windows, observe,
                                 read_video, track_objects)
from galileo_jax.observe import video as video_module
from galileo_jax.scene import scene_from_dict

G = 9.81
FPS = 30.0
FOOT = (300.0, 240.0)


def synthetic_scene(start_pixels=None, foot=True, two=True, angle=20.0):
    cam = {"pixels_per_metre": 500.0, "ramp_direction": "right"}
    if foot:
        cam["foot_pixel"] = list(FOOT)
    if start_pixels is not None:
        cam["start_pixels"] = [list(map(float, p)) for p in start_pixels]
    objects = [{"shape": "box", "size": [0.10, 0.06, 0.05], "start": 0.40}]
    if two:
        objects.append({"shape": "box", "size": [0.08, 0.06, 0.05], "start": 0.14})
    return scene_from_dict({"ramp": {"angle_deg": angle, "length": 0.6}, "objects": objects, "camera": cam})


def _kinematics(scene, times, release, k=(0.15, 0.45), m=(0.5, 0.4), dt=2e-4):
    """Path coordinates (m) of the objects at ``times``: object 1 from -start up the ramp
    (sliding at g (sin - k cos), then k g deceleration on the floor), an elastic collision
    with object 2 resting on the floor."""
    th = scene.ramp.angle
    o1 = scene.objects[0]
    two = scene.n_objects == 2
    p, v = -o1.start, 0.0
    q, w = (scene.objects[1].start, 0.0) if two else (np.inf, 0.0)
    out, t, j = np.zeros((len(times), 2)), 0.0, 0
    while j < len(times):
        while j < len(times) and times[j] <= t + 1e-12:
            out[j] = (p, q)
            j += 1
        if t >= release:
            a = G * (math.sin(th) - k[0] * math.cos(th)) if p < 0 else -k[0] * G * np.sign(v)
            v = v + a * dt if p < 0 else (max(v + a * dt, 0.0) if v > 0 else 0.0)
            w = max(w - k[1] * G * dt, 0.0) if w > 0 else 0.0
            p, q = p + v * dt, q + w * dt
            if two and p + o1.length / 2 >= q - scene.objects[1].length / 2 and v > w:
                v, w = ((m[0] - m[1]) * v + 2 * m[1] * w) / sum(m), (2 * m[0] * v + (m[1] - m[0]) * w) / sum(m)
        t += dt
    return out


def _pose1(scene, p):
    """World centre (x, y_up) and tilt (rad) of object 1 at path coordinate p (blended
    from the ramp pose to the floor pose over one box length around the foot)."""
    th, o = scene.ramp.angle, scene.objects[0]
    ramp = np.array([p * math.cos(th) + o.height / 2 * math.sin(th), -p * math.sin(th) + o.height / 2 * math.cos(th)])
    floor = np.array([p, o.height / 2])
    wgt = float(np.clip((p + o.length / 2) / o.length, 0, 1))
    return (1 - wgt) * ramp + wgt * floor, (1 - wgt) * th


def _texture(h, w, colours, cell, seed):
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    chk = ((yy // cell + xx // cell) % 2).astype(bool)
    tex = np.where(chk[..., None], np.array(colours[0], np.float32), np.array(colours[1], np.float32))
    tex += rng.normal(0, 6, tex.shape).astype(np.float32)
    return cv2.GaussianBlur(tex, (0, 0), 0.7)


def _disc(radius_px, seed):
    """A pipe seen end-on: white face, grey rim, a black bar (so that it visibly turns);
    returns (texture, alpha)."""
    n = int(2 * math.ceil(radius_px) + 3)
    yy, xx = np.mgrid[0:n, 0:n] - (n - 1) / 2
    r = np.hypot(xx, yy)
    tex = np.full((n, n, 3), 235, np.float32)
    tex[r > 0.85 * radius_px] = (150, 150, 150)
    tex[(np.abs(yy) < 0.15 * radius_px) & (xx > 0) & (xx < 0.7 * radius_px)] = (20, 20, 20)
    tex += np.random.default_rng(seed).normal(0, 4, tex.shape).astype(np.float32)
    alpha = np.clip(radius_px + 0.5 - r, 0, 1).astype(np.float32)
    return cv2.GaussianBlur(tex, (0, 0), 0.7), alpha


def _draw(canvas, tex, centre, angle, alpha=None):
    h, w = tex.shape[:2]
    c, s = math.cos(angle), math.sin(angle)
    M = np.array([[c, -s, 0], [s, c, 0]], np.float64)
    M[:, 2] = np.asarray(centre) - M[:, :2] @ np.array([(w - 1) / 2, (h - 1) / 2])
    size = (canvas.shape[1], canvas.shape[0])
    img = cv2.warpAffine(tex, M, size, flags=cv2.INTER_LINEAR)
    alpha = np.ones((h, w), np.float32) if alpha is None else alpha
    alpha = cv2.warpAffine(alpha, M, size, flags=cv2.INTER_LINEAR)[..., None]
    canvas *= 1 - alpha
    canvas += img * alpha


def _background(H, W, scene, calib, seed=0):
    rng = np.random.default_rng(seed)
    bg = np.full((H, W, 3), 200, np.float32)
    bg += cv2.GaussianBlur(rng.normal(0, 40, (H, W, 3)).astype(np.float32), (0, 0), 6)
    bg += np.linspace(-15, 15, W, dtype=np.float32)[None, :, None]
    th, L = scene.ramp.angle, scene.ramp.length
    top = calib.world_to_pixel([-L * math.cos(th), L * math.sin(th)])
    foot = calib.world_to_pixel([0.0, 0.0])
    end = calib.world_to_pixel([scene.floor.length, 0.0])
    poly = np.array([top, foot, end, [end[0], H], [top[0], H]], np.int32)
    cv2.fillPoly(bg, [poly], (90, 120, 150))
    cv2.line(bg, tuple(map(int, top)), tuple(map(int, foot)), (60, 80, 100), 2)
    cv2.line(bg, tuple(map(int, foot)), tuple(map(int, end)), (60, 80, 100), 2)
    return bg


class Clip(NamedTuple):
    """A synthetic clip and its truth: (N, n, 2) pixels and world (x, y_up) positions in m,
    as drawn (with jitter) and smooth (without), and the release time in s."""

    frames: np.ndarray
    pixels: np.ndarray
    world: np.ndarray
    pixels_smooth: np.ndarray
    world_smooth: np.ndarray
    release_time: float


def make_clip(scene, n_frames=45, release_frame=7.3, jitter=0.0, noise=2.0, hand=True, size=(520, 300), seed=1,
              k=(0.15, 0.45), hand_offset=(-10.0, -22.0), hand_step=(-4.0, -13.0), hand_frames=12) -> Clip:
    """Draw a synthetic clip of ``scene`` (object 1 sliding with friction k[0], object 2 with
    k[1]); ``jitter`` px of white positional noise on every drawn centre; ``noise`` grey
    levels of pixel noise; a hand over object 1 (centre ``hand_offset`` px from it) that
    moves ``hand_step`` px per frame (up and out) for ``hand_frames`` frames."""
    rng = np.random.default_rng(seed)
    W, H = size
    calib = calibration(scene.camera, anchor_px=FOOT)
    times = np.arange(n_frames) / FPS
    release = release_frame / FPS
    path = _kinematics(scene, times, release, k=k)
    bg = _background(H, W, scene, calib, seed)
    sc = scene.camera.scale
    colours = [((40, 40, 200), (210, 230, 250)), ((200, 90, 40), (250, 230, 200))]
    texs = [_disc(o.size[0] * sc, seed + i) if o.shape == "sphere" else
            (_texture(int(round(o.height * sc)), int(round(o.length * sc)), colours[i], 6, seed + i), None)
            for i, o in enumerate(scene.objects)]
    hand_tex = _texture(34, 46, ((120, 160, 215), (100, 140, 190)), 9, seed + 7)
    frames, drawn, smooth = [], [], []
    for k_ in range(n_frames):
        canvas = bg.copy()
        poses = [_pose1(scene, path[k_, 0])]
        if scene.n_objects == 2:
            poses.append((np.array([path[k_, 1], scene.objects[1].height / 2]), 0.0))
        px, px_smooth = [], []
        for i, (xy, tilt) in enumerate(poses):
            uv0 = calib.world_to_pixel(xy)
            uv = uv0 + rng.normal(0, jitter, 2)
            direction = calib.world_to_pixel([math.cos(tilt), -math.sin(tilt)]) - calib.world_to_pixel([0, 0])
            angle = math.atan2(direction[1], direction[0])
            if scene.objects[i].shape == "sphere":  # rolls: turned by distance / radius
                angle = (path[k_, i] + scene.objects[i].start) / scene.objects[i].size[0]
            _draw(canvas, texs[i][0], uv, angle, texs[i][1])
            px.append(uv)
            px_smooth.append(uv0)
        if hand and k_ < hand_frames:
            start = smooth[0][0] + np.asarray(hand_offset) if smooth else px_smooth[0] + np.asarray(hand_offset)
            _draw(canvas, hand_tex, start + k_ * np.asarray(hand_step), -0.3)
        canvas += rng.normal(0, noise, canvas.shape).astype(np.float32)
        frames.append(np.clip(canvas, 0, 255).astype(np.uint8))
        drawn.append(px)
        smooth.append(px_smooth)
    drawn, smooth = np.array(drawn), np.array(smooth)
    return Clip(np.stack(frames), drawn, calib.pixel_to_world(drawn), smooth, calib.pixel_to_world(smooth), release)


def _write_video(path, frames, fps=FPS, fourcc="mp4v"):
    h, w = frames.shape[1:3]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (w, h))
    assert writer.isOpened()
    for f in frames:
        writer.write(f)
    writer.release()


def _profile_rms(obs, world):
    """RMS over the fit mask of observed minus true velocity, per trace (m/s)."""
    true = profile_from_positions(world, obs.frame_times)
    return np.sqrt(np.mean((obs.profile - true)[:, obs.mask] ** 2, axis=1))


# ------------------------------------------------------------------------- video errors


def test_missing_video_file(tmp_path):
    with pytest.raises(VideoError, match="not found"):
        read_video(tmp_path / "nope.mp4")


def test_text_file_renamed_mp4(tmp_path):
    path = tmp_path / "notes.mp4"
    path.write_text("this is not a video\n")
    with pytest.raises(VideoError, match="not a readable video|no decodable frames") as err:
        read_video(path)
    assert "\n" not in str(err.value)


def test_too_few_frames(tmp_path):
    path = tmp_path / "short.avi"
    _write_video(path, np.zeros((3, 48, 64, 3), np.uint8), fourcc="MJPG")
    with pytest.raises(VideoError, match="only 3 frames"):
        read_video(path)


def test_video_round_trip_and_fps_override(tmp_path):
    path = tmp_path / "ok.avi"
    frames = np.random.default_rng(0).integers(0, 255, (8, 48, 64, 3), dtype=np.uint8)
    _write_video(path, frames, fps=25.0, fourcc="MJPG")
    clip = read_video(path)
    assert clip.frames.shape == (8, 48, 64, 3) and clip.frames.dtype == np.uint8
    assert clip.fps == pytest.approx(25.0)
    assert read_video(path, fps_override=240.0).fps == 240.0


def test_missing_or_bad_fps(tmp_path, monkeypatch):
    path = tmp_path / "ok.avi"
    _write_video(path, np.zeros((8, 48, 64, 3), np.uint8), fps=25.0, fourcc="MJPG")
    monkeypatch.setattr(video_module, "_container_fps", lambda cap: math.nan)
    with pytest.raises(VideoError, match=r"video: \{fps: \.\.\.\}"):
        read_video(path)
    assert read_video(path, fps_override=30.0).fps == 30.0
    with pytest.raises(VideoError, match="fps"):
        read_video(path, fps_override=-5)
    with pytest.raises(VideoError, match="fps"):
        clip_from_frames(np.zeros((8, 4, 4, 3), np.uint8), math.nan)


# ------------------------------------------------------------------------- tracking


@pytest.fixture(scope="module")
def clip():
    return make_clip(synthetic_scene())


def test_track_from_given_start_pixels(clip):
    scene = synthetic_scene()
    tracks = track_objects(clip.frames, clip.pixels[0], object_windows(scene, calibration(scene.camera)), fps=FPS)
    err = np.linalg.norm(tracks.pixels - clip.pixels, axis=-1)
    assert tracks.valid.all()
    assert np.median(err) < 0.5 and err.max() < 2.0
    assert (tracks.n_features >= 4).all()


def test_observe_finds_objects_despite_the_hand(clip):
    """No start pixels, no foot pixel: object 1 is found by its motion down the ramp (not
    the hand lifting off it), object 2 from the scene's offset and its own motion."""
    scene = synthetic_scene(foot=False)
    obs = observe(clip_from_frames(clip.frames, FPS), scene)
    err = np.linalg.norm(obs.pixels - clip.pixels, axis=-1)
    assert np.median(err, axis=0).max() <= 2.0, np.median(err, axis=0)
    assert np.abs(obs.release_time - clip.release_time) * FPS < 0.25
    assert obs.moved.all()
    assert (_profile_rms(obs, clip.world) < 0.02).all()  # m/s; 1 px/frame here is 0.06 m/s
    # positions are anchored at the scene's start positions (objects at rest before the release)
    for i in range(2):
        pos, _ = object_start_pose(scene, i)
        assert np.allclose(obs.positions[0, i], [pos[0], pos[2]], atol=0.5 / scene.camera.scale)
    # shapes of the contract
    N = len(clip.frames)
    assert obs.profile.shape == (4, N - 1) and obs.mask.shape == (N - 1,) and obs.position_sd.shape == (4,)
    assert not obs.mask[: int(clip.release_time * FPS) - 3].any() and obs.mask[-1]


def test_find_objects_with_foot_prior_and_wrong_start(clip):
    """With camera.foot_pixel the scene predicts the start pixels; object 2's start in the
    scene is 2 cm (10 px) off, and the finder still lands on the object."""
    scene = synthetic_scene()
    data = scene.model_dump()
    data["objects"][1]["start"] += 0.02
    wrong = scene_from_dict(data)
    found = find_objects(clip.frames, wrong, calibration(wrong.camera))
    assert np.linalg.norm(found - clip.pixels[0], axis=-1).max() < 1.5


def test_noise_sd_from_jittered_clip():
    """Object 1 sliding slowly down a 10 degree ramp for the whole clip (80 frames), drawn
    with 0.5 px of white positional jitter: the estimated position SD matches the actual SD
    of the tracked positions about the smooth truth within 30% (mean of the x and y traces;
    each trace within 45%)."""
    def scene(start_pixels=None):
        data = synthetic_scene(two=False, start_pixels=start_pixels, angle=10.0).model_dump()
        data["objects"][0]["start"] = 0.55
        return scene_from_dict(data)

    c = make_clip(scene(), n_frames=80, release_frame=2.4, jitter=0.5, k=(0.15,), seed=4, hand=False)
    obs = observe(clip_from_frames(c.frames, FPS), scene(c.pixels_smooth[0]))
    after = obs.frame_times > c.release_time + 0.1
    true_sd = (obs.positions[:, 0] - c.world_smooth[:, 0])[after].std(axis=0)
    assert obs.position_sd.mean() == pytest.approx(true_sd.mean(), rel=0.3), (obs.position_sd, true_sd)
    assert np.allclose(obs.position_sd, true_sd, rtol=0.45), (obs.position_sd, true_sd)
    assert abs(obs.release_time - c.release_time) * FPS < 1.5  # slow start, 0.5 px jitter


def test_noise_estimator_on_white_noise():
    rng = np.random.default_rng(0)
    t = np.arange(200) / FPS
    motion = np.where(t > 1, 0.5 * 2.0 * (t - 1) ** 2, 0.0)  # rest, then constant acceleration
    est = estimate_noise_sd(motion + rng.normal(0, 0.01, t.size))
    assert est == pytest.approx(0.01, rel=0.15)


def test_lost_track_is_reported(clip):
    frames = clip.frames.copy()
    frames[20:, 100:, 150:] = 128  # a flat grey board hides the lower right from frame 20
    scene = synthetic_scene(start_pixels=clip.pixels[0])
    assert clip.pixels[0, 1, 0] > 150 and clip.pixels[0, 1, 1] > 100  # object 2 rests there ...
    assert clip.pixels[20, 0, 0] > 150 and clip.pixels[20, 0, 1] > 100  # ... and object 1 slides under it then
    with pytest.raises(TrackingError, match=r"object [12] track lost at frame 2\d \(t = 0\.\d\d s\)") as err:
        observe(clip_from_frames(frames, FPS), scene)
    assert "\n" not in str(err.value)


def test_object_that_never_moves(clip):
    still = make_clip(synthetic_scene(), n_frames=20, release_frame=100, hand=False)
    with pytest.raises(TrackingError, match=r"object 1 never moves.*tan\(theta\) = 0\.364"):
        observe(clip_from_frames(still.frames, FPS), synthetic_scene(start_pixels=still.pixels[0]))
    with pytest.raises(TrackingError, match="object 1 never moves"):
        observe(clip_from_frames(still.frames, FPS), synthetic_scene(foot=False))


def test_fit_window_and_fps_override(clip):
    data = synthetic_scene(start_pixels=clip.pixels[0]).model_dump()
    data["video"] = {"window": [0.4, 1.0], "fps": 60.0}
    obs = observe(clip_from_frames(clip.frames, FPS), scene_from_dict(data))
    assert obs.fps == 60.0 and obs.frame_times[1] == pytest.approx(1 / 60)
    t0, t1 = obs.frame_times[:-1], obs.frame_times[1:]
    assert np.array_equal(obs.mask, (t0 >= 0.4 - 1e-9) & (t1 <= 1.0 + 1e-9))
    assert observe(clip_from_frames(clip.frames, FPS), scene_from_dict(data), fps=120.0).fps == 120.0
    # a clip already read with an override (e.g. --fps) keeps it
    assert observe(clip_from_frames(clip.frames, FPS).with_fps(50.0), scene_from_dict(data)).fps == 50.0


def test_rolling_sphere_is_tracked_by_its_outline():
    """A rolling disc (its face turns by distance / radius, ~0.5 rad per frame at the
    foot) is found automatically and followed to within a pixel; KLT features would turn
    away with it."""
    data = synthetic_scene(two=False, foot=False).model_dump()
    data["objects"][0] = {"shape": "sphere", "size": [0.03], "start": 0.40}
    scene = scene_from_dict(data)
    c = make_clip(scene, n_frames=36, release_frame=4.5, k=(0.1,), hand=False)
    obs = observe(clip_from_frames(c.frames, FPS), scene)
    assert not obs.mask[-3:].any()  # it rolls out at the right: samples after it left are not fitted
    used = np.zeros(len(c.frames), bool)
    used[:-1] |= obs.mask
    used[1:] |= obs.mask
    err = np.linalg.norm(obs.pixels - c.pixels, axis=-1)[used]
    assert np.median(err) <= 1.0 and err.max() <= 2.5, (np.median(err), err.max())
    assert abs(obs.release_time - c.release_time) * FPS < 0.5


def test_outline_tracker_measures_its_start_frame():
    """A round object's start pixel (given, or found by the motion-based locator) may be a few
    px off its outline; the start frame is measured on the outline like every other frame,
    so the track has no one-frame jump there (before the fix: the given pixel itself, a jump
    of the full offset and a velocity spike at the release in rendered rolling videos)."""
    data = synthetic_scene(two=False, foot=False).model_dump()
    data["objects"][0] = {"shape": "sphere", "size": [0.03], "start": 0.40}
    c = make_clip(scene_from_dict(data), n_frames=20, release_frame=4.5, k=(0.1,), hand=False)
    data["camera"]["start_pixels"] = [list(map(float, c.pixels[0, 0] + np.array([3.0, -2.0])))]
    scene = scene_from_dict(data)
    obs = observe(clip_from_frames(c.frames, FPS), scene)
    err = np.linalg.norm(obs.pixels[:, 0] - c.pixels[:, 0], axis=-1)
    assert err[0] <= 1.0, err[:3]
    assert np.abs(np.diff(obs.pixels[:4, 0], axis=0)).max() <= 1.0  # at rest: no jump after frame 0


# ------------------------------------------------------------------------- rendered video


def test_rendered_video_with_hand(tmp_path):
    """A MuJoCo-rendered video (galileo_jax.synth) with the hand: objects found
    automatically, median position error <= 2 px against the renderer's truth pixels."""
    synth = pytest.importorskip("galileo_jax.synth")
    from galileo_jax.errors import GalileoError
    from galileo_jax.scene import load_scene

    scene = load_scene(Path(__file__).parents[1] / "scenes" / "ramp_20.yaml")
    out = tmp_path / "hand.mp4"
    try:
        synth.render_video(scene, {"m1": 0.6, "k1": 0.15, "m2": 0.3, "k2": 0.25}, out, width=480, height=270,
                           duration=1.6, hand=True, progress=False)
    except GalileoError as err:  # no OpenGL here
        pytest.skip(str(err))
    truth = json.loads(out.with_suffix(".truth.json").read_text())
    obs = observe(out, load_scene(out.with_suffix(".yaml")))
    err = np.linalg.norm(obs.pixels - np.array(truth["pixels"]), axis=-1)
    assert np.median(err, axis=0).max() <= 2.0, np.median(err, axis=0)
    assert abs(obs.release_time - truth["release_time"]) * obs.fps < 0.5


def test_object_neither_textured_nor_coloured_is_reported(clip):
    """An object that ``tracker: auto`` can follow neither by features nor by colour (here
    painted over with the background's grey) gets one line saying both, not only KLT's."""
    frames = clip.frames.copy()
    u, v = np.round(clip.pixels[0, 1]).astype(int)
    frames[:, v - 25:v + 25, u - 30:u + 30] = 128
    with pytest.raises(TrackingError, match=r"object 2: it shows too little texture .* colour does not stand "
                                            r"out .* start pixel \(\d+, \d+\) in frame 0; check") as err:
        observe(clip_from_frames(frames, FPS), synthetic_scene(start_pixels=clip.pixels[0]))
    assert "\n" not in str(err.value)


def test_track_not_measured_in_its_anchor_frame_still_gives_positions(clip):
    """A track without a measurement in the frame that anchors it to the scene's start
    position (a colour track begun a few frames later) is anchored at its measured frame
    nearest to it: positions, noise and release time come out finite (NaN there made every
    position NaN, and the release-time fit raised a bare ValueError), and the same as a track
    measured there, to the object's motion before that frame."""
    from galileo_jax.observe.profile import observation_from_tracks
    from galileo_jax.observe.tracks import Tracks

    scene = synthetic_scene(start_pixels=clip.pixels[0])
    N, n = clip.pixels.shape[:2]
    full = Tracks(clip.pixels.copy(), np.ones((N, n), bool), np.ones((N, n), int), np.ones((N, n)))
    late = full._replace(pixels=full.pixels.copy(), valid=full.valid.copy(), quality=full.quality.copy())
    late.pixels[:3, 0], late.valid[:3, 0], late.quality[:3, 0] = np.nan, False, 0.0
    ref, obs = observation_from_tracks(full, scene, FPS), observation_from_tracks(late, scene, FPS)
    assert np.isfinite(obs.positions[3:]).all() and np.isfinite(obs.position_sd).all()
    assert np.allclose(obs.positions[3:], ref.positions[3:], atol=1e-9)  # object 1 rests until frame 7
    assert obs.release_time == pytest.approx(ref.release_time, abs=1e-4)  # 0.3% of a frame: 3 fewer samples


def test_objects_never_measured_together_get_a_tracking_error(clip):
    """Where the tracker measured each object only in frames in which the other was not (one
    lost at a collision, the other never measured at rest: a held-out render), no velocity
    sample has both; the user gets a one-line tracking error that names the counts, not the
    likelihood's "widen the fit window"."""
    from galileo_jax.observe.profile import observation_from_tracks
    from galileo_jax.observe.tracks import Tracks

    scene = synthetic_scene(start_pixels=clip.pixels[0])
    N, n = clip.pixels.shape[:2]
    valid = np.zeros((N, n), bool)
    valid[: N // 2, 0] = True
    valid[N // 2:, 1] = True
    tracks = Tracks(clip.pixels.copy(), valid, valid.astype(int), valid.astype(float))
    with pytest.raises(TrackingError, match=rf"no two consecutive frames in which every object was measured "
                                            rf"\(object 1 in {N // 2}, object 2 in {N - N // 2} of {N} frames\)"
                       ) as err:
        observation_from_tracks(tracks, scene, FPS)
    assert "\n" not in str(err.value)
    valid[N // 2 - 2: N // 2 + 2] = True  # four frames with both: a velocity sample, no error
    both = tracks._replace(valid=valid, quality=valid.astype(float))
    assert observation_from_tracks(both, scene, FPS).mask.sum() >= 1

