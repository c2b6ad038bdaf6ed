"""Scene files: what a video shows, validated.

A scene file is YAML. It describes the ramp (angle, length), the horizontal floor it runs
into, one or two free objects (shape, size, start position, known or free mass and friction
coefficient), the camera calibration (pixels per metre, or two image points a known distance
apart; the image direction in which object 1 moves down the ramp), the frame rate (read from
the video unless given) and optional start pixels of each object.

World frame (SI units, metres): x is horizontal, positive in the direction object 1 moves
down the ramp; z is up; the ramp's foot line is the y axis. The floor is z = 0 for x >= 0 and
the ramp surface is z = -x tan(theta) for -L cos(theta) <= x <= 0 (for a board of thickness
t, ``ramp.thickness``, that plane is its bottom face and the objects slide on the plane t above
it). An object's ``start`` is
the distance along the surface from the foot line to the point under its centre (up the
slope for an object on the ramp, along +x for one on the floor).

Profile frame: trace "x" is the world x velocity, trace "y" the world z (vertical, up)
velocity, in m/s; the camera calibration maps image pixels to this frame.

Example::

    name: ramp_20
    ramp: {angle_deg: 20, length: 0.6}
    objects:
      - {shape: box, size: [0.08, 0.05, 0.04], start: 0.40}
      - {shape: box, size: [0.06, 0.05, 0.04], start: 0.15, mass: 0.2}
    camera: {pixels_per_metre: 800, ramp_direction: right}

Errors: :func:`load_scene` raises :class:`~galileo_jax.errors.SceneError` with one line
that names the offending key and what is expected.
"""

from __future__ import annotations

import difflib
import math
from pathlib import Path
from typing import Annotated, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from galileo_jax.errors import SceneError

PositiveFloat = Annotated[float, Field(gt=0)]
#: Object-object collisions MJX 3.17 does not implement (measured, issue 2).
UNSUPPORTED_PAIRS = (frozenset({"cylinder", "box"}), frozenset({"cylinder", "sphere"}))
Pixel = tuple[float, float]
#: Thickest ramp board a scene (or a rendered world) may have, in m.
MAX_RAMP_THICKNESS = 0.1


#: Largest relative scale tolerance a scene file or ``fit --scale-tolerance`` may give (30%).
MAX_SCALE_TOLERANCE = 0.3


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Ramp(_Strict):
    """The inclined plane: angle in degrees (0, 80), length along the surface in metres, and
    ``thickness`` in metres (0 to 0.1): 0 (the default) is a ramp surface that meets the floor
    flush at the foot line; > 0 is a board of that thickness lying on the floor (the common
    classroom setup), whose top face the objects slide on, so an object leaves it over an edge
    and drops ``thickness * cos(angle)`` onto the floor. Measure it with a ruler: a 1-2 cm board
    left out changes the velocity profile at the foot by several times the tracking noise."""

    angle_deg: float = Field(gt=0, lt=80)
    length: PositiveFloat = 1.0
    width: PositiveFloat = 0.3
    thickness: float = Field(default=0.0, ge=0.0, le=MAX_RAMP_THICKNESS)

    @property
    def angle(self) -> float:
        """Ramp angle theta in radians."""
        return math.radians(self.angle_deg)


class Floor(_Strict):
    """The horizontal surface the ramp continues into; length in metres (for drawing)."""

    length: PositiveFloat = 1.5


class Rolling(_Strict):
    """A round cross-section for the ``rolling`` effect: a cylinder of ``radius`` (m) lying
    across the slope whose moment of inertia about its axis is ``inertia_ratio`` m r^2
    (0.5 solid cylinder, 1 thin ring, (1 + (r_in / r)^2) / 2 a pipe, 0.4 a solid sphere)."""

    radius: PositiveFloat
    inertia_ratio: float = Field(default=0.5, gt=0, le=1)


class SceneObject(_Strict):
    """One free object.

    ``size``: box ``[length, width, height]`` (full extents, m; length along the motion),
    cylinder ``[radius, height]`` (standing on a flat face), sphere ``[radius]``.
    ``mass`` (kg) and ``friction`` (sliding friction coefficient on ramp and floor) are
    known when given and free parameters when ``null``/absent. ``tracker`` chooses how the
    object is followed in the video: ``features`` (KLT on its texture), ``colour`` (its
    colour against the static background, for objects without texture), ``outline`` (a round
    outline, for rolling spheres or a pipe seen end-on, whose features turn with it) or
    ``auto`` (outline for spheres; otherwise features where the object shows texture inside
    its outline, colour where it does not; see :mod:`galileo_jax.observe.track`). ``rolling`` gives a box-modelled
    round object (a pipe, a can) its true cross-section, used only when the ``rolling``
    effect is on; its radius must be half the box's height.
    """

    name: str | None = None
    shape: Literal["box", "cylinder", "sphere"] = "box"
    size: list[PositiveFloat]
    start: float = Field(ge=0)
    on: Literal["ramp", "floor"] | None = None
    mass: PositiveFloat | None = None
    friction: float | None = Field(default=None, ge=0)
    rgba: tuple[float, float, float, float] | None = None
    tracker: Literal["auto", "features", "colour", "outline"] = "auto"
    rolling: Rolling | None = None

    @model_validator(mode="after")
    def _check_size(self) -> "SceneObject":
        expected = {"box": 3, "cylinder": 2, "sphere": 1}[self.shape]
        if len(self.size) != expected:
            names = {"box": "[length, width, height]", "cylinder": "[radius, height]", "sphere": "[radius]"}
            raise ValueError(f"a {self.shape} needs size {names[self.shape]} ({expected} numbers in metres), got {self.size}")
        if self.rolling is not None:
            if self.shape != "box":
                raise ValueError("rolling: {radius, ...} is for a round object modelled as a box (shape: box)")
            if not math.isclose(self.rolling.radius, self.size[2] / 2, rel_tol=0.01):
                raise ValueError(f"rolling.radius = {self.rolling.radius} m must be half the box height "
                                 f"({self.size[2] / 2:.4g} m) so that the rolling and sliding models start at the same pose")
        return self

    @property
    def height(self) -> float:
        """Distance from the supporting surface to the object's centre, times two (m)."""
        if self.shape == "box":
            return self.size[2]
        if self.shape == "cylinder":
            return self.size[1]
        return 2 * self.size[0]

    @property
    def length(self) -> float:
        """Extent along the direction of motion (m)."""
        if self.shape == "box":
            return self.size[0]
        return 2 * self.size[0]


class Reference(_Strict):
    """Two image points (pixels) a known distance apart (m), for calibration."""

    p1: Pixel
    p2: Pixel
    distance: PositiveFloat


class Camera(_Strict):
    """Camera calibration from image pixels to the world x-z plane.

    Give ``pixels_per_metre`` or a ``reference`` (two points a known distance apart).
    ``ramp_direction`` is the image direction ("right" or "left") in which object 1 moves
    down the ramp. ``roll_deg`` is the angle (degrees, counter-clockwise as seen in the image)
    by which the image's horizontal is rotated from the world horizontal. ``start_pixels``
    optionally gives each object's centre (u, v) in the first frame, else objects are found
    automatically. ``scale_tolerance`` (relative, e.g. 0.1 = 10%) says how uncertain the scale
    is (a scale read off a hand-held ruler, a reference that is not in the plane of motion):
    the fit then carries a nuisance ``scale_error`` uniform on +-tolerance, the observed
    displacements being (1 + scale_error) times the true ones (0: the scale is exact). Unset
    (None), ``fit`` and ``diagnose`` allow their own defaults
    (:attr:`galileo_jax.config.FitConfig.scale_tolerance` and
    :attr:`galileo_jax.criticism.diagnosis.DiagnoseSettings.scale_tolerance`, both 3%): a scale read
    off a ruler in the image is rarely better than a few percent, and a few-percent scale error
    biases the frictions as much as their intervals are wide (``fit --method cnn`` and
    ``--init cnn`` take an unstated scale as exact: the network knows the base model only).
    With a perspective camera the tracked surface (an object's front face) is nearer the camera
    than the plane of the objects' centres, where the scale is measured; for motion parallel to
    the image that too is a uniform scale error (a 6 cm cube 2.2 m away: ~1.4%), so the same
    nuisance covers it.
    """

    pixels_per_metre: PositiveFloat | None = None
    reference: Reference | None = None
    ramp_direction: Literal["right", "left"] = "right"
    roll_deg: float = Field(default=0.0, ge=-45, le=45)
    start_pixels: list[Pixel] | None = None
    foot_pixel: Pixel | None = None
    scale_tolerance: float | None = Field(default=None, ge=0.0, le=MAX_SCALE_TOLERANCE)

    @model_validator(mode="after")
    def _check_scale(self) -> "Camera":
        if (self.pixels_per_metre is None) == (self.reference is None):
            raise ValueError("give exactly one of camera.pixels_per_metre or camera.reference")
        if self.reference is not None:
            (u1, v1), (u2, v2) = self.reference.p1, self.reference.p2
            if math.hypot(u2 - u1, v2 - v1) < 5:
                raise ValueError("camera.reference points are less than 5 px apart")
        return self

    @property
    def scale(self) -> float:
        """Pixels per metre in the plane of motion."""
        if self.pixels_per_metre is not None:
            return self.pixels_per_metre
        (u1, v1), (u2, v2) = self.reference.p1, self.reference.p2
        return math.hypot(u2 - u1, v2 - v1) / self.reference.distance


class Video(_Strict):
    """Video timing. ``fps`` overrides the container's frame rate (e.g. a high-speed clip
    stored at 29.97 fps); ``window`` restricts the fit to [start, end] seconds of the video."""

    fps: PositiveFloat | None = None
    window: tuple[float, float] | None = None


class Priors(_Strict):
    """Uniform prior ranges for free parameters (dissertation 4.2.5: masses and friction in (0, 1))."""

    friction: tuple[float, float] = (0.0, 1.0)
    mass: tuple[float, float] = (0.0, 1.0)

    @model_validator(mode="after")
    def _check(self) -> "Priors":
        for name, (lo, hi) in (("friction", self.friction), ("mass", self.mass)):
            if not (0 <= lo < hi):
                raise ValueError(f"priors.{name} must be [low, high] with 0 <= low < high, got [{lo}, {hi}]")
        return self


class Simulation(_Strict):
    """Physics settings. ``substeps`` physics steps per video frame (8 at ~30 fps gives the
    1/240 s timestep measured to be within 0.01 m/s of a 1/1920 s reference); ``tail`` extra
    seconds simulated after the video for the rest-position prediction; ``fit_release``: fit
    the release time (``dt_release``, s, a correction within +-``release_window`` s of the
    tracker's estimate) along with the physics (see ``galileo_jax/params.py``)."""

    substeps: int = Field(default=8, ge=1, le=64)
    tail: float = Field(default=3.0, ge=0, le=30)
    fit_release: bool = True
    release_window: float = Field(default=0.2, gt=0, le=2.0)


class Scene(_Strict):
    """A validated scene. Build with :func:`load_scene` or ``Scene.model_validate(dict)``.

    ``effects`` names physical effects (:mod:`galileo_jax.effects`) that belong to this setup
    and are always simulated with it (e.g. ``[rolling]``); ``fit --effects`` adds more.
    """

    name: str = "scene"
    ramp: Ramp
    floor: Floor = Floor()
    objects: list[SceneObject] = Field(min_length=1, max_length=2)
    camera: Camera
    video: Video = Video()
    priors: Priors = Priors()
    simulation: Simulation = Simulation()
    gravity: PositiveFloat = 9.81
    effects: list[str] = Field(default_factory=list)

    @model_validator(mode="after")
    def _check_layout(self) -> "Scene":
        placed = []
        for i, obj in enumerate(self.objects):
            where = obj.on or ("ramp" if i == 0 else "floor")
            if where == "ramp" and obj.start > self.ramp.length:
                raise ValueError(f"objects[{i}].start = {obj.start} m is beyond the ramp's length {self.ramp.length} m")
            if where == "ramp" and obj.start < obj.length / 2:
                raise ValueError(f"objects[{i}].start = {obj.start} m puts the object over the ramp's foot; it must be >= {obj.length / 2} m")
            placed.append(where)
        if len(self.objects) == 2 and placed == ["floor", "ramp"]:
            raise ValueError("object 1 must be the one on the ramp (swap the objects)")
        if len(self.objects) == 2 and placed == ["floor", "floor"]:
            raise ValueError("at least object 1 must start on the ramp")
        if self.camera.start_pixels is not None and len(self.camera.start_pixels) != len(self.objects):
            raise ValueError(f"camera.start_pixels has {len(self.camera.start_pixels)} points for {len(self.objects)} objects")
        if len(self.objects) == 2:
            shapes = frozenset(o.shape for o in self.objects)
            if shapes in UNSUPPORTED_PAIRS:
                a, b = sorted(shapes)
                raise ValueError(f"MuJoCo-MJX cannot collide a {a} with a {b}; model both objects as boxes "
                                 f"(or both as cylinders) with the same sizes")
        if self.ramp.thickness > 0:
            for i, (obj, where) in enumerate(zip(self.objects, placed)):
                if where == "ramp" and obj.shape == "cylinder":
                    raise ValueError(f"objects[{i}] is a cylinder on a ramp board (ramp.thickness > 0), and MuJoCo-MJX "
                                     "cannot collide a cylinder with a box; give ramp.thickness 0, or model it as a box")
        if len(self.objects) == 2 and placed == ["ramp", "ramp"]:
            a, b = self.objects
            if abs(a.start - b.start) < (a.length + b.length) / 2:
                raise ValueError("objects 1 and 2 overlap on the ramp")
        return self

    def placement(self, i: int) -> str:
        """Where object ``i`` starts: "ramp" or "floor"."""
        obj = self.objects[i]
        return obj.on or ("ramp" if i == 0 else "floor")

    @property
    def n_objects(self) -> int:
        return len(self.objects)

    def free_parameters(self) -> list[str]:
        """Names of free physical parameters among m1, k1, m2, k2, in that order."""
        names = []
        for i, obj in enumerate(self.objects, start=1):
            if obj.mass is None:
                names.append(f"m{i}")
            if obj.friction is None:
                names.append(f"k{i}")
        return names

    def with_scale_tolerance(self, tolerance: float) -> "Scene":
        """This scene with ``camera.scale_tolerance`` = ``tolerance`` where the camera states none
        (a stated tolerance, 0 included, is kept; ``tolerance`` <= 0 changes nothing): the
        default calibration nuisance of ``fit`` (:attr:`galileo_jax.config.FitConfig.scale_tolerance`)
        and ``diagnose`` (:attr:`galileo_jax.criticism.settings.DiagnoseSettings.scale_tolerance`)."""
        if self.camera.scale_tolerance is not None or tolerance <= 0:
            return self
        return self.model_copy(update={"camera": self.camera.model_copy(update={"scale_tolerance": float(tolerance)})})

    def mass_scale_known(self) -> bool:
        """True when a known mass fixes the absolute mass scale."""
        return any(o.mass is not None for o in self.objects)


def _known_keys(loc: tuple) -> list[str]:
    """Field names allowed at the parent of ``loc`` (for "did you mean" hints)."""
    model: type[BaseModel] | None = Scene
    for part in loc[:-1]:
        if isinstance(part, int) or model is None:
            continue
        field = model.model_fields.get(str(part))
        if field is None:
            return []
        ann = field.annotation
        args = [a for a in getattr(ann, "__args__", (ann,)) if isinstance(a, type)]
        nested = [a for a in args if issubclass(a, BaseModel)]
        if not nested:
            inner = [b for a in getattr(ann, "__args__", ()) for b in getattr(a, "__args__", (a,))]
            nested = [a for a in inner if isinstance(a, type) and issubclass(a, BaseModel)]
        model = nested[0] if nested else None
    return list(model.model_fields) if model is not None else []


def _format_validation_error(path: str, err: ValidationError) -> str:
    errors = err.errors()
    # An unknown (misspelt) key explains the "missing" errors it causes: report it first.
    errors.sort(key=lambda e: e["type"] != "extra_forbidden")
    first = errors[0]
    loc = ".".join(str(p) for p in first["loc"]) or "(top level)"
    msg = first["msg"].removeprefix("Value error, ")
    if first["type"] == "extra_forbidden":
        close = difflib.get_close_matches(str(first["loc"][-1]), _known_keys(first["loc"]), n=1)
        hint = f"did you mean '{close[0]}'?" if close else "see scenes/ramp_20.yaml for the format"
        msg = f"unknown key ({hint})"
    elif first["type"] == "missing":
        msg = "required key is missing"
    more = f" (and {len(errors) - 1} more problems)" if len(errors) > 1 else ""
    return f"scene file {path}: {loc}: {msg}{more}"


def scene_from_dict(data: dict, source: str = "<dict>") -> Scene:
    """Validate a scene given as a dict (as read from YAML).

    Raises:
        SceneError: one line naming the first bad key and what is expected.
    """
    if not isinstance(data, dict):
        raise SceneError(f"scene file {source}: expected a mapping of keys (ramp, objects, camera, ...), got {type(data).__name__}")
    try:
        return Scene.model_validate(data)
    except ValidationError as err:
        raise SceneError(_format_validation_error(source, err)) from None


def load_scene(path: str | Path) -> Scene:
    """Read and validate a YAML scene file.

    Raises:
        SceneError: the file is missing, not YAML, or not a valid scene.
    """
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"scene file {path} not found; pass --scene FILE (see scenes/ for examples)")
    try:
        data = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as err:
        line = getattr(getattr(err, "problem_mark", None), "line", None)
        where = f" at line {line + 1}" if line is not None else ""
        raise SceneError(f"scene file {path} is not valid YAML{where}; fix the syntax") from None
    return scene_from_dict(data, str(path))


def save_scene(scene: Scene, path: str | Path) -> None:
    """Write a scene as YAML (only non-default keys)."""
    data = scene.model_dump(mode="json", exclude_defaults=True)
    if "name" not in data:
        data["name"] = scene.name
    Path(path).write_text(yaml.safe_dump(data, sort_keys=False))


def scene_key(scene: Scene) -> str:
    """What of a scene changes the simulation (everything but its name, camera and video block).
    A flush ramp (``ramp.thickness`` 0) leaves the thickness out, so the key of every scene
    written before that key existed (and the shipped CNNs' scene hashes) is unchanged."""
    exclude: dict = {"name": True, "camera": True, "video": True}
    if scene.ramp.thickness == 0:
        exclude["ramp"] = {"thickness"}
    return scene.model_dump_json(exclude=exclude)
