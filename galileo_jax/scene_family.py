"""A family of ramp scenes: the geometry and frame rate a scene-conditioned network reads.

The amortised CNN (:mod:`galileo_jax.inference.cnn`) was trained for one scene file at a time.
A *scene family* is every Physics 101 ramp scene within ranges of its geometry and frame
rate; a network trained on scenes drawn from those ranges reads, next to the velocity
profile, the scene's *features* (:data:`FEATURES`) and serves any scene inside them.

The family's scenes (:func:`family_scene`): two boxes with free masses and friction
coefficients, object 1 resting on a flush ramp (``ramp.thickness`` 0), object 2 resting on
the floor, gravity 9.81 m/s^2, no effects. Ramp and floor are MuJoCo planes, unbounded for
contacts, so their drawn lengths and widths do not change the motion and are no features.

Features, in order (SI units; :data:`DEFAULT_RANGES` gives the ranges):

==============  =====================================================  ==============
name            meaning                                                default range
==============  =====================================================  ==============
angle_deg       ramp angle (degrees)                                   5 - 45
length_1        object 1's extent along the slope (m)                  0.02 - 0.16
width_1         object 1's extent across the slope (m)                 0.02 - 0.16
height_1        object 1's height (m)                                  0.02 - 0.16
length_2        object 2's extent along the floor (m)                  0.02 - 0.16
width_2         object 2's extent across (m)                           0.02 - 0.16
height_2        object 2's height (m)                                  0.02 - 0.16
start_1         object 1's start up the slope from the foot line (m)   0.10 - 1.2
start_2         object 2's start along the floor from the foot (m)     0.0 - 0.6
fps             the video's frame rate (frames per second)             25 - 240
==============  =====================================================  ==============

A start must also clear the foot line: ``start_1 >= length_1 / 2 + FOOT_CLEARANCE`` and
``start_2 >= length_2 / 2 + FOOT_CLEARANCE`` (the scene file's own rule, :class:`~galileo_jax.scene.Scene`).
The angle range is the issue's (5-45 degrees); the sizes and starts span the blocks and cubes
of the shipped scenes and of the rendered test worlds (``benchmarks/world.py``: cubes of up to
15 cm, object 1 up to 1.1 m up a ramp) with margin; the frame rates span PAL video to
slow-motion phone clips.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from galileo_jax.errors import GalileoError
from galileo_jax.scene import Scene

#: The features of a family scene, in the order the network reads them (module docstring).
FEATURES = ("angle_deg", "length_1", "width_1", "height_1", "length_2", "width_2", "height_2",
            "start_1", "start_2", "fps")
#: Units of the features, for messages.
UNITS = {"angle_deg": "deg", "fps": "fps"}
#: Features normalised on a log scale (:meth:`SceneFamily.normalise`).
LOG_FEATURES = ("fps",)
#: Default ranges of the features (module docstring).
DEFAULT_RANGES = {
    "angle_deg": (5.0, 45.0),
    "length_1": (0.02, 0.16), "width_1": (0.02, 0.16), "height_1": (0.02, 0.16),
    "length_2": (0.02, 0.16), "width_2": (0.02, 0.16), "height_2": (0.02, 0.16),
    "start_1": (0.10, 1.2), "start_2": (0.0, 0.6),
    "fps": (25.0, 240.0),
}
#: Gap (m) kept between an object's end and the ramp's foot line at the start.
FOOT_CLEARANCE = 0.005
#: Gravity of the family's scenes (m/s^2) and the largest relative departure a scene may have.
GRAVITY = 9.81
GRAVITY_TOLERANCE = 0.01


class OutOfFamily(GalileoError):
    """A scene (or video) that the scene family does not cover; the message names the input."""


@dataclass(frozen=True)
class SceneFamily:
    """Ranges of the :data:`FEATURES` (a pytree-free, hashable description).

    Attributes:
        ranges: ((low, high), ...) per feature, in :data:`FEATURES` order.
    """

    ranges: tuple[tuple[float, float], ...] = tuple(DEFAULT_RANGES[f] for f in FEATURES)

    def __post_init__(self):
        if len(self.ranges) != len(FEATURES):
            raise ValueError(f"a scene family needs {len(FEATURES)} ranges ({', '.join(FEATURES)}), "
                             f"got {len(self.ranges)}")
        for name, (lo, hi) in zip(FEATURES, self.ranges):
            if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
                raise ValueError(f"family range of {name} must be [low, high] with low < high, got [{lo}, {hi}]")
            if name in LOG_FEATURES and lo <= 0:
                raise ValueError(f"family range of {name} must be positive, got [{lo}, {hi}]")

    @classmethod
    def from_dict(cls, ranges: dict | None) -> "SceneFamily":
        """A family from {feature: [low, high]} (features not named keep their default).

        Raises:
            ValueError: an unknown feature name or a bad range.
        """
        ranges = dict(ranges or {})
        unknown = sorted(set(ranges) - set(FEATURES))
        if unknown:
            raise ValueError(f"unknown family feature(s) {', '.join(unknown)}; known: {', '.join(FEATURES)}")
        merged = {**DEFAULT_RANGES, **{k: tuple(float(x) for x in v) for k, v in ranges.items()}}
        return cls(tuple(merged[f] for f in FEATURES))

    def to_dict(self) -> dict:
        """{feature: [low, high]} (JSON-ready)."""
        return {f: [float(lo), float(hi)] for f, (lo, hi) in zip(FEATURES, self.ranges)}

    @property
    def lower(self) -> np.ndarray:
        """(F,) lower ends."""
        return np.array([r[0] for r in self.ranges])

    @property
    def upper(self) -> np.ndarray:
        """(F,) upper ends."""
        return np.array([r[1] for r in self.ranges])

    def middle(self) -> np.ndarray:
        """(F,) the features at the middle of every range: a scene that stands for the family
        where only its kind matters (its parameter coordinates and their bounds)."""
        return 0.5 * (self.lower + self.upper)

    def normalise(self, features):
        """Features (..., F) mapped to [-1, 1] over the family's ranges (log scale for
        :data:`LOG_FEATURES`): what the network reads. NumPy or JAX in, the same out (pure)."""
        xp = jnp if isinstance(features, jax.Array) else np
        f = xp.asarray(features)
        lo, hi = self.lower, self.upper
        log = np.array([name in LOG_FEATURES for name in FEATURES])
        lo_t = np.where(log, np.log(np.where(log, lo, 1.0)), lo)
        hi_t = np.where(log, np.log(np.where(log, hi, 1.0)), hi)
        f_t = xp.where(log, xp.log(xp.where(log, f, 1.0)), f)
        return 2.0 * (f_t - lo_t) / (hi_t - lo_t) - 1.0

    def draw(self, key: jax.Array, n: int) -> jax.Array:
        """n feature vectors (n, F) drawn uniformly over the family (fps log-uniformly), each
        start drawn above its object's :data:`FOOT_CLEARANCE` (pure, jittable).

        Raises:
            ValueError: a start range that cannot clear the foot for the largest object.
        """
        idx = {f: i for i, f in enumerate(FEATURES)}
        lo, hi = self.lower, self.upper
        for obj in ("1", "2"):
            if hi[idx["start_" + obj]] < hi[idx["length_" + obj]] / 2 + FOOT_CLEARANCE:
                raise ValueError(f"start_{obj}'s range ends below the largest object's half length; widen it")
        u = jax.random.uniform(key, (n, len(FEATURES)), jnp.float64, minval=0.0, maxval=1.0)
        log = jnp.asarray([name in LOG_FEATURES for name in FEATURES])
        lo_j, hi_j = jnp.asarray(lo), jnp.asarray(hi)
        lin = lo_j + (hi_j - lo_j) * u
        lg = jnp.exp(jnp.log(jnp.where(log, lo_j, 1.0)) + (jnp.log(jnp.where(log, hi_j, 1.0))
                                                           - jnp.log(jnp.where(log, lo_j, 1.0))) * u)
        f = jnp.where(log, lg, lin)
        for obj in ("1", "2"):
            s, ln = idx["start_" + obj], idx["length_" + obj]
            low = jnp.maximum(lo[s], f[:, ln] / 2 + FOOT_CLEARANCE)
            f = f.at[:, s].set(low + (hi[s] - low) * u[:, s])
        return f

    def check(self, features, what: str = "the scene") -> None:
        """Raise :class:`OutOfFamily` naming the first feature of ``features`` (F,) outside
        the family's ranges (a relative slack of 1e-9 for values read back from files)."""
        f = np.asarray(features, np.float64).reshape(-1)
        for name, x, (lo, hi) in zip(FEATURES, f, self.ranges):
            slack = 1e-9 * max(abs(lo), abs(hi), 1.0)
            if not (lo - slack <= x <= hi + slack):
                unit = UNITS.get(name, "m")
                raise OutOfFamily(f"{what}: {name} = {x:.4g} {unit} is outside the scene-conditioned CNN's "
                                  f"training range {lo:g}-{hi:g} {unit}; use --method grad or mh, or train a "
                                  "CNN for this scene (python -m galileo_jax.train)")


def family_scene(features, name: str = "family") -> Scene:
    """The family scene of a feature vector (F,) (module docstring; nothing checked against
    the ranges): two boxes, object 1 on a flush ramp, object 2 on the floor.

    Raises:
        galileo_jax.errors.SceneError-like pydantic errors: features that make no valid scene
        (a start over the foot line).
    """
    f = dict(zip(FEATURES, (float(x) for x in np.asarray(features, np.float64).reshape(-1))))
    return Scene.model_validate({
        "name": name,
        "ramp": {"angle_deg": f["angle_deg"], "length": f["start_1"] + f["length_1"] / 2 + 0.05, "width": 0.3},
        "floor": {"length": max(1.2, f["start_2"] + 1.0)},
        "objects": [
            {"name": "object 1", "shape": "box", "size": [f["length_1"], f["width_1"], f["height_1"]],
             "start": f["start_1"]},
            {"name": "object 2", "shape": "box", "size": [f["length_2"], f["width_2"], f["height_2"]],
             "start": f["start_2"], "on": "floor"},
        ],
        "camera": {"pixels_per_metre": 1000.0, "ramp_direction": "right"},
        "video": {"fps": f["fps"]},
    })


def scene_features(scene: Scene, fps: float) -> np.ndarray:
    """The (F,) features of a user's scene filmed at ``fps`` (not checked against ranges:
    :meth:`SceneFamily.check`).

    Raises:
        OutOfFamily: the scene is not of the family's kind (one line naming what differs): not
            two boxes, object 1 not on the ramp or object 2 not on the floor, a ramp board
            (``ramp.thickness`` > 0), a known mass or friction, effects, or other gravity.
    """
    if scene.n_objects != 2:
        raise OutOfFamily(f"scene {scene.name!r} has {scene.n_objects} object(s); the scene-conditioned CNN knows "
                          "two (object 1 on the ramp, object 2 on the floor); use --method grad or mh")
    for i, obj in enumerate(scene.objects):
        if obj.shape != "box":
            raise OutOfFamily(f"objects[{i}] is a {obj.shape}; the scene-conditioned CNN knows boxes only; "
                              "use --method grad or mh")
        for key in ("mass", "friction"):
            if getattr(obj, key) is not None:
                raise OutOfFamily(f"objects[{i}].{key} is known; the scene-conditioned CNN fits free masses and "
                                  "friction coefficients only; use --method grad or mh")
        if obj.rolling is not None:
            raise OutOfFamily(f"objects[{i}].rolling is set; the scene-conditioned CNN knows sliding boxes only")
    if (scene.placement(0), scene.placement(1)) != ("ramp", "floor"):
        raise OutOfFamily("the scene-conditioned CNN needs object 1 on the ramp and object 2 on the floor")
    if scene.ramp.thickness > 0:
        raise OutOfFamily(f"ramp.thickness = {scene.ramp.thickness} m; the scene-conditioned CNN knows flush ramps "
                          "(thickness 0) only; use --method grad or mh")
    if scene.effects:
        raise OutOfFamily(f"the scene has effects ({', '.join(scene.effects)}); the scene-conditioned CNN knows the "
                          "base model only")
    if abs(scene.gravity - GRAVITY) > GRAVITY_TOLERANCE * GRAVITY:
        raise OutOfFamily(f"gravity = {scene.gravity} m/s^2; the scene-conditioned CNN was trained at {GRAVITY}")
    a, b = scene.objects
    return np.array([scene.ramp.angle_deg, *a.size, *b.size, a.start, b.start, float(fps)], np.float64)


def family_angle(features):
    """Ramp angle (rad) of feature vectors (..., F) (NumPy or JAX)."""
    return features[..., FEATURES.index("angle_deg")] * (math.pi / 180.0)
