"""Scene -> MuJoCo model, built with :class:`mujoco.MjSpec`.

Design (measured for MJX 3.17, see issue 2 and ``tests/test_physics.py``):

* The floor is a plane (z = 0); the ramp is a second plane tilted by theta through the foot
  line. Collision treats planes as half-spaces, so together they give exactly the
  ramp-and-floor profile; their ``size`` only limits what is drawn.
* Objects collide only through explicit contact pairs (default contacts are off:
  ``contype = conaffinity = 0``), and each pair carries its own friction. MuJoCo would
  otherwise combine two geoms' friction by taking the maximum; with pairs, the pair's
  friction *is* the effective sliding friction coefficient of the object on that surface,
  so k1 and k2 mean what they say (proved in ``tests/test_physics.py``).
* Object 1 and the floor/ramp: ``condim 3`` (sliding friction), pyramidal cones and the
  Newton solver (elliptic cones give NaN tangents in MJX). Object-object impacts are
  frictionless (``condim 1``) with MuJoCo's default ``solref`` (rebound ratio ~0.1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from galileo_jax.scene import MAX_RAMP_THICKNESS, Scene, SceneObject

#: Nominal mass (kg) given to free masses when the model is built; the simulator rescales.
NOMINAL_MASS = 0.5
#: Nominal friction coefficient given to free frictions when the model is built.
NOMINAL_FRICTION = 0.3
#: Default object colours (RGBA), object 1 and object 2.
OBJECT_COLOURS = ((0.85, 0.25, 0.2, 1.0), (0.2, 0.45, 0.85, 1.0))


@dataclass(frozen=True)
class ModelIndex:
    """Indices into the compiled model that the simulator needs (static, not traced).

    Attributes:
        body: (n_obj,) body id of each object.
        qpos: (n_obj,) address of each object's free-joint position in ``qpos``.
        dof: (n_obj,) address of each object's first free-joint dof in ``qvel``.
        pairs: per object, the contact-pair ids that carry its friction (ramp, floor).
        object_pair: id of the object-object pair, or -1.
        ramp_pair: per object, id of its pair with the ramp, or -1 (it starts on the floor).
        floor_pair: per object, id of its pair with the floor.
    """

    body: tuple[int, ...]
    qpos: tuple[int, ...]
    dof: tuple[int, ...]
    pairs: tuple[tuple[int, ...], ...]
    object_pair: int
    ramp_pair: tuple[int, ...] = ()
    floor_pair: tuple[int, ...] = ()


def _rot_y(angle: float) -> list[float]:
    """Quaternion (w, x, y, z) of a rotation by ``angle`` (rad) about the world y axis."""
    return [math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0]


def object_poses(index: ModelIndex, qpos, xp=np):
    """Each object's centre x, z (m) and pitch about the world y axis (rad) from ``qpos``.

    Args:
        index: the model's :class:`ModelIndex` (free-joint addresses).
        qpos: (..., nq) joint positions (NumPy or JAX).
        xp: the array module, ``numpy`` (C MuJoCo) or ``jax.numpy`` (MJX, traceable).

    Returns:
        (..., n_objects, 3) poses; pitch = 2 atan2(q_y, q_w) of the free joint's quaternion.
    """
    rows = [xp.stack([qpos[..., a], qpos[..., a + 2], 2.0 * xp.arctan2(qpos[..., a + 5], qpos[..., a + 3])], axis=-1)
            for a in index.qpos]
    return xp.stack(rows, axis=-2)


def object_start_pose(scene: Scene, i: int) -> tuple[np.ndarray, list[float]]:
    """Centre position (3,) in m and orientation quaternion (4,) of object ``i`` at rest.

    Object on the ramp: centre = -s t + (h/2 + d) n with t = (cos, 0, -sin) theta the downhill
    tangent, n = (sin, 0, cos) theta the surface normal and d the ramp board's thickness
    (``scene.ramp.thickness``, 0 for a flush ramp); on the floor: (s, 0, h/2).
    """
    obj = scene.objects[i]
    s, h = obj.start, obj.height
    if scene.placement(i) == "ramp":
        th = scene.ramp.angle
        t = np.array([math.cos(th), 0.0, -math.sin(th)])
        n = np.array([math.sin(th), 0.0, math.cos(th)])
        return -s * t + (0.5 * h + scene.ramp.thickness) * n, _rot_y(th)
    return np.array([s, 0.0, 0.5 * h]), [1.0, 0.0, 0.0, 0.0]


def _add_object_geom(body: mujoco.MjsBody, obj: SceneObject, name: str, rgba) -> None:
    kind = {"box": mujoco.mjtGeom.mjGEOM_BOX, "cylinder": mujoco.mjtGeom.mjGEOM_CYLINDER,
            "sphere": mujoco.mjtGeom.mjGEOM_SPHERE}[obj.shape]
    if obj.shape == "box":
        size = [v / 2 for v in obj.size]
    elif obj.shape == "cylinder":
        size = [obj.size[0], obj.size[1] / 2, 0.0]
    else:
        size = [obj.size[0], 0.0, 0.0]
    body.add_geom(name=name, type=kind, size=size + [0.0] * (3 - len(size)),
                  mass=obj.mass or NOMINAL_MASS, contype=0, conaffinity=0, rgba=list(rgba),
                  material=f"{name}_mat")


@dataclass(frozen=True)
class WorldPhysics:
    """Physics a rendered video may have that the fitted model does not (for ``synth`` only).

    Real setups differ from the model in ways no parameter of it describes; videos rendered with
    these test whether inference and model criticism hold on data the model cannot reproduce
    exactly. The default is the model's own physics.

    Attributes:
        cone: friction cone of the object-surface contacts: ``"pyramidal"`` (the model's; MJX
            needs it) or ``"elliptic"`` (MuJoCo's other, exact Coulomb cone).
        ramp_thickness: the true thickness of the ramp board in m, in place of the scene's
            ``ramp.thickness`` (which the fitted model uses): > 0 makes the ramp a board (a box)
            lying on the floor at its foot, its top face the sliding surface, so an object
            leaves it over an edge and drops ``ramp_thickness * cos(theta)`` onto the floor;
            0: the scene's own ramp.
    """

    cone: str = "pyramidal"
    ramp_thickness: float = 0.0

    def __post_init__(self):
        if self.cone not in ("pyramidal", "elliptic"):
            raise ValueError(f"cone {self.cone!r}: give pyramidal or elliptic")
        if not (math.isfinite(self.ramp_thickness) and 0.0 <= self.ramp_thickness <= MAX_RAMP_THICKNESS):
            raise ValueError(f"ramp thickness {self.ramp_thickness} m: give 0 to {MAX_RAMP_THICKNESS:g} m")


def apply_world_physics(spec: mujoco.MjSpec, scene: Scene, world: WorldPhysics) -> None:
    """Change a scene's :func:`build_spec` in place to ``world``'s physics (see
    :class:`WorldPhysics`): the friction cone, and a ramp board of ``world.ramp_thickness`` m in
    place of the scene's (:func:`set_ramp_board`)."""
    if world.cone == "elliptic":
        spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    if world.ramp_thickness > 0:
        set_ramp_board(spec, scene, world.ramp_thickness)


def set_ramp_board(spec: mujoco.MjSpec, scene: Scene, thickness: float) -> None:
    """Make the ramp of a scene's :func:`build_spec` (built with ``scene.ramp.thickness``) a
    board (a box) ``thickness`` (> 0) m thick whose bottom face is the ramp plane, so its foot
    edge rests on the floor, with the objects on the ramp moved onto its top face."""
    th, L, W = scene.ramp.angle, scene.ramp.length, scene.ramp.width
    tangent = np.array([math.cos(th), 0.0, -math.sin(th)])
    normal = np.array([math.sin(th), 0.0, math.cos(th)])
    ramp = spec.geom("ramp")
    ramp.type = mujoco.mjtGeom.mjGEOM_BOX
    ramp.size = [L / 2, W / 2, thickness / 2]
    ramp.pos = list(-0.5 * L * tangent + 0.5 * thickness * normal)
    lift = thickness - scene.ramp.thickness
    for i in range(scene.n_objects):
        if scene.placement(i) == "ramp":
            body = spec.body(f"object{i + 1}")
            body.pos = list(np.asarray(body.pos) + lift * normal)


def build_spec(scene: Scene, effects=(), world: WorldPhysics | None = None, engine: str = "mjx") -> mujoco.MjSpec:
    """Build the MuJoCo specification of a scene (ramp, floor, objects, contact pairs).

    ``effects``: :class:`~galileo_jax.effects.Effect` objects whose ``build`` hook changes
    the structure (e.g. ``rolling``), applied last; for ``engine`` "mujoco" (the C engine's
    rollouts) then their ``c_build`` hooks (the C form of a per-step effect). ``world``:
    physics the model does not have (:class:`WorldPhysics`, rendering only), applied before
    the effects.

    Returns:
        An uncompiled :class:`mujoco.MjSpec`; :func:`build_model` compiles it. Rendering code
        may add cameras and lights before compiling.
    """
    spec = mujoco.MjSpec()
    # One model name for every scene: MJX keeps the name table's offsets as static metadata,
    # so a scene's own name would give each scene its own compiled programs.
    spec.modelname = "galileo_scene"
    opt = spec.option
    opt.gravity = [0.0, 0.0, -scene.gravity]
    opt.cone = mujoco.mjtCone.mjCONE_PYRAMIDAL
    opt.solver = mujoco.mjtSolver.mjSOL_NEWTON
    opt.iterations = 20
    opt.ls_iterations = 10
    opt.timestep = 1.0 / 240.0

    spec.add_texture(name="grid", type=mujoco.mjtTexture.mjTEXTURE_2D, builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
                     rgb1=[0.82, 0.8, 0.76], rgb2=[0.74, 0.72, 0.68], width=256, height=256)
    spec.add_material(name="surface_mat", textures=["", "grid"], texrepeat=[8, 8], texuniform=True)

    th = scene.ramp.angle
    L, W = scene.ramp.length, scene.ramp.width
    tangent = np.array([math.cos(th), 0.0, -math.sin(th)])
    ground = spec.worldbody
    ground.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, pos=[scene.floor.length / 2, 0, 0],
                   size=[scene.floor.length / 2, W / 2, 0.05], contype=0, conaffinity=0, material="surface_mat")
    ground.add_geom(name="ramp", type=mujoco.mjtGeom.mjGEOM_PLANE, pos=list(-0.5 * L * tangent),
                   quat=_rot_y(th), size=[L / 2, W / 2, 0.05], contype=0, conaffinity=0, material="surface_mat")
    # A solid block under the ramp, for looks only.
    ground.add_geom(name="ramp_block", type=mujoco.mjtGeom.mjGEOM_BOX, contype=0, conaffinity=0,
                   pos=list(-0.5 * L * tangent + np.array([0.0, 0.0, -0.01 / math.cos(th)])),
                   quat=_rot_y(th), size=[L / 2, W / 2 - 1e-3, 0.01], rgba=[0.55, 0.45, 0.35, 1], group=1)
    ground.add_light(name="sun", pos=[0, -2, 3], dir=[0, 0.6, -0.8], diffuse=[0.8, 0.8, 0.8])

    for i, obj in enumerate(scene.objects):
        pos, quat = object_start_pose(scene, i)
        rgba = obj.rgba or OBJECT_COLOURS[i % 2]
        name = f"object{i + 1}"
        spec.add_texture(name=f"{name}_tex", type=mujoco.mjtTexture.mjTEXTURE_CUBE,
                         builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER, rgb1=list(rgba[:3]),
                         rgb2=[0.1 + 0.3 * c for c in rgba[:3]], width=64, height=64)
        spec.add_material(name=f"{name}_mat", textures=["", f"{name}_tex"], texuniform=False)
        body = ground.add_body(name=name, pos=list(pos), quat=quat)
        body.add_freejoint(name=f"{name}_free")
        _add_object_geom(body, obj, name, rgba)

    for i, obj in enumerate(scene.objects):
        k = obj.friction if obj.friction is not None else NOMINAL_FRICTION
        surfaces = ["ramp", "floor"] if scene.placement(i) == "ramp" else ["floor"]
        for surf in surfaces:
            spec.add_pair(name=f"object{i + 1}_{surf}", geomname1=f"object{i + 1}", geomname2=surf,
                          condim=3, friction=[k, k, 0.005, 0.0001, 0.0001])
    if scene.n_objects == 2:
        spec.add_pair(name="object1_object2", geomname1="object1", geomname2="object2", condim=1,
                      friction=[0.0, 0.0, 0.005, 0.0001, 0.0001])
    if scene.ramp.thickness > 0:
        set_ramp_board(spec, scene, scene.ramp.thickness)
    if world is not None:
        apply_world_physics(spec, scene, world)
    for effect in effects:
        if effect.build is not None:
            effect.build(spec, scene)
    for effect in effects if engine == "mujoco" else ():
        if effect.c_build is not None:
            effect.c_build(spec, scene)
    return spec


def build_model(scene: Scene, timestep: float | None = None, effects=(),
                world: WorldPhysics | None = None, engine: str = "mjx") -> tuple[mujoco.MjModel, ModelIndex]:
    """Compile the scene's MuJoCo model.

    Args:
        scene: the validated scene.
        timestep: physics timestep in s (default 1/240 s).
        effects: effects whose ``build`` hooks change the model's structure.
        world: physics the model does not have (:class:`WorldPhysics`; rendering only).
        engine: "mujoco" for the C engine's rollouts (the effects' ``c_build`` hooks added),
            else "mjx".

    Returns:
        ``(model, index)``: the compiled :class:`mujoco.MjModel` and the :class:`ModelIndex`
        of the ids the simulator needs.
    """
    spec = build_spec(scene, effects, world, engine)
    if timestep is not None:
        spec.option.timestep = timestep
    model = spec.compile()
    return model, model_index(model, scene.n_objects)


def model_index(model: mujoco.MjModel, n_objects: int) -> ModelIndex:
    """Look up body, joint and pair ids of the objects in a compiled scene model."""
    bodies, qpos, dofs, pairs, ramp, floor = [], [], [], [], [], []
    for i in range(1, n_objects + 1):
        b = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"object{i}")
        j = model.body_jntadr[b]
        bodies.append(int(b))
        qpos.append(int(model.jnt_qposadr[j]))
        dofs.append(int(model.jnt_dofadr[j]))
        ids = []
        for surf, out in (("ramp", ramp), ("floor", floor)):
            pid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_PAIR, f"object{i}_{surf}")
            out.append(int(pid))
            if pid >= 0:
                ids.append(int(pid))
        pairs.append(tuple(ids))
    op = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_PAIR, "object1_object2")
    return ModelIndex(tuple(bodies), tuple(qpos), tuple(dofs), tuple(pairs), int(op), tuple(ramp), tuple(floor))


#: The model fields :func:`set_physics` writes (the C engine restores them before it reuses a
#: model copy: :func:`galileo_jax.physics.simulate_c._checkout_models`).
PHYSICS_FIELDS = ("body_mass", "body_inertia", "pair_friction")


def set_physics(model: mujoco.MjModel, data: mujoco.MjData, index: ModelIndex, mass, friction) -> None:
    """Write masses and frictions into a C model, as ``simulate.apply_params`` does in MJX.

    The renderer (:mod:`galileo_jax.synth`) and the C engine (:mod:`galileo_jax.physics.simulate_c`)
    both set the physics through it, so that a rendered video and a fitted rollout agree.

    Args:
        model, data: the C model (changed in place) and a data for it.
        index: the model's :class:`ModelIndex`.
        mass: (n_objects,) masses in kg: ``body_mass``, with ``body_inertia`` scaled by
            m_i / m_i0.
        friction: (n_objects,) sliding friction coefficients: ``pair_friction[pid, 0:2]`` of
            each pair of object i with the ramp and floor.

    ``mj_setConst`` then recomputes ``body_invweight0`` / ``dof_invweight0``.
    """
    for i, b in enumerate(index.body):
        m = float(mass[i])
        model.body_inertia[b] *= m / model.body_mass[b]
        model.body_mass[b] = m
        for pid in index.pairs[i]:
            model.pair_friction[pid, 0:2] = float(friction[i])
    mujoco.mj_setConst(model, data)
