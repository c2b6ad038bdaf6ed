"""Rendering helpers for synthetic ramp videos: camera framing, scenery, textures, the hand.

The camera is orthographic and looks along world +y at the x-z plane (the plane of motion,
y = 0): image right is world +x, image up is world +z, so every point of the plane maps to
pixels by one exact scale (px/m) and an offset, at any depth. Pixel convention (OpenCV): pixel
(u, v) has its centre at integer coordinates, u to the right, v down; the optical axis passes
through (W/2 - 1/2, H/2 - 1/2).

Everything added here is visual only (``contype = conaffinity = 0``, static world geoms or a
mocap body without joints): the physics of the model is unchanged, and the qpos layout is the
same as :func:`galileo_jax.model.build_model`'s.
"""

from __future__ import annotations

import math
import os

os.environ.setdefault("MUJOCO_GL", "egl")

from typing import NamedTuple  # noqa: E402

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from galileo_jax.effects import resolve_effects  # noqa: E402
from galileo_jax.model import OBJECT_COLOURS, build_spec, object_start_pose  # noqa: E402
from galileo_jax.scene import Camera, Scene  # noqa: E402

#: Name of the render camera added to the model.
CAMERA = "front"
#: Name of the hand's mocap body.
HAND = "hand"
#: Skin colour (RGB, 0..1) of the hand.
SKIN = (0.88, 0.68, 0.56)
#: Seconds the hand takes to leave the frame after release.
HAND_EXIT_TIME = 0.4


class View(NamedTuple):
    """An orthographic front view of the x-z plane.

    Attributes:
        centre: (2,) world (x, z) in m at the image centre.
        scale: pixels per metre.
        width: image width in px.
        height: image height in px.
    """

    centre: tuple[float, float]
    scale: float
    width: int
    height: int

    @property
    def extent(self) -> float:
        """Vertical extent of the view in m (MuJoCo's orthographic ``fovy``)."""
        return self.height / self.scale

    @property
    def foot_pixel(self) -> tuple[float, float]:
        """Pixel (u, v) of the world origin (the ramp foot in the plane y = 0)."""
        return self.world_to_pixel(np.zeros(2)).tolist()

    def world_to_pixel(self, xz: np.ndarray) -> np.ndarray:
        """(..., 2) world (x, z) in m -> (..., 2) pixels (u, v)."""
        xz = np.asarray(xz, dtype=float)
        u = (self.width / 2 - 0.5) + (xz[..., 0] - self.centre[0]) * self.scale
        v = (self.height / 2 - 0.5) - (xz[..., 1] - self.centre[1]) * self.scale
        return np.stack([u, v], axis=-1)

    def top(self) -> float:
        """World z (m) of the image's top edge."""
        return self.centre[1] + 0.5 * self.extent

    def camera_block(self) -> Camera:
        """The scene's ``camera`` block for this view: exact scale and foot pixel, roll 0."""
        return Camera(pixels_per_metre=self.scale, ramp_direction="right", roll_deg=0.0,
                      foot_pixel=tuple(self.foot_pixel))


def object_half_extent(scene: Scene, i: int) -> float:
    """Radius (m) of a circle around object ``i``'s centre that contains it in any pose."""
    obj = scene.objects[i]
    if obj.shape == "box":
        return 0.5 * math.hypot(obj.size[0], obj.size[2])
    if obj.shape == "cylinder":
        return math.hypot(obj.size[0], 0.5 * obj.size[1])
    return obj.size[0]


def frame_view(scene: Scene, positions: np.ndarray, width: int, height: int, margin: float = 0.04) -> View:
    """Frame the whole ramp, the objects' paths and a strip of table.

    Args:
        scene: the scene.
        positions: (N, n_objects, 2) world (x, z) of the object centres in m over the video.
        width, height: image size in px.
        margin: free border around the content in m.

    Returns:
        A :class:`View` whose scale (px/m) is an integer, the largest that fits.
    """
    th, L = scene.ramp.angle, scene.ramp.length
    r = np.array([object_half_extent(scene, i) for i in range(scene.n_objects)])
    x_lo = min(-L * math.cos(th), float(np.min(positions[..., 0] - r)))
    x_hi = max(0.05, float(np.max(positions[..., 0] + r)))
    z_lo = -0.03
    z_hi = max(L * math.sin(th), float(np.max(positions[..., 1] + r)))
    x_lo, x_hi, z_lo, z_hi = x_lo - margin, x_hi + margin, z_lo - margin, z_hi + margin
    scale = float(math.floor(min(width / (x_hi - x_lo), height / (z_hi - z_lo))))
    return View(((x_lo + x_hi) / 2, (z_lo + z_hi) / 2), scale, width, height)


def checker_texture(rgb, n: int = 64, checks: int = 4, seed: int = 0) -> np.ndarray:
    """A checker texture with a random shade per square (breaks the periodicity for KLT).

    Args:
        rgb: (3,) base colour, 0..1.
        n: texture size in texels.
        checks: squares per side.
        seed: seed of the shade pattern.

    Returns:
        (n, n, 3) uint8 image.
    """
    rng = np.random.default_rng(seed)
    base = np.asarray(rgb, dtype=float)
    dark = 0.1 + 0.3 * base
    idx = np.arange(n) * checks // n
    parity = (idx[:, None] + idx[None, :]) % 2
    shade = rng.uniform(0.8, 1.15, size=(checks, checks))[idx[:, None], idx[None, :]]
    img = np.where(parity[..., None] == 0, base, dark) * shade[..., None]
    return np.clip(255 * img, 0, 255).astype(np.uint8)


def speckle_texture(rgb, n: int = 32, spot: float = 0.7, frac: float = 0.25, seed: int = 0) -> np.ndarray:
    """A skin/cloth texture: base colour with random darker texels ((n, n, 3) uint8)."""
    rng = np.random.default_rng(seed)
    base = np.asarray(rgb, dtype=float)
    img = np.broadcast_to(base, (n, n, 3)).copy()
    mask = rng.random((n, n)) < frac
    img[mask] *= spot
    img *= rng.uniform(0.95, 1.05, size=(n, n, 1))
    return np.clip(255 * img, 0, 255).astype(np.uint8)


def _set_cube_texture(spec: mujoco.MjSpec, name: str, img: np.ndarray, create: bool = False) -> None:
    """Give cube texture ``name`` the image ``img`` (n, n, 3) on all six faces."""
    tex = spec.add_texture(name=name, type=mujoco.mjtTexture.mjTEXTURE_CUBE) if create else spec.texture(name)
    tex.builtin = mujoco.mjtBuiltin.mjBUILTIN_NONE
    tex.width, tex.height, tex.nchannel = img.shape[1], img.shape[0], 3
    tex.data = np.ascontiguousarray(img).tobytes()


def _add_scenery(spec: mujoco.MjSpec, scene: Scene, view: View) -> None:
    """Backdrop wall, table under the floor and a wedge under the ramp (visual only).

    The table reaches the floor's length or the view's right edge, whichever is further (the
    floor plane is unbounded for the physics, so an object may slide past ``floor.length``).
    """
    th, L, W = scene.ramp.angle, scene.ramp.length, scene.ramp.width
    world = spec.worldbody
    vis = dict(contype=0, conaffinity=0, group=1)
    spec.add_texture(name="wall_tex", type=mujoco.mjtTexture.mjTEXTURE_2D, builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT,
                     rgb1=[0.86, 0.87, 0.88], rgb2=[0.7, 0.72, 0.75], width=64, height=64)
    spec.add_material(name="wall_mat", textures=["", "wall_tex"], texrepeat=[1, 1])
    world.add_geom(name="backdrop", type=mujoco.mjtGeom.mjGEOM_BOX, pos=[0.0, W / 2 + 0.4, 0.0],
                   size=[6.0, 0.01, 6.0], material="wall_mat", **vis)
    table_len = max(scene.floor.length, view.centre[0] + 0.5 * view.width / view.scale + 0.05)
    world.add_geom(name="table", type=mujoco.mjtGeom.mjGEOM_BOX, pos=[table_len / 2, 0.0, -0.5005],
                   size=[table_len / 2, W / 2, 0.5], rgba=[0.45, 0.33, 0.22, 1.0], **vis)
    x0, z0 = -L * math.cos(th), L * math.sin(th)
    verts = []
    for y in (-W / 2, W / 2):
        verts += [x0, y, z0 - 0.0005, 0.0, y, -0.0005, x0, y, -0.0005]
    spec.add_mesh(name="wedge_mesh", uservert=verts)
    world.add_geom(name="wedge", type=mujoco.mjtGeom.mjGEOM_MESH, meshname="wedge_mesh",
                   rgba=[0.6, 0.47, 0.33, 1.0], **vis)


def _add_hand(spec: mujoco.MjSpec, scene: Scene) -> None:
    """A skin-coloured hand gripping object 1 from above, with its forearm and sleeve.

    A mocap body (no joints, no collisions) named :data:`HAND` whose frame is object 1's top
    centre, rotated with the ramp; :func:`hand_pose` moves it.
    """
    obj = scene.objects[0]
    w = obj.size[1] if obj.shape == "box" else 2 * obj.size[0]
    half = 0.5 * obj.length
    _set_cube_texture(spec, "skin_tex", speckle_texture(SKIN, seed=1), create=True)
    spec.add_material(name="skin_mat", textures=["", "skin_tex"])
    _set_cube_texture(spec, "sleeve_tex", checker_texture((0.2, 0.25, 0.5), n=64, checks=8, seed=2), create=True)
    spec.add_material(name="sleeve_mat", textures=["", "sleeve_tex"])
    body = spec.worldbody.add_body(name=HAND, mocap=True)
    vis = dict(contype=0, conaffinity=0, group=2, material="skin_mat")
    caps = mujoco.mjtGeom.mjGEOM_CAPSULE
    body.add_geom(name="palm", type=mujoco.mjtGeom.mjGEOM_ELLIPSOID, pos=[-0.2 * half, 0.0, 0.022],
                  size=[1.1 * half, 0.5 * w + 0.012, 0.02], **vis)
    # Fingers behind the object (their tips show above it) and a thumb on the near face.
    back, front = 0.5 * w + 0.008, -0.5 * w - 0.009
    for j, dx in enumerate(np.linspace(-0.6 * half, 0.7 * half, 4)):
        body.add_geom(name=f"finger{j}", type=caps, fromto=[dx, back, 0.02, dx + 0.004, back, -0.012],
                      size=[0.0075, 0, 0], **vis)
    body.add_geom(name="thumb", type=caps, fromto=[-0.5 * half, front, 0.02, -0.15 * half, front, -0.004],
                  size=[0.0085, 0, 0], **vis)
    body.add_geom(name="forearm", type=caps, fromto=[-0.6 * half, 0.0, 0.04, -0.2, 0.03, 0.34],
                  size=[0.024, 0, 0], **vis)
    body.add_geom(name="sleeve", type=caps, fromto=[-0.17, 0.03, 0.3, -0.35, 0.06, 0.8], size=[0.036, 0, 0],
                  contype=0, conaffinity=0, group=2, material="sleeve_mat")


def hand_rest_pose(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """(3,) position in m and (4,) quaternion of the hand holding object 1 at its start."""
    centre, quat = object_start_pose(scene, 0)
    th = scene.ramp.angle if scene.placement(0) == "ramp" else 0.0
    normal = np.array([math.sin(th), 0.0, math.cos(th)])
    return centre + 0.5 * scene.objects[0].height * normal, np.asarray(quat, dtype=float)


def hand_position(scene: Scene, view: View, t: float, release_time: float,
                  exit_time: float = HAND_EXIT_TIME) -> np.ndarray:
    """World position (3,) in m of the hand at video time ``t`` (s).

    At rest on object 1 until ``release_time``, then it lifts up and back (smoothstep in time)
    and is above the image's top edge after ``exit_time`` s.
    """
    p0, _ = hand_rest_pose(scene)
    s = float(np.clip((t - release_time) / exit_time, 0.0, 1.0))
    ease = s * s * (3.0 - 2.0 * s)
    rise = view.top() - (p0[2] - 0.05) + 0.05
    return p0 + ease * np.array([-0.35 * rise, 0.0, rise])


def build_render_model(scene: Scene, view: View, timestep: float, hand: bool = False,
                       effects=()) -> mujoco.MjModel:
    """Compile the scene's model with scenery, textures, the front camera and optionally a hand.

    Args:
        scene: the scene.
        view: the camera framing.
        timestep: physics timestep in s (kept for consistency; rendering does not step).
        hand: add the hand mocap body.
        effects: the simulated effects (:class:`~galileo_jax.effects.Effect` objects or names:
            the scene's own and any hidden ones); their ``build`` hooks change what is drawn (``rolling``
            draws a round object as its cylinder). They keep the qpos layout.

    Returns:
        The compiled :class:`mujoco.MjModel` (offscreen buffer sized to the view).
    """
    spec = build_spec(scene, resolve_effects(list(effects)))
    spec.option.timestep = timestep
    spec.visual.global_.offwidth = max(view.width, 64)
    spec.visual.global_.offheight = max(view.height, 64)
    spec.visual.quality.shadowsize = 2048
    for i, obj in enumerate(scene.objects):
        rgba = obj.rgba or OBJECT_COLOURS[i % 2]
        _set_cube_texture(spec, f"object{i + 1}_tex", checker_texture(rgba[:3], seed=10 + i))
    _add_scenery(spec, scene, view)
    spec.geom("ramp_block").group = 4  # replaced by the wedge; group 4 is not drawn
    sun = spec.light("sun")
    sun.type = mujoco.mjtLightType.mjLIGHT_DIRECTIONAL  # no spotlight cone edge on the backdrop
    sun.castshadow = False  # the hand's shadow would sweep the backdrop after it left the frame
    if hand:
        _add_hand(spec, scene)
    s2 = math.sqrt(0.5)
    cam = spec.worldbody.add_camera(name=CAMERA, pos=[view.centre[0], -3.0, view.centre[1]], quat=[s2, s2, 0.0, 0.0],
                                    fovy=view.extent)
    cam.proj = mujoco.mjtProjection.mjPROJ_ORTHOGRAPHIC
    return spec.compile()
