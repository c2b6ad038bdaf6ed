"""Rendering helpers for synthetic ramp videos: camera framing, scenery, textures, the hand.

The camera looks straight at the x-z plane (the plane of motion, y = 0) from one side:

* ``direction = "right"`` (default): from -y along +y; image right is world +x.
* ``direction = "left"``: from +y along -y (the scene seen from its other side); image right
  is world -x, so object 1 moves to the left. The backdrop wall stays behind the objects and
  the light comes from the camera's side.

Image up is world +z in both. Projections:

* ``orthographic`` (default): every point maps to pixels by one exact scale (px/m) and an
  offset, at any depth.
* ``perspective``: a pinhole on the optical axis at ``distance`` D m from the plane y = 0 with
  focal length f = scale * D px, so the plane y = 0 has the view's exact scale while points
  nearer the camera (an object's front face) look larger, those behind it smaller
  (:meth:`View.project`).

Pixel convention (OpenCV): pixel (u, v) has its centre at integer coordinates, u to the
right, v down; the optical axis passes through (W/2 - 1/2, H/2 - 1/2).

Everything added here is visual only (``contype = conaffinity = 0``, static world geoms or a
mocap body without joints): the physics of the model is unchanged, and the qpos layout is the
same as :func:`galileo_jax.physics.model.build_model`'s.
"""

from __future__ import annotations

import math

from typing import NamedTuple  # noqa: E402

import cv2  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from galileo_jax.effects import resolve_effects  # noqa: E402
from galileo_jax.errors import GalileoError  # noqa: E402
from galileo_jax.physics.model import OBJECT_COLOURS, build_spec, object_start_pose  # noqa: E402
from galileo_jax.scene import Camera, Scene  # noqa: E402
from galileo_jax.textures import MAX_TEXELS, checker_texture, clutter_texture, speckle_texture  # noqa: E402

#: Name of the render camera added to the model.
CAMERA = "front"
#: Name of the hand's mocap body.
HAND = "hand"
#: Skin colour (RGB, 0..1) of the hand.
SKIN = (0.88, 0.68, 0.56)
#: Seconds the hand takes to leave the frame after release.
HAND_EXIT_TIME = 0.4
#: Camera projections (:attr:`View.projection`).
PROJECTIONS = ("orthographic", "perspective")
#: Image directions of object 1's motion (:attr:`View.direction`).
DIRECTIONS = ("right", "left")
#: Object looks: a checker texture with a random shade per square, or one flat colour.
LOOKS = ("checker", "plain")
#: Backdrops: a grey gradient wall, or a wall cluttered with posters, shelves, cables and blobs.
BACKDROPS = ("plain", "clutter")
#: Default distance (m) of the perspective camera from the plane of motion.
CAMERA_DISTANCE = 2.2
#: Perspective camera distances (m) allowed; the camera must also clear the ramp's near edge.
CAMERA_DISTANCE_RANGE = (0.5, 100.0)
#: Distance (m) of the orthographic camera from the plane y = 0 (it only has to be in front).
ORTHO_DISTANCE = 3.0
#: Gap (m) between the ramp's and table's back edge and the backdrop wall.
BACKDROP_GAP = 0.4


class View(NamedTuple):
    """A front view of the x-z plane (the plane of motion, y = 0); see the module docstring.

    Attributes:
        centre: (2,) world (x, z) in m on the optical axis (the image centre).
        scale: pixels per metre in the plane y = 0.
        width: image width in px.
        height: image height in px.
        projection: ``"orthographic"`` or ``"perspective"``.
        distance: perspective only: distance D (m) of the pinhole from the plane y = 0.
        direction: ``"right"`` (camera at -y, world +x to the image right) or ``"left"``
            (camera at +y, world +x to the image left).
    """

    centre: tuple[float, float]
    scale: float
    width: int
    height: int
    projection: str = "orthographic"
    distance: float = CAMERA_DISTANCE
    direction: str = "right"

    @property
    def sign(self) -> float:
        """+1.0 if world +x points right in the image, -1.0 if left (the camera sits at y = -sign D)."""
        return 1.0 if self.direction == "right" else -1.0

    @property
    def perspective(self) -> bool:
        return self.projection == "perspective"

    @property
    def extent(self) -> float:
        """Vertical extent of the view in m in the plane y = 0 (MuJoCo's orthographic ``fovy``)."""
        return self.height / self.scale

    @property
    def focal(self) -> float:
        """Perspective focal length f = scale * distance in px."""
        return self.scale * self.distance

    @property
    def fovy(self) -> float:
        """MuJoCo's camera ``fovy``: the extent in m (orthographic) or 2 atan((H/2) / f) in degrees."""
        if not self.perspective:
            return self.extent
        return math.degrees(2.0 * math.atan(0.5 * self.height / self.focal))

    @property
    def foot_pixel(self) -> tuple[float, float]:
        """Pixel (u, v) of the world origin (the ramp foot in the plane y = 0)."""
        return self.world_to_pixel(np.zeros(2)).tolist()

    def magnification(self, y) -> np.ndarray | float:
        """Scale at world depth ``y`` (m, array or float) relative to the plane y = 0: D / (D + sign y)
        in perspective (> 1 nearer the camera), 1 in orthographic views."""
        if not self.perspective:
            return 1.0
        return self.distance / (self.distance + self.sign * np.asarray(y, dtype=float))

    def world_to_pixel(self, xz: np.ndarray) -> np.ndarray:
        """(..., 2) world (x, z) in m of points in the plane y = 0 -> (..., 2) pixels (u, v)."""
        return self._to_pixel(np.asarray(xz, dtype=float), 1.0)

    def project(self, xyz: np.ndarray) -> np.ndarray:
        """(..., 3) world (x, y, z) in m -> (..., 2) pixels (u, v), exact for both projections.

        Perspective: u = W/2 - 1/2 + sign f (x - xc) / depth, v = H/2 - 1/2 - f (z - zc) / depth
        with depth = D + sign y the distance from the camera's plane (in front: depth > 0).
        Orthographic: y is ignored (:meth:`world_to_pixel` of (x, z)).
        """
        xyz = np.asarray(xyz, dtype=float)
        return self._to_pixel(xyz[..., [0, 2]], self.magnification(xyz[..., 1]))

    def _to_pixel(self, xz: np.ndarray, gain) -> np.ndarray:
        u = (self.width / 2 - 0.5) + self.sign * (xz[..., 0] - self.centre[0]) * self.scale * gain
        v = (self.height / 2 - 0.5) - (xz[..., 1] - self.centre[1]) * self.scale * gain
        return np.stack([u, v], axis=-1)

    def half_size(self, y: float = 0.0) -> tuple[float, float]:
        """Half width and half height in m of what the image shows of the plane at world depth ``y``."""
        m = float(self.magnification(y))
        return 0.5 * self.width / (self.scale * m), 0.5 * self.height / (self.scale * m)

    def top(self) -> float:
        """World z (m) of the image's top edge in the plane y = 0."""
        return self.centre[1] + 0.5 * self.extent

    def camera_pose(self) -> tuple[list[float], list[float]]:
        """Position (3,) in m and orientation quaternion (4,) of the camera in the world.

        The camera's -z axis (view direction) is world +y * sign, its +y axis (image up) world +z.
        """
        s2 = math.sqrt(0.5)
        dist = self.distance if self.perspective else ORTHO_DISTANCE
        quat = [s2, s2, 0.0, 0.0] if self.sign > 0 else [0.0, 0.0, s2, s2]
        return [self.centre[0], -self.sign * dist, self.centre[1]], quat

    def camera_block(self) -> Camera:
        """The scene's ``camera`` block for this view: exact scale (plane y = 0), foot pixel, direction, roll 0."""
        return Camera(pixels_per_metre=self.scale, ramp_direction=self.direction, roll_deg=0.0,
                      foot_pixel=tuple(self.foot_pixel))


def check_choice(value, choices, what: str, flag: str) -> None:
    """Raise a one-line :class:`GalileoError` unless ``value`` is one of ``choices``."""
    if value not in choices:
        raise GalileoError(f"{what} {value!r}: give one of {', '.join(choices)} ({flag})")


def check_camera(scene: Scene, projection: str, distance: float, direction: str) -> None:
    """Check camera options.

    Raises:
        GalileoError: an unknown projection or direction, or a perspective distance outside
            :data:`CAMERA_DISTANCE_RANGE` or not beyond the ramp's near edge.
    """
    check_choice(projection, PROJECTIONS, "camera", "--camera")
    check_choice(direction, DIRECTIONS, "direction", "--direction, --left")
    lo, hi = CAMERA_DISTANCE_RANGE
    near = max(lo, 0.5 * scene.ramp.width + 0.1)
    if projection == "perspective" and not (math.isfinite(distance) and near <= distance <= hi):
        raise GalileoError(f"camera distance {distance} m: give a distance in [{near:g}, {hi:g}] m from the "
                           f"plane of motion (--distance)")


def object_half_extent(scene: Scene, i: int) -> float:
    """Radius (m) of a circle around object ``i``'s centre that contains it in any pose."""
    obj = scene.objects[i]
    if obj.shape == "box":
        return 0.5 * math.hypot(obj.size[0], obj.size[2])
    if obj.shape == "cylinder":
        return math.hypot(obj.size[0], 0.5 * obj.size[1])
    return obj.size[0]


def object_half_depth(scene: Scene, i: int) -> float:
    """Half the extent (m) of object ``i`` across the plane of motion (along its body y axis):
    half a box's width (also when ``rolling`` draws it as a cylinder across the slope), a
    cylinder's or sphere's radius."""
    obj = scene.objects[i]
    return 0.5 * obj.size[1] if obj.shape == "box" else obj.size[0]


def front_offsets(scene: Scene, view: View) -> np.ndarray:
    """(n_objects, 3) body-frame offsets (m) from each object's centre to the centre of its face
    nearest the camera (its surface point nearest the camera for a cylinder or sphere)."""
    return np.array([[0.0, -view.sign * object_half_depth(scene, i), 0.0] for i in range(scene.n_objects)])


def outline_points(scene: Scene, i: int, n_round: int = 48) -> np.ndarray:
    """(P, 3) body-frame points (m) of object ``i`` whose projections' convex hull is its
    silhouette in any pose and either projection (the object is convex): a box's 8 corners; a
    round object's two rim circles (``n_round`` points each; a cylinder stands on its end, a
    ``rolling`` box is drawn as a cylinder across the slope, radius half its height); a
    sphere's ``8 n_round`` points spread evenly over it (Fibonacci lattice)."""
    obj = scene.objects[i]
    a = 2.0 * np.pi * np.arange(n_round) / n_round
    ring = np.stack([np.cos(a), np.sin(a)], axis=-1)
    if obj.shape == "box" and obj.rolling is None:
        L, W, H = (0.5 * float(x) for x in obj.size)
        return np.array([[sx * L, sy * W, sz * H] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    if obj.shape == "box":  # a rolling box: its cylinder, axis along body y
        r, h = 0.5 * float(obj.size[2]), 0.5 * float(obj.size[1])
        return np.concatenate([np.stack([r * ring[:, 0], np.full(n_round, y), r * ring[:, 1]], -1) for y in (-h, h)])
    if obj.shape == "cylinder":  # axis along body z
        r, h = float(obj.size[0]), 0.5 * float(obj.size[1])
        return np.concatenate([np.concatenate([r * ring, np.full((n_round, 1), z)], -1) for z in (-h, h)])
    n = 8 * n_round
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5.0 ** 0.5) * k
    rho = np.sqrt(1.0 - z * z)
    return float(obj.size[0]) * np.stack([rho * np.cos(phi), rho * np.sin(phi), z], axis=-1)


def silhouettes(view: "View", points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroids and areas of the convex hulls of projected point sets.

    Args:
        view: the camera.
        points: (..., P, 3) world points (m) of one convex object per leading index
            (:func:`outline_points` placed in the world).

    Returns:
        ``(centroids, areas)``: (..., 2) the area centroid (u, v) in px of each set's projected
        convex hull (where the centroid of the object's image lies when all of it is seen) and
        (...,) its area in px^2.
    """
    px = view.project(points)
    flat = px.reshape(-1, *px.shape[-2:])
    centroids, areas = np.empty((len(flat), 2)), np.empty(len(flat))
    for j, pts in enumerate(flat):
        m = cv2.moments(cv2.convexHull(pts.astype(np.float32)))
        areas[j] = m["m00"]
        centroids[j] = (m["m10"] / m["m00"], m["m01"] / m["m00"]) if m["m00"] > 1e-9 else pts.mean(axis=0)
    return centroids.reshape(*px.shape[:-2], 2), areas.reshape(px.shape[:-2])


def rotate(quat: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate (..., 3) vectors by (..., 4) unit quaternions (w, x, y, z) -> (..., 3)."""
    quat, v = np.asarray(quat, dtype=float), np.asarray(v, dtype=float)
    t = 2.0 * np.cross(quat[..., 1:], v)
    return v + quat[..., :1] * t + np.cross(quat[..., 1:], t)


def body_points(qpos: np.ndarray, qpos_adr, local) -> np.ndarray:
    """World positions of one point fixed in each object.

    Args:
        qpos: (..., nq) generalised positions (free joints: position in m, quaternion).
        qpos_adr: (n_objects,) each object's free-joint address in ``qpos``.
        local: (n_objects, 3) the point in each object's body frame in m (zeros: the centres).

    Returns:
        (..., n_objects, 3) world (x, y, z) in m.
    """
    qpos = np.asarray(qpos, dtype=float)
    pos = np.stack([qpos[..., a:a + 3] for a in qpos_adr], axis=-2)
    quat = np.stack([qpos[..., a + 3:a + 7] for a in qpos_adr], axis=-2)
    return pos + rotate(quat, np.broadcast_to(np.asarray(local, dtype=float), pos.shape))


def object_colours(scene: Scene, colours=None) -> list[tuple[float, float, float]]:
    """Each object's base colour (RGB, 0..1).

    Args:
        scene: the scene.
        colours: None (the scene's ``rgba`` of each object, else :data:`OBJECT_COLOURS`) or
            (n_objects, 3) RGB in [0, 1], one per object.

    Raises:
        GalileoError: a component outside [0, 1] or not a number, or not one colour per object.
    """
    if colours is None:
        return [tuple(float(c) for c in (obj.rgba or OBJECT_COLOURS[i % 2])[:3]) for i, obj in enumerate(scene.objects)]
    try:
        rows = [np.asarray(c, dtype=float).reshape(-1) for c in colours]
    except (TypeError, ValueError):
        raise GalileoError("colours must be a list of R,G,B triples in [0, 1], one per object") from None
    for c in rows:
        if c.shape != (3,) or not np.all((c >= 0) & (c <= 1)):
            raise GalileoError(f"colour {','.join(f'{x:g}' for x in c)}: give R,G,B with each component in [0, 1] "
                               f"(--colour 0.2,0.5,0.9)")
    if len(rows) != scene.n_objects:
        raise GalileoError(f"{len(rows)} colour(s) for {scene.n_objects} object(s): give one R,G,B per object "
                           f"(--colour once per object)")
    return [tuple(float(x) for x in c) for c in rows]


def frame_view(scene: Scene, positions: np.ndarray, width: int, height: int, margin: float = 0.04, *,
               projection: str = "orthographic", distance: float = CAMERA_DISTANCE,
               direction: str = "right") -> View:
    """Frame the whole ramp, the objects' paths and a strip of table (in the plane y = 0).

    Args:
        scene: the scene.
        positions: (N, n_objects, 2) world (x, z) of the object centres in m over the video.
        width, height: image size in px.
        margin: free border around the content in m (in perspective it also takes the slightly
            larger image of the objects' near faces).
        projection, distance, direction: the camera (see :class:`View`; ``distance`` in m is
            used in perspective only).

    Returns:
        A :class:`View` whose scale (px/m) is an integer, the largest that fits.

    Raises:
        GalileoError: bad camera options (:func:`check_camera`).
    """
    check_camera(scene, projection, distance, direction)
    th, L = scene.ramp.angle, scene.ramp.length
    r = np.array([object_half_extent(scene, i) for i in range(scene.n_objects)])
    x_lo = min(-L * math.cos(th), float(np.min(positions[..., 0] - r)))
    x_hi = max(0.05, float(np.max(positions[..., 0] + r)))
    z_lo = -0.03
    z_hi = max(L * math.sin(th), float(np.max(positions[..., 1] + r)))
    x_lo, x_hi, z_lo, z_hi = x_lo - margin, x_hi + margin, z_lo - margin, z_hi + margin
    scale = float(math.floor(min(width / (x_hi - x_lo), height / (z_hi - z_lo))))
    return View(((x_lo + x_hi) / 2, (z_lo + z_hi) / 2), scale, width, height, projection, float(distance), direction)


def _set_texture(spec: mujoco.MjSpec, name: str, img: np.ndarray, create: bool = False,
                 kind: mujoco.mjtTexture = mujoco.mjtTexture.mjTEXTURE_CUBE) -> None:
    """Give texture ``name`` the image ``img`` (h, w, 3) uint8 (a cube texture: on all six faces)."""
    tex = spec.add_texture(name=name, type=kind) if create else spec.texture(name)
    tex.builtin = mujoco.mjtBuiltin.mjBUILTIN_NONE
    tex.width, tex.height, tex.nchannel = img.shape[1], img.shape[0], 3
    tex.data = np.ascontiguousarray(img).tobytes()


def _add_backdrop(spec: mujoco.MjSpec, view: View, y: float, backdrop: str, seed: int) -> None:
    """The backdrop wall at world depth ``y`` (m, behind the objects): a 12 m grey gradient
    (``plain``) or a :func:`~galileo_jax.textures.clutter_texture` wall covering the view with some margin
    (``clutter``; about one texel per image pixel, at most :data:`MAX_TEXELS` a side)."""
    if backdrop == "clutter":
        hw, hh = (1.1 * s + 0.05 for s in view.half_size(y))
        tpm = min(view.scale * float(view.magnification(y)), MAX_TEXELS / (2 * max(hw, hh)))
        img = clutter_texture(max(16, round(2 * hw * tpm)), max(16, round(2 * hh * tpm)), tpm, seed)
        _set_texture(spec, "wall_tex", img, create=True, kind=mujoco.mjtTexture.mjTEXTURE_2D)
        pos, size = [view.centre[0], y, view.centre[1]], [hw, 0.01, hh]
    else:
        spec.add_texture(name="wall_tex", type=mujoco.mjtTexture.mjTEXTURE_2D,
                         builtin=mujoco.mjtBuiltin.mjBUILTIN_GRADIENT, rgb1=[0.86, 0.87, 0.88], rgb2=[0.7, 0.72, 0.75],
                         width=64, height=64)
        pos, size = [0.0, y, 0.0], [6.0, 0.01, 6.0]
    spec.add_material(name="wall_mat", textures=["", "wall_tex"], texrepeat=[1, 1])
    spec.worldbody.add_geom(name="backdrop", type=mujoco.mjtGeom.mjGEOM_BOX, pos=pos, size=size, material="wall_mat",
                            contype=0, conaffinity=0, group=1)


def _add_scenery(spec: mujoco.MjSpec, scene: Scene, view: View, backdrop: str = "plain", seed: int = 0) -> None:
    """Backdrop wall (behind the objects as the camera sees them), table under the floor and a
    wedge under the ramp (visual only).

    The table reaches the floor's length or the view's edge on the +x side at the table's back
    edge, whichever is further (the floor plane is unbounded for the physics, so an object may
    slide past ``floor.length``).
    """
    th, L, W = scene.ramp.angle, scene.ramp.length, scene.ramp.width
    world = spec.worldbody
    vis = dict(contype=0, conaffinity=0, group=1)
    _add_backdrop(spec, view, view.sign * (W / 2 + BACKDROP_GAP), backdrop, seed)
    table_len = max(scene.floor.length, view.centre[0] + view.half_size(view.sign * W / 2)[0] + 0.05)
    world.add_geom(name="table", type=mujoco.mjtGeom.mjGEOM_BOX, pos=[table_len / 2, 0.0, -0.5005],
                   size=[table_len / 2, W / 2, 0.5], rgba=[0.45, 0.33, 0.22, 1.0], **vis)
    x0, z0 = -L * math.cos(th), L * math.sin(th)
    verts = []
    for y in (-W / 2, W / 2):
        verts += [x0, y, z0 - 0.0005, 0.0, y, -0.0005, x0, y, -0.0005]
    spec.add_mesh(name="wedge_mesh", uservert=verts)
    world.add_geom(name="wedge", type=mujoco.mjtGeom.mjGEOM_MESH, meshname="wedge_mesh",
                   rgba=[0.6, 0.47, 0.33, 1.0], **vis)


def _add_hand(spec: mujoco.MjSpec, scene: Scene, side: float = 1.0) -> None:
    """A skin-coloured hand gripping object 1 from above, with its forearm and sleeve.

    A mocap body (no joints, no collisions) named :data:`HAND` whose frame is object 1's top
    centre, rotated with the ramp; :func:`hand_pose` moves it. ``side``: the camera's side
    (:attr:`View.sign`, +1: camera at -y); the fingers go behind the object, the thumb on its
    face toward the camera.
    """
    obj = scene.objects[0]
    w = obj.size[1] if obj.shape == "box" else 2 * obj.size[0]
    half = 0.5 * obj.length
    _set_texture(spec, "skin_tex", speckle_texture(SKIN, seed=1), create=True)
    spec.add_material(name="skin_mat", textures=["", "skin_tex"])
    _set_texture(spec, "sleeve_tex", checker_texture((0.2, 0.25, 0.5), n=64, checks=8, seed=2), create=True)
    spec.add_material(name="sleeve_mat", textures=["", "sleeve_tex"])
    body = spec.worldbody.add_body(name=HAND, mocap=True)
    vis = dict(contype=0, conaffinity=0, group=2, material="skin_mat")
    caps = mujoco.mjtGeom.mjGEOM_CAPSULE
    body.add_geom(name="palm", type=mujoco.mjtGeom.mjGEOM_ELLIPSOID, pos=[-0.2 * half, 0.0, 0.022],
                  size=[1.1 * half, 0.5 * w + 0.012, 0.02], **vis)
    # Fingers behind the object (their tips show above it) and a thumb on the near face.
    back, front = side * (0.5 * w + 0.008), side * (-0.5 * w - 0.009)
    for j, dx in enumerate(np.linspace(-0.6 * half, 0.7 * half, 4)):
        body.add_geom(name=f"finger{j}", type=caps, fromto=[dx, back, 0.02, dx + 0.004, back, -0.012],
                      size=[0.0075, 0, 0], **vis)
    body.add_geom(name="thumb", type=caps, fromto=[-0.5 * half, front, 0.02, -0.15 * half, front, -0.004],
                  size=[0.0085, 0, 0], **vis)
    body.add_geom(name="forearm", type=caps, fromto=[-0.6 * half, 0.0, 0.04, -0.2, side * 0.03, 0.34],
                  size=[0.024, 0, 0], **vis)
    body.add_geom(name="sleeve", type=caps, fromto=[-0.17, side * 0.03, 0.3, -0.35, side * 0.06, 0.8],
                  size=[0.036, 0, 0], contype=0, conaffinity=0, group=2, material="sleeve_mat")


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


def _dress_object(spec: mujoco.MjSpec, i: int, rgb, look: str) -> None:
    """Object ``i``'s look: the checker texture on base colour ``rgb`` (0..1), or ``rgb`` flat (``plain``)."""
    name = f"object{i + 1}"
    geom = spec.geom(name)
    geom.rgba = [*rgb, float(geom.rgba[3])]
    if look == "plain":
        geom.material = ""
    else:
        _set_texture(spec, f"{name}_tex", checker_texture(rgb, seed=10 + i))


def build_render_model(scene: Scene, view: View, timestep: float, hand: bool = False, effects=(), *,
                       look: str = "checker", colours=None, backdrop: str = "plain", seed: int = 0,
                       world=None) -> mujoco.MjModel:
    """Compile the scene's model with scenery, object looks, the front camera and optionally a hand.

    Args:
        scene: the scene.
        view: the camera (framing, projection, side; :class:`View`).
        timestep: physics timestep in s (kept for consistency; rendering does not step).
        hand: add the hand mocap body.
        effects: the simulated effects (:class:`~galileo_jax.effects.Effect` objects or names:
            the scene's own and any hidden ones); their ``build`` hooks change what is drawn (``rolling``
            draws a round object as its cylinder). They keep the qpos layout.
        look: ``"checker"`` (a checker texture with a random shade per square on the base
            colour) or ``"plain"`` (the base colour, no texture).
        colours: (n_objects, 3) base RGB in [0, 1], or None (:func:`object_colours`).
        backdrop: ``"plain"`` (grey gradient wall) or ``"clutter"`` (:func:`~galileo_jax.textures.clutter_texture`).
        seed: seed of the cluttered backdrop.
        world: physics the model does not have (:class:`~galileo_jax.physics.model.WorldPhysics`): a
            ramp board is drawn as the box it is.

    Returns:
        The compiled :class:`mujoco.MjModel` (offscreen buffer sized to the view).

    Raises:
        GalileoError: an unknown look or backdrop, or bad colours.
    """
    check_choice(look, LOOKS, "look", "--look")
    check_choice(backdrop, BACKDROPS, "backdrop", "--backdrop")
    spec = build_spec(scene, resolve_effects(list(effects)), world)
    spec.option.timestep = timestep
    spec.visual.global_.offwidth = max(view.width, 64)
    spec.visual.global_.offheight = max(view.height, 64)
    spec.visual.quality.shadowsize = 2048
    for i, rgb in enumerate(object_colours(scene, colours)):
        _dress_object(spec, i, rgb, look)
    _add_scenery(spec, scene, view, backdrop, seed)
    spec.geom("ramp_block").group = 4  # replaced by the wedge; group 4 is not drawn
    sun = spec.light("sun")
    sun.type = mujoco.mjtLightType.mjLIGHT_DIRECTIONAL  # no spotlight cone edge on the backdrop
    sun.castshadow = False  # the hand's shadow would sweep the backdrop after it left the frame
    sun.pos, sun.dir = [0.0, -2.0 * view.sign, 3.0], [0.0, 0.6 * view.sign, -0.8]  # from the camera's side
    if hand:
        _add_hand(spec, scene, view.sign)
    pos, quat = view.camera_pose()
    cam = spec.worldbody.add_camera(name=CAMERA, pos=pos, quat=quat, fovy=view.fovy)
    cam.proj = mujoco.mjtProjection.mjPROJ_PERSPECTIVE if view.perspective else mujoco.mjtProjection.mjPROJ_ORTHOGRAPHIC
    return spec.compile()
