"""Rendering a synthetic video and writing its files atomically: the frames
(:func:`render_frames`, motion blur as sub-frames), the ``.mp4`` (:func:`write_video`), the
calibrated scene ``.yaml`` and the ground truth ``.truth.json`` (:func:`truth_record`), all
through :func:`render_video`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

import cv2
import mujoco
import numpy as np
from tqdm import tqdm

from galileo_jax import render
from galileo_jax.effects import check_applicable
from galileo_jax.errors import GalileoError
from galileo_jax.physics.model import WorldPhysics
from galileo_jax.physics.simulate import PhysParams, physics_timestep, scene_effects
from galileo_jax.scene import Scene, Video, save_scene
from galileo_jax.synth.draws import effect_value_dict, param_dict, resolve_params
from galileo_jax.synth.motion import MAX_BLUR, REST_SECONDS, Motion, exposure_times, simulate_motion


def _renderer(model: mujoco.MjModel, view: render.View) -> mujoco.Renderer:
    try:
        return mujoco.Renderer(model, view.height, view.width)
    except Exception as err:  # noqa: BLE001 - any GL failure becomes one user-facing line
        backend = os.environ.get("MUJOCO_GL", "")
        raise GalileoError(f"cannot create an OpenGL context for rendering (MUJOCO_GL={backend}: "
                           f"{str(err).splitlines()[0] if str(err) else type(err).__name__}); install "
                           f"libegl1 libegl-mesa0 libopengl0 libgl1-mesa-dri, or set MUJOCO_GL=osmesa") from None


def render_frames(model: mujoco.MjModel, view: render.View, qpos: np.ndarray, hand_pos: np.ndarray | None = None,
                  hand_quat: np.ndarray | None = None, noise_sd: float = 0.0,
                  rng: np.random.Generator | None = None) -> Iterator[np.ndarray]:
    """Render frames of the front camera, optionally motion-blurred.

    Args:
        model: render model from :func:`galileo_jax.render.build_render_model`.
        view: its view (image size).
        qpos: (N, nq) generalised positions, one row per frame; or (N, S, nq), S sub-frames
            per frame whose renders are averaged (in float, before the noise and the rounding
            to 8 bits): motion blur (:func:`exposure_times`, :meth:`Motion.qpos_at`).
        hand_pos: (N, 3) or (N, S, 3) (as ``qpos``) hand mocap position in m, or None (no hand).
        hand_quat: (4,) hand orientation.
        noise_sd: SD of Gaussian pixel noise in grey levels (0..255), independent per pixel
            and channel.
        rng: noise generator.

    Yields:
        (H, W, 3) uint8 BGR frames.
    """
    rng = rng if rng is not None else np.random.default_rng(0)
    qpos = np.asarray(qpos)
    subs = qpos if qpos.ndim == 3 else qpos[:, None]
    hands = None if hand_pos is None else np.asarray(hand_pos).reshape(subs.shape[:2] + (3,))
    data = mujoco.MjData(model)
    renderer = _renderer(model, view)
    try:
        for k in range(subs.shape[0]):
            images = [_render_state(renderer, model, data, subs[k, j], None if hands is None else hands[k, j],
                                    hand_quat) for j in range(subs.shape[1])]
            rgb = images[0] if len(images) == 1 else np.mean(images, axis=0, dtype=np.float32)
            yield np.ascontiguousarray(_to_uint8(rgb, noise_sd, rng)[:, :, ::-1])
    finally:
        renderer.close()


def _render_state(renderer: mujoco.Renderer, model: mujoco.MjModel, data: mujoco.MjData, qpos: np.ndarray,
                  hand_pos: np.ndarray | None, hand_quat: np.ndarray | None) -> np.ndarray:
    """(H, W, 3) uint8 RGB render of the front camera at one state."""
    data.qpos[:] = qpos
    if hand_pos is not None:
        data.mocap_pos[0] = hand_pos
        data.mocap_quat[0] = hand_quat
    mujoco.mj_kinematics(model, data)
    mujoco.mj_camlight(model, data)
    renderer.update_scene(data, camera=render.CAMERA)
    return renderer.render()


def _to_uint8(rgb: np.ndarray, noise_sd: float, rng: np.random.Generator) -> np.ndarray:
    """An image (uint8 or float 0..255) plus Gaussian noise of SD ``noise_sd``, rounded to uint8."""
    if noise_sd > 0:
        noisy = rng.standard_normal(rgb.shape, dtype=np.float32)
        noisy *= np.float32(noise_sd)
        noisy += rgb
        rgb = noisy
    if rgb.dtype == np.uint8:
        return rgb
    return np.clip(np.rint(rgb, out=rgb), 0, 255, out=rgb).astype(np.uint8)


def _temp_path(path: Path) -> Path:
    """A new empty file beside ``path`` (same suffix), with the usual permissions (umask)."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix or ".tmp", dir=path.parent)
    os.close(fd)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    return Path(tmp)


def _json_text(record: dict) -> str:
    """JSON with one top-level key per line and one frame per line for per-frame arrays."""
    lines = []
    for key, value in record.items():
        if isinstance(value, list) and value and isinstance(value[0], list):
            rows = ",\n  ".join(json.dumps(row) for row in value)
            lines.append(f" {json.dumps(key)}: [\n  {rows}\n ]")
        else:
            lines.append(f" {json.dumps(key)}: {json.dumps(value)}")
    return "{\n" + ",\n".join(lines) + "\n}\n"


def _atomic_write_text(path: Path, text: str) -> None:
    tmp = _temp_path(path)
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_video(path: Path, frames: Iterator[np.ndarray], fps: float, size: tuple[int, int], n_frames: int,
                progress: bool = True) -> float:
    """Write BGR frames to an mp4 (mp4v) atomically; returns the container's frame rate.

    Args:
        path: output ``.mp4``.
        frames: iterator of (H, W, 3) uint8 BGR frames.
        fps: frames per second.
        size: (width, height) in px.
        n_frames: number of frames (for the progress bar).
        progress: show a tqdm bar.
    """
    tmp = _temp_path(path)
    try:
        writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
        if not writer.isOpened():
            raise GalileoError(f"cannot write video {path} (OpenCV has no mp4v encoder?)")
        try:
            for frame in tqdm(frames, total=n_frames, desc=f"rendering {path.name}", unit="frame",
                              disable=not progress, leave=False):
                writer.write(frame)
        finally:
            writer.release()
        cap = cv2.VideoCapture(str(tmp))
        container_fps = float(cap.get(cv2.CAP_PROP_FPS))
        cap.release()
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return container_fps


def truth_record(scene: Scene, params: PhysParams, motion: Motion, view: render.View, *, noise_sd: float,
                 hand: bool, seed: int, video: str, effects=(), look: str = "checker", colours=None, blur: int = 0,
                 shutter: float = 0.5, backdrop: str = "plain", world: WorldPhysics | None = None) -> dict:
    """The ground-truth JSON record of a rendered video.

    Keys: ``video`` (file name), ``scene`` (scene name), ``m1, k1, m2, k2`` (those of the
    scene's objects; kg and dimensionless), ``phi`` = (m1 - m2) / (m1 + m2) (two objects),
    then, when effects were simulated, each effect parameter by its name (e.g.
    ``drag_quadratic``; units in the effect's :class:`~galileo_jax.effects.EffectParam`),
    ``effects`` ({effect name: {parameter: value}}: every simulated effect, the scene's own
    and the hidden ones; ``{}`` for the base model), ``hidden_effects`` (names of the
    simulated effects that the written scene file does not list), ``fps``, ``release_time``
    (s), ``release_frame``, ``n_frames``, ``width``, ``height`` (px), ``noise_sd`` (grey
    levels), ``hand``, ``seed``, ``substeps``, ``pixels_per_metre`` (in the plane of motion),
    ``foot_pixel`` ([u, v]), ``moved`` (per object, whether it moved more than 1 mm),
    ``pixels`` (N x n_objects x [u, v]: each object's centre projected into the image at the
    frame time, px), ``positions`` (N x n_objects x [x, z]: world x and vertical of each
    centre, m), ``look``, ``colours`` (n_objects x [r, g, b], 0..1: each object's base colour),
    ``camera`` ({``projection``, ``distance_m`` (null when orthographic), ``fovy_deg`` (null
    when orthographic), ``direction``}), ``blur`` (sub-frames per frame, 0: none), ``shutter``
    (exposure / frame interval), ``backdrop``, ``pixels_front`` (N x n_objects x [u, v]: the
    centre of each object's face toward the camera, offset from its centre by half its width
    (radius for cylinders and spheres) along the body's y axis, projected; equal to ``pixels``
    in orthographic views) and, when ``blur`` >= 2, ``pixels_exposure`` (N x n_objects x
    [u, v]: the mean over each frame's sub-frames of the projected centre, what the centroid
    of a blurred image sees), ``pixels_silhouette`` (N x n_objects x [u, v]: the centroid of
    each object's whole silhouette, over the exposure when blurred: what a centroid tracker
    measures when nothing hides the object; off the projected centre by the faces a
    perspective camera sees beside the near one), ``world`` ({``cone``, ``ramp_thickness`` (m)}: the physics the
    fitted model does not have, :class:`~galileo_jax.physics.model.WorldPhysics`).

    ``effects``: the simulated effects (names or Effects, the scene's own included), in the
    order of ``params.effects``. ``colours``: as :func:`galileo_jax.render.object_colours`.
    """
    effects = scene_effects(scene, effects)
    rec = {"video": video, "scene": scene.name}
    rec.update(param_dict(params))
    if scene.n_objects == 2:
        m1, m2 = (float(m) for m in params.mass)
        rec["phi"] = (m1 - m2) / (m1 + m2)
    by_effect = effect_value_dict(effects, params.effects) if effects else {}
    for values in by_effect.values():
        rec.update(values)
    rec["effects"] = by_effect
    rec["hidden_effects"] = [e.name for e in effects if e.name not in scene.effects]
    travel = np.linalg.norm(motion.positions - motion.positions[0], axis=-1).max(axis=0)
    centres = np.zeros((scene.n_objects, 3))
    rec.update({
        "fps": motion.fps, "release_time": motion.release_time, "release_frame": motion.release_frame,
        "n_frames": motion.n_frames, "width": view.width, "height": view.height, "noise_sd": noise_sd,
        "hand": hand, "seed": seed, "substeps": scene.simulation.substeps,
        "pixels_per_metre": view.scale, "foot_pixel": list(view.foot_pixel),
        "moved": [bool(d > 1e-3) for d in travel],
        "pixels": _pixels(view, motion.qpos, motion.qpos_adr, centres),
        "positions": np.round(motion.positions, 7).tolist(),
        "look": look, "colours": [list(c) for c in render.object_colours(scene, colours)],
        "camera": {"projection": view.projection, "distance_m": view.distance if view.perspective else None,
                   "fovy_deg": view.fovy if view.perspective else None, "direction": view.direction},
        "blur": blur, "shutter": shutter, "backdrop": backdrop,
        "world": dataclasses.asdict(world or WorldPhysics()),
        "pixels_front": _pixels(view, motion.qpos, motion.qpos_adr, render.front_offsets(scene, view)),
    })
    if blur >= 2:
        sub = motion.qpos_at(exposure_times(motion.n_frames, motion.fps, blur, shutter))
        rec["pixels_exposure"] = _pixels(view, sub, motion.qpos_adr, centres, mean_axis=1)
    rec["pixels_silhouette"] = _silhouette_pixels(scene, view, sub if blur >= 2 else motion.qpos[:, None],
                                                  motion.qpos_adr)
    return rec


def _silhouette_pixels(scene: Scene, view: render.View, qpos: np.ndarray, qpos_adr) -> list:
    """(N, n_objects, 2) centroids (px) of each object's whole silhouette (the convex hull of its
    projected :func:`~galileo_jax.render.outline_points`), from (N, S, nq) poses at S sub-frames
    per frame: the area-weighted mean over the sub-frames (a blurred image's centroid); rounded
    to 1e-4 px, as nested lists."""
    out = []
    for i in range(scene.n_objects):
        local = render.outline_points(scene, i)  # (P, 3)
        world = np.stack([render.body_points(qpos, [qpos_adr[i]], p[None])[..., 0, :] for p in local], axis=-2)
        c, a = render.silhouettes(view, world)  # (N, S, 2), (N, S)
        out.append((c * a[..., None]).sum(axis=1) / np.maximum(a.sum(axis=1), 1e-9)[:, None])
    return np.round(np.stack(out, axis=1), 4).tolist()


def _pixels(view: render.View, qpos: np.ndarray, qpos_adr, local: np.ndarray, mean_axis: int | None = None) -> list:
    """Projected body points (:func:`galileo_jax.render.body_points`) in px, rounded to 1e-4 px,
    as nested lists; ``mean_axis``: average over that axis of ``qpos`` first (sub-frames)."""
    px = view.project(render.body_points(qpos, qpos_adr, local))
    if mean_axis is not None:
        px = px.mean(axis=mean_axis)
    return np.round(px, 4).tolist()


def calibrated_scene(scene: Scene, view: render.View, container_fps: float, fps: float) -> Scene:
    """The scene with the exact camera calibration; ``video`` holds only ``fps``, and only when
    the container's frame rate differs from ``fps`` (an input ``video`` block described another
    video and is dropped)."""
    video = Video() if math.isclose(container_fps, fps, rel_tol=1e-4) else Video(fps=fps)
    return scene.model_copy(update={"camera": view.camera_block(), "video": video})


def check_options(fps: float, duration: float | None, width: int, height: int, noise_sd: float,
                   rest_frames: int) -> None:
    if not (math.isfinite(fps) and 1 <= fps <= 1000):
        raise GalileoError(f"--fps {fps}: give a frame rate in [1, 1000] frames per second")
    if not (16 <= width <= 4096 and 16 <= height <= 4096 and width % 2 == 0 and height % 2 == 0):
        raise GalileoError(f"image size {width}x{height}: give even sizes in [16, 4096] px")
    if not (math.isfinite(noise_sd) and 0 <= noise_sd <= 100):
        raise GalileoError(f"--noise {noise_sd}: give a pixel noise SD in [0, 100] grey levels")
    if rest_frames < 1:
        raise GalileoError(f"rest_frames = {rest_frames}: need at least one frame before release")
    if duration is not None:
        if not (math.isfinite(duration) and 0 < duration <= 120):
            raise GalileoError(f"--duration {duration}: give a length in (0, 120] s")
        if int(round(duration * fps)) < rest_frames + 2:
            raise GalileoError(f"--duration {duration} s leaves no frames after the release at "
                               f"{rest_frames / fps:.3g} s; make it longer")


def check_style(scene: Scene, look: str, colours, camera: str, camera_distance: float, direction: str, blur: int,
                 shutter: float, backdrop: str) -> None:
    """Check :func:`render_video`'s look, camera and blur options (one-line :class:`GalileoError`)."""
    render.check_choice(look, render.LOOKS, "look", "--look")
    render.check_choice(backdrop, render.BACKDROPS, "backdrop", "--backdrop")
    render.object_colours(scene, colours)
    render.check_camera(scene, camera, camera_distance, direction)
    if isinstance(blur, bool) or not isinstance(blur, (int, np.integer)) or not 0 <= blur <= MAX_BLUR:
        raise GalileoError(f"--blur {blur}: give 0 (no motion blur) or a whole number of sub-frames per frame "
                           f"in [2, {MAX_BLUR}]")
    if not (math.isfinite(shutter) and 0 < shutter <= 1):
        raise GalileoError(f"--shutter {shutter}: give the exposure as a fraction of the frame interval in (0, 1]")


def render_video(scene: Scene, params, out_path, *, fps: float = 30.0, duration: float | None = None,
                 width: int = 640, height: int = 360, noise_sd: float = 2.0, hand: bool = False,
                 rest_frames: int | None = None, seed: int = 0, progress: bool = True, effects=None,
                 look: str = "checker", colours=None, camera: str = "orthographic",
                 camera_distance: float = render.CAMERA_DISTANCE, direction: str = "right", blur: int = 0,
                 shutter: float = 0.5, backdrop: str = "plain", world: WorldPhysics | None = None) -> dict:
    """Simulate and render one ramp video with its calibrated scene file and ground truth.

    Args:
        scene: the scene (start positions, shapes; its camera block is replaced).
        params: ``{"m1", "k1", "m2", "k2"}`` plus the value of every effect parameter by name
            (e.g. ``"drag_quadratic"``), or :class:`PhysParams` (see :func:`resolve_params`).
        out_path: the ``.mp4`` to write; ``<stem>.yaml`` and ``<stem>.truth.json`` go beside it.
        fps: frames per second.
        duration: video length in s (rest frames included); ``None``: until all objects have
            rested for 0.5 s, at most 4 s.
        width, height: image size in px (even).
        noise_sd: SD of Gaussian pixel noise in grey levels.
        hand: show a hand holding object 1 until the release, then leaving the frame.
        rest_frames: frames at rest before release (default ``round(0.3 * fps)``).
        seed: seed of the pixel noise and of the cluttered backdrop.
        progress: show a progress bar.
        effects: hidden effects (names or :class:`~galileo_jax.effects.Effect`), simulated
            and drawn on top of the scene's own ``scene.effects``. They go into the truth
            (``effects``, ``hidden_effects`` and each parameter at top level), not into the
            written scene file, which describes only the setup (it keeps the scene's own
            ``effects``).
        look: ``"checker"`` (textured objects) or ``"plain"`` (one flat colour each).
        colours: (n_objects, 3) base RGB of the objects in [0, 1]; None: the scene's ``rgba``,
            else red and blue.
        camera: ``"orthographic"`` or ``"perspective"`` (a pinhole ``camera_distance`` m from the
            plane of motion whose scale there is the written ``pixels_per_metre``; nearer
            surfaces look larger). See :mod:`galileo_jax.render`.
        camera_distance: perspective camera's distance from the plane of motion in m.
        direction: ``"right"`` or ``"left"``: the image direction object 1 moves in (left: the
            scene seen from its other side; the scene file says ``ramp_direction: left``).
        blur: motion blur: render this many sub-frames per frame (>= 2) at
            :func:`exposure_times` (the state interpolated between physics steps,
            :meth:`Motion.qpos_at`) and average them; 0 (or 1): none.
        shutter: exposure time as a fraction of the frame interval (with ``blur``).
        backdrop: ``"plain"`` (grey wall) or ``"clutter"`` (posters, shelves, cables, blobs).
        world: physics the fitted model does not have (:class:`~galileo_jax.physics.model.WorldPhysics`:
            elliptic friction cones, a ramp board of some thickness with an edge at its foot),
            simulated and drawn; the written scene file does not know of it. ``None``: the
            model's own physics.

    Returns:
        The truth record (as written to ``<stem>.truth.json``; see :func:`truth_record`).

    Raises:
        GalileoError: bad parameters, effects or options, or rendering is unavailable.
    """
    out_path = Path(out_path)
    if out_path.suffix.lower() != ".mp4":
        raise GalileoError(f"output {out_path} must end in .mp4")
    if not out_path.parent.is_dir():
        raise GalileoError(f"output folder {out_path.parent} does not exist; create it first")
    rest_frames = max(1, int(round(REST_SECONDS * fps))) if rest_frames is None else int(rest_frames)
    check_options(fps, duration, width, height, noise_sd, rest_frames)
    check_style(scene, look, colours, camera, camera_distance, direction, blur, shutter, backdrop)
    effs = scene_effects(scene, effects or ())
    check_applicable(effs, scene)
    phys = resolve_params(scene, params, effs)
    n_frames = None if duration is None else int(round(duration * fps))
    motion = simulate_motion(scene, phys, fps, rest_frames, n_frames, effects=effs, world=world)
    if hand and n_frames is None:  # let the hand leave the frame before the video ends
        min_frames = rest_frames + int(math.ceil((render.HAND_EXIT_TIME + 0.1) * fps))
        if motion.n_frames < min_frames:
            motion = simulate_motion(scene, phys, fps, rest_frames, min_frames, effects=effs, world=world)
    view = render.frame_view(scene, motion.positions, width, height, projection=camera, distance=camera_distance,
                             direction=direction)
    model = render.build_render_model(scene, view, physics_timestep(fps, scene.simulation.substeps), hand=hand,
                                      effects=effs, look=look, colours=colours, backdrop=backdrop, seed=seed,
                                      world=world)
    times = exposure_times(motion.n_frames, fps, blur, shutter)
    hand_pos = hand_quat = None
    if hand:
        hand_quat = render.hand_rest_pose(scene)[1]
        hand_pos = np.array([[render.hand_position(scene, view, t, motion.release_time) for t in row] for row in times])
    frames = render_frames(model, view, motion.qpos_at(times), hand_pos, hand_quat, noise_sd,
                           np.random.default_rng(seed))
    container_fps = write_video(out_path, frames, fps, (width, height), motion.n_frames, progress)
    truth = truth_record(scene, phys, motion, view, noise_sd=noise_sd, hand=hand, seed=seed, video=out_path.name,
                         effects=effs, look=look, colours=colours, blur=blur, shutter=shutter, backdrop=backdrop,
                         world=world)
    yaml_path = out_path.with_suffix(".yaml")
    tmp = _temp_path(yaml_path)
    try:
        save_scene(calibrated_scene(scene, view, container_fps, fps), tmp)
        os.replace(tmp, yaml_path)
    finally:
        tmp.unlink(missing_ok=True)
    _atomic_write_text(out_path.with_suffix(".truth.json"), _json_text(truth))
    return truth
