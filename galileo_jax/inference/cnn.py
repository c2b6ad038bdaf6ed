"""Amortised inference: a Flax NNX network maps a velocity profile straight to parameters.

The design's third estimator (dissertation 4.3; NOTES.md "CNN"): a network trained on
simulations of one scene reads an observed velocity profile and returns the parameters the
video determines (the scene's :class:`~galileo_jax.params.ParamSpace` coordinates: k1, k2,
phi and the release-time correction for the Physics 101 ramp; a mass only where the scene
fixes the scale). It costs one forward pass, so it serves as ``fit --method cnn`` and as the
starting point of ``grad`` and ``mh`` (``--init cnn``), as Galileo used it.

Input (:func:`network_input`). A window of ``n_samples`` velocity samples (all traces, m/s)
that starts ``release_offset`` s before the tracker's release estimate, plus a mask channel
(1 = observed sample, 0 = before the video, after its end or outside its fit window), so one
network reads videos of any length: shorter ones are padded and masked, longer ones cut at
the window's end (3.2 s after the window's start by default; the seed's 60-frame window
missed the collision of slow slides). Training draws the valid length and a masked prefix at
random (:func:`~galileo_jax.inference.cnn_training.simulate_examples`).

Outputs. Two networks, both ``f(x (B, L, T + 1)) -> (B, 2, d)``:

* :class:`SeedCNN`: the seed's Keras network as a named baseline (NOTES.md: Conv 6x(1,7) ->
  AvgPool -> Conv 16x(1,7) -> AvgPool -> Dense 64 -> 32 -> d, ReLU, 'valid' padding, 13,252
  weights at d = 4), reading the first 60 samples of the traces as a (T, 60) image without the
  mask channel. It gives point estimates only (trained with the seed's mean absolute error,
  on theta scaled to [0, 1]); its second row is a constant, unused scale.
* :class:`ProfileCNN` (default): 1-D convolutions over time with the mask as a channel, three
  poolings, then dense layers to a Gaussian head: mean mu and standard deviation s of the
  unconstrained coordinates z = logit((theta - lo) / (hi - lo)) (:meth:`ParamSpace.to_unconstrained`).
  Trained by the Gaussian negative log-likelihood, so (mu, s) approximate the posterior
  marginals under the training prior; because the transform is monotone, the 90% interval
  theta(mu +- 1.645 s) has the same coverage as the one in z. Checked on fresh simulations
  in ``benchmarks/cnn_accuracy.py``.

The slide's closed form (:func:`slide_friction`, ``CNNSpec.ramp``, a training option). On the
ramp object 1 slides with the constant acceleration a = g (sin theta - k1 cos theta), so a
straight line through its speeds there gives k1 = tan theta - a / (g cos theta), exact up to
the tracking noise. A network with ``ramp`` computes that estimate and its standard error
from its own input and combines it with its own Gaussian reading of k1's z by their
precisions, as two independent measurements (mu = (mu_net / s_net^2 + z_slide / s_slide^2) /
(1 / s_net^2 + 1 / s_slide^2)): the closed form where the speeds are sharp, the network's
reading of the whole profile (the floor's deceleration, the impact) where they are noisy. The
dense layers read how sharp the closed form is (the log of its standard error, and whether
enough samples gave it), not its value, so that the network's reading stays its own. On the
seed's prior and clean simulations this takes k1 from 0.0010 to 0.0003 (the seed's network
0.0004); at 1-3 mm of tracker noise the network's k1 came out worse than without it
(``benchmarks/results/cnn_accuracy.md``, ``docs/cnn.md``), so the shipped networks do not use it.

All functions here are pure JAX (the model is split into a graph definition and a parameter
state with :func:`flax.nnx.split`), except loading and the input window, which are I/O and NumPy.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from galileo_jax.errors import GalileoError
from galileo_jax.inference.covariance import Z90
from galileo_jax.observation import Observation
from galileo_jax.params import ParamSpace
from galileo_jax.scene import Scene

#: Architectures by name (``CNNSpec.architecture``).
ARCHITECTURES = ("profile", "seed")


#: Samples the seed's network reads (dissertation 4.3: a (4, 60) profile).
SEED_SAMPLES = 60


#: Smallest predicted SD in z (keeps the negative log-likelihood finite).
MIN_SD = 1e-3


#: Speed (m/s) above which a simulated training profile counts as blown up: no object on a
#: ramp of at most 1 m reaches sqrt(2 g 1 m) = 4.4 m/s.
MAX_SPEED = 10.0


#: Largest relative difference between a video's frame rate and the model's.
FPS_TOLERANCE = 0.02


#: Kinds of fit coordinate (:attr:`~galileo_jax.params.ParamSpace.kinds`) a network need not
#: predict: the camera's scale error, a calibration nuisance at whose neutral value (0) the
#: network is trained. :func:`estimate` puts such a coordinate at 0 and leaves its whole window
#: open, so ``--init cnn`` keeps the nuisance ``fit`` adds by default.
NEUTRAL_KINDS = ("scale",)


class CNNError(GalileoError):
    """No usable trained model (none matches the scene, or the files are unreadable)."""


def scene_hash(scene: Scene) -> str:
    """Short hash of what of ``scene`` changes the simulation (its physics; not its name or
    camera), so a model trained on one scene file serves every file of the same setup."""
    from galileo_jax.scene import scene_key

    return hashlib.sha256(scene_key(scene).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class CNNSpec:
    """What a trained network reads and predicts (saved next to its weights as ``model.json``).

    Attributes:
        scene: name of the scene it was trained on (for messages).
        scene_hash: :func:`scene_hash` of that scene.
        fps: frame rate of the training profiles (frames per second).
        names: predicted coordinates, the scene's :class:`ParamSpace` names, e.g. (k1, k2, phi, dt_release).
        lower, upper: (d,) their bounds (the z transform).
        n_traces: velocity traces T (2 per object).
        n_samples: window length L in samples.
        release_offset: s between the window's start and the tracker's release estimate.
        architecture: "profile" or "seed".
        width: channels of the first convolution of :class:`ProfileCNN` (later ones 2x).
        hidden: width of the dense layers of :class:`ProfileCNN`.
        family: for a scene-conditioned network, its scene family's ranges
            ({feature: [low, high]}, :meth:`~galileo_jax.scene_family.SceneFamily.to_dict`);
            ``fps`` is then the rate of the network's own time grid, onto which a video's
            positions are resampled (:func:`family_network_input`). None: a network for one
            scene at one frame rate.
        ramp: for a network that reads the slide's closed form (:func:`slide_friction`):
            (tan theta, cos theta, object 1's distance to the ramp's foot in m (its start minus
            half its length), gravity in m/s^2, window times in s from which the distance slid
            is summed (the release offset plus the release-time correction's lower bound) and
            from which the speeds count (plus its upper bound and one frame)); for a
            scene-conditioned network the first three are each input's own, from its scene
            features (:class:`SlideFeature`), and are stored as those of the family's middle
            scene. None: not read.
    """

    scene: str
    scene_hash: str
    fps: float
    names: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    n_traces: int
    n_samples: int = 96
    release_offset: float = 0.25
    architecture: str = "profile"
    width: int = 32
    hidden: int = 128
    family: dict | None = None
    ramp: tuple[float, ...] | None = None

    @property
    def dim(self) -> int:
        return len(self.names)

    @property
    def n_scene(self) -> int:
        """Scene features F the network reads (0: a network for one scene; else the
        :data:`~galileo_jax.scene_family.FEATURES` of a scene family)."""
        from galileo_jax.scene_family import FEATURES

        return 0 if self.family is None else len(FEATURES)

    @property
    def channels(self) -> int:
        """Channels of one input sample: T traces, then the F scene features (constant over
        time), then the mask."""
        return self.n_traces + self.n_scene + 1

    def to_json(self) -> dict:
        return asdict(self)

    @classmethod
    def from_json(cls, data: dict) -> "CNNSpec":
        d = dict(data)
        for k in ("names", "lower", "upper"):
            d[k] = tuple(d[k])
        if d.get("ramp") is not None:
            d["ramp"] = tuple(d["ramp"])
        return cls(**d)

    @classmethod
    def for_scene(cls, scene: Scene, fps: float, ramp_feature: bool = False, **kw) -> "CNNSpec":
        """The spec of a network for ``scene`` at ``fps`` (base model: no effects); with
        ``ramp_feature`` one that reads the slide's closed form (``ramp``, :func:`slide_friction`).

        Raises:
            ValueError: unknown architecture, a window too short for the release offset, or
            ``ramp_feature`` where object 1 does not start on the ramp, k1 is not fitted or the
            architecture is the seed's.
        """
        space = ParamSpace.from_scene(scene)
        spec = cls(scene.name, scene_hash(scene), float(fps), space.names, space.lower, space.upper,
                   2 * scene.n_objects, **kw)
        if ramp_feature:
            if scene.placement(0) != "ramp" or "k1" not in space.names or spec.architecture != "profile":
                raise ValueError("ramp_feature needs object 1 on the ramp, k1 fitted and architecture 'profile'")
            theta, first = scene.ramp.angle, scene.objects[0]
            i = space.names.index("dt_release") if "dt_release" in space.names else None
            dt_lo, dt_hi = (0.0, 0.0) if i is None else (space.lower[i], space.upper[i])
            spec = replace(spec, ramp=(math.tan(theta), math.cos(theta), first.start - first.length / 2,
                                       float(scene.gravity), spec.release_offset + dt_lo,
                                       spec.release_offset + dt_hi + 1.0 / spec.fps))
        if spec.architecture not in ARCHITECTURES:
            raise ValueError(f"unknown architecture {spec.architecture!r}; choose one of {ARCHITECTURES}")
        if spec.architecture == "seed" and spec.n_samples < SEED_SAMPLES:
            raise ValueError(f"the seed's network reads {SEED_SAMPLES} samples; n_samples is {spec.n_samples}")
        if spec.n_samples < 16 or spec.n_samples % 8:
            raise ValueError(f"n_samples must be a multiple of 8 and >= 16, got {spec.n_samples}")
        if not 0 <= spec.release_offset < spec.n_samples / spec.fps:
            raise ValueError(f"release_offset must lie inside the window, got {spec.release_offset} s")
        return spec


    @classmethod
    def for_family(cls, family, fps: float = 30.0, **kw) -> "CNNSpec":
        """The spec of a scene-conditioned network for ``family``
        (:class:`~galileo_jax.scene_family.SceneFamily`), reading profiles resampled to ``fps``
        (its time grid). Its coordinates are every family scene's (k1, k2, phi, dt_release,
        the same bounds for all).

        Raises:
            ValueError: as :meth:`for_scene`; the seed's architecture (it reads no scene).
        """
        from galileo_jax.scene_family import family_scene

        base = cls.for_scene(family_scene(family.middle()), fps, **kw)
        if base.architecture != "profile":
            raise ValueError("a scene-conditioned network needs architecture 'profile'")
        return replace(base, scene="family", scene_hash="family", family=family.to_dict())


#: Fewest samples on the ramp through which :func:`slide_friction` draws its line. Its standard
#: error comes from the scatter about the line, n - 2 degrees of freedom: with 3 or 4 samples
#: that scatter is small by chance often enough that the error was 4-9 standard errors in 1%
#: of 300 simulated slides (tracker noise 0.1-3 mm); from 6 on it is estimated well enough.
SLIDE_MIN_SAMPLES = 6
#: Share of the distance to the ramp's foot within which object 1's speeds count (the last
#: samples before the foot may hold the turn onto the floor).
SLIDE_REACH = 0.9
#: Error of :func:`slide_friction`'s k1 where the speeds hold no noise: its mean absolute error
#: on 256 clean simulations of the 20 degree scene from the seed's prior was 0.0002 (the
#: simulator's contact is soft, and the release falls between frames). Added in quadrature to
#: the standard error the network reads, so a noiseless profile reads like the sharpest ones it
#: was trained on instead of an error of 0.
SLIDE_SE_FLOOR = 2e-4


class SlideFeature(NamedTuple):
    """What :func:`slide_friction` needs to know of a network's scene and window (static).

    Attributes:
        ramp: ``CNNSpec.ramp`` (tan theta, cos theta, foot distance m, gravity m/s^2, the
            times (s) from which the distance is summed and the speeds count).
        fps: frame rate of the window (frames per second).
        k1_index: position of k1 among the network's coordinates.
        k1_bounds: (low, high) of k1, for its z.
        scene_features: for a scene-conditioned network, where its input holds the ramp's
            geometry: (first feature channel, (index, low, high) of ``angle_deg``, of
            ``length_1`` and of ``start_1`` among the features, normalised linearly to [-1, 1]
            over (low, high)); None: ``ramp``'s geometry for every input.
    """

    ramp: tuple[float, ...]
    fps: float
    k1_index: int
    k1_bounds: tuple[float, float]
    scene_features: tuple | None = None

    @classmethod
    def of(cls, spec: "CNNSpec") -> "SlideFeature | None":
        if spec.ramp is None:
            return None
        i = spec.names.index("k1")
        geometry = None
        if spec.family is not None:
            from galileo_jax.scene_family import FEATURES, SceneFamily

            family = SceneFamily.from_dict(spec.family)
            columns = [FEATURES.index(f) for f in ("angle_deg", "length_1", "start_1")]
            geometry = (spec.n_traces,) + tuple((j, float(family.lower[j]), float(family.upper[j])) for j in columns)
        return cls(tuple(spec.ramp), float(spec.fps), i, (float(spec.lower[i]), float(spec.upper[i])), geometry)

    def geometry(self, x: jax.Array) -> tuple:
        """(tan theta, cos theta, foot distance in m) of inputs ``x`` (B, L, C): scalars, or
        (B,) from each input's scene features."""
        if self.scene_features is None:
            return self.ramp[:3]
        first, *columns = self.scene_features
        angle, length, start = (lo + 0.5 * (x[:, 0, first + j] + 1.0) * (hi - lo) for j, lo, hi in columns)
        theta = jnp.deg2rad(angle)
        return jnp.tan(theta), jnp.cos(theta), start - 0.5 * length


def slide_friction(x: jax.Array, feature: SlideFeature) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Object 1's friction coefficient on the ramp from the slope of its speed (pure, jittable).

    On the ramp the speed grows linearly, v = a (t - t0) with a = g (sin theta - k1 cos theta)
    (the sliding acceleration of a block on an incline), so k1 = tan theta - a / (g cos theta).
    The speeds v_x cos theta - v_y sin theta of object 1 down the slope (traces 0 and 1, in the
    scene's frame: x down the ramp, the second axis up; signed, so noise does not bias them as
    it biases |v| at low speed) count from ``feature.ramp``'s start time (after the latest
    release the network's prior allows) while the distance slid since the earliest release it
    allows, the running sum of speed / fps, is under :data:`SLIDE_REACH` of the distance to the
    foot; a = their least-squares slope over the window times k / fps.

    Args:
        x: (B, L, C) network inputs (traces in m/s first, the mask channel last).
        feature: the scene and window (:class:`SlideFeature`).

    Returns:
        ``(k1, se, n)``: (B,) estimates, (B,) their standard errors (the least-squares slope's,
        from the scatter of the speeds about the line, over g cos theta; both 0 where fewer
        than :data:`SLIDE_MIN_SAMPLES` samples counted) and (B,) the number of samples that
        counted.
    """
    tan_t, cos_t, foot = feature.geometry(x)
    gravity, offset, start = feature.ramp[3:]
    t = jnp.arange(x.shape[1], dtype=x.dtype) / feature.fps
    mask = x[..., -1]
    # the velocity along the slope (x runs down the ramp, z up: the scene's frame), signed and
    # linear in the noise: a speed |v| would be biased up by the noise where it is slow
    speed = (x[..., 0] - x[..., 1] * jnp.reshape(tan_t, (-1, 1))) * jnp.reshape(cos_t, (-1, 1))
    slid = jnp.cumsum(speed * mask * (t > offset), axis=1) / feature.fps
    w = mask * (t > start) * (slid < SLIDE_REACH * jnp.reshape(foot, (-1, 1)))
    n = jnp.sum(w, axis=1)
    safe = jnp.maximum(n, 1.0)
    t_mean = jnp.sum(w * t, axis=1) / safe
    v_mean = jnp.sum(w * speed, axis=1) / safe
    dt = t - t_mean[:, None]
    sxx = jnp.maximum(jnp.sum(w * dt ** 2, axis=1), 1e-12)
    a = jnp.sum(w * dt * (speed - v_mean[:, None]), axis=1) / sxx
    scatter = jnp.sum(w * (speed - v_mean[:, None] - a[:, None] * dt) ** 2, axis=1) / jnp.maximum(n - 2.0, 1.0)
    ok = n >= SLIDE_MIN_SAMPLES
    se = jnp.sqrt(scatter / sxx) / (gravity * cos_t)
    return jnp.where(ok, tan_t - a / (gravity * cos_t), 0.0), jnp.where(ok, se, 0.0), n


def _slide_inputs(x: jax.Array, feature: SlideFeature) -> tuple[jax.Array, jax.Array, jax.Array]:
    """(B,) z of :func:`slide_friction`'s k1 (clipped into k1's bounds), (B,) the log of its
    standard error (with :data:`SLIDE_SE_FLOOR` in quadrature) in z, clipped to [-12, 3], and
    (B,) 1 where it counted, else 0 (and the first two 0)."""
    k1, se, n = slide_friction(x, feature)
    lo, hi = feature.k1_bounds
    u = jnp.clip((k1 - lo) / (hi - lo), 1e-3, 1 - 1e-3)
    valid = (n >= SLIDE_MIN_SAMPLES).astype(x.dtype)
    se = jnp.sqrt(se ** 2 + SLIDE_SE_FLOOR ** 2)
    log_se = jnp.clip(jnp.log(se / ((hi - lo) * u * (1.0 - u))), -12.0, 3.0)
    return (jnp.log(u) - jnp.log1p(-u)) * valid, log_se * valid, valid


class SeedCNN(nnx.Module):
    """The seed's network (NOTES.md "CNN"), ``x (B, L, T + 1) -> (B, 2, d)``.

    Reads the first 60 samples of the T traces as a one-channel (T, 60) image (the mask
    channel is dropped, as the seed had none): Conv 6x(1,7) -> AvgPool 2x2 -> Conv 16x(1,7) ->
    AvgPool 2x2 -> Dense 64 -> Dense 32 -> Dense d, ReLU, 'valid' padding. Row 0 of the output
    is the point estimate of theta scaled to [0, 1]; row 1 is zero (no uncertainty).
    """

    def __init__(self, n_traces: int, dim: int, *, rngs: nnx.Rngs):
        self.conv1 = nnx.Conv(1, 6, (1, 7), padding="VALID", rngs=rngs)
        self.conv2 = nnx.Conv(6, 16, (1, 7), padding="VALID", rngs=rngs)
        h, w = n_traces, SEED_SAMPLES
        h, w = h // 2, (w - 6) // 2
        h, w = h // 2, (w - 6) // 2
        self.dense1 = nnx.Linear(max(h, 1) * w * 16, 64, rngs=rngs)
        self.dense2 = nnx.Linear(64, 32, rngs=rngs)
        self.out = nnx.Linear(32, dim, rngs=rngs)

    def __call__(self, x: jax.Array) -> jax.Array:
        img = jnp.swapaxes(x[:, :SEED_SAMPLES, :-1], 1, 2)[..., None]  # (B, T, 60, 1)
        y = nnx.avg_pool(nnx.relu(self.conv1(img)), (2, 2), (2, 2))
        y = nnx.avg_pool(nnx.relu(self.conv2(y)), (2, 2), (2, 2))
        y = y.reshape(y.shape[0], -1)
        y = nnx.relu(self.dense2(nnx.relu(self.dense1(y))))
        est = self.out(y)
        return jnp.stack([est, jnp.zeros_like(est)], axis=1)


class ProfileCNN(nnx.Module):
    """The default network, ``x (B, L, T + F + 1) -> (B, 2, d)``: row 0 the mean mu of z, row 1
    the SD s of z (softplus, at least :data:`MIN_SD`). F = ``n_scene`` scene features (0 for a
    one-scene network) sit between the traces and the mask, constant over time; the
    convolutions read the traces and the mask, and the features join their flattened output
    before the dense layers.

    Five 1-D convolutions over time (kernel 5, 5, 5, 5, 3; ``width``, ``width``, 2 ``width``,
    2 ``width``, 2 ``width`` channels; GELU), average-pooled by 2 after the 2nd, 4th and 5th,
    flattened (time positions matter: the impact's time tells k1 and where object 2 starts),
    then Dense ``hidden`` -> Dense ``hidden`` -> Dense 2d.
    """

    def __init__(self, n_traces: int, dim: int, n_samples: int, width: int = 32, hidden: int = 128,
                 n_scene: int = 0, slide: SlideFeature | None = None, *, rngs: nnx.Rngs):
        w2 = 2 * width
        self.n_traces, self.n_scene, self.slide = n_traces, n_scene, slide
        self.convs = nnx.List([nnx.Conv(n_traces + 1, width, 5, rngs=rngs), nnx.Conv(width, width, 5, rngs=rngs),
                               nnx.Conv(width, w2, 5, rngs=rngs), nnx.Conv(w2, w2, 5, rngs=rngs),
                               nnx.Conv(w2, w2, 3, rngs=rngs)])
        self.dense1 = nnx.Linear((n_samples // 8) * w2 + n_scene + (2 if slide else 0), hidden, rngs=rngs)
        self.dense2 = nnx.Linear(hidden, hidden, rngs=rngs)
        self.out = nnx.Linear(hidden, 2 * dim, rngs=rngs)
        self.dim = dim

    def __call__(self, x: jax.Array) -> jax.Array:
        T, F = self.n_traces, self.n_scene
        y = jnp.concatenate([x[..., :T], x[..., T + F:]], axis=-1) if F else x
        for i, conv in enumerate(self.convs):
            y = nnx.gelu(conv(y))
            if i in (1, 3, 4):
                y = nnx.avg_pool(y, (2,), (2,))
        y = y.reshape(y.shape[0], -1)
        if F:  # the scene's features join the flattened convolution features
            y = jnp.concatenate([y, x[:, 0, T:T + F]], axis=-1)
        if self.slide is not None:  # how sharp the slide's closed form is joins them (not its value)
            z_slide, log_se, valid = _slide_inputs(x, self.slide)
            y = jnp.concatenate([y, log_se[:, None], valid[:, None]], axis=-1)
        y = nnx.gelu(self.dense2(nnx.gelu(self.dense1(y))))
        out = self.out(y).reshape(-1, 2, self.dim)
        mu, sd = out[:, 0], jax.nn.softplus(out[:, 1]) + MIN_SD
        if self.slide is not None:  # k1: the network's reading and the closed form's, by their precisions
            i = self.slide.k1_index
            p_net, p_slide = sd[:, i] ** -2, valid * jnp.exp(-2.0 * log_se)
            mu = mu.at[:, i].set((p_net * mu[:, i] + p_slide * z_slide) / (p_net + p_slide))
            sd = sd.at[:, i].set((p_net + p_slide) ** -0.5)
        return jnp.stack([mu, sd], axis=1)


def build_network(spec: CNNSpec, seed: int = 0) -> nnx.Module:
    """A freshly initialised network for ``spec`` (``rngs`` from ``seed``)."""
    rngs = nnx.Rngs(seed)
    if spec.architecture == "seed":
        return SeedCNN(spec.n_traces, spec.dim, rngs=rngs)
    return ProfileCNN(spec.n_traces, spec.dim, spec.n_samples, spec.width, spec.hidden, spec.n_scene,
                      SlideFeature.of(spec), rngs=rngs)


class Prediction(NamedTuple):
    """The network's answer for a batch of profiles (NumPy or JAX arrays).

    Attributes:
        theta: (B, d) point estimate in physical coordinates (the median, theta(mu)).
        mu: (B, d) mean of z (the seed's network: z of its point estimate).
        sd: (B, d) SD of z (0 for the seed's network: no uncertainty).
        interval90: (B, d, 2) 90% interval theta(mu -+ 1.645 sd).
    """

    theta: jax.Array
    mu: jax.Array
    sd: jax.Array
    interval90: jax.Array


def _space_bounds(spec: CNNSpec, dtype=jnp.float32) -> tuple[jax.Array, jax.Array]:
    return jnp.asarray(spec.lower, dtype), jnp.asarray(spec.upper, dtype)


def to_z(spec: CNNSpec, theta: jax.Array) -> jax.Array:
    """z = logit((theta - lo) / (hi - lo)), clipped to +-12 (as ParamSpace.to_unconstrained)."""
    lo, hi = _space_bounds(spec)
    u = jnp.clip((theta - lo) / (hi - lo), 1e-6, 1 - 1e-6)
    return jnp.log(u) - jnp.log1p(-u)


def from_z(spec: CNNSpec, z: jax.Array) -> jax.Array:
    """theta = lo + (hi - lo) sigmoid(z), in z's dtype (float32 in training, float64 for a fit)."""
    z = jnp.asarray(z)
    lo, hi = _space_bounds(spec, z.dtype)
    return lo + (hi - lo) * jax.nn.sigmoid(z)


def predict(spec: CNNSpec, graphdef, params, x: jax.Array) -> Prediction:
    """Run the network on inputs ``x`` (B, L, T + 1) (pure, jittable).

    Raises:
        ValueError: ``x`` does not have the spec's shape (L, T + 1) per example.
    """
    if x.shape[1:] != (spec.n_samples, spec.channels):
        raise ValueError(f"network input must have shape (B, {spec.n_samples}, {spec.channels}), got {x.shape}")
    out = nnx.merge(graphdef, params)(x)
    if spec.architecture == "seed":
        lo, hi = _space_bounds(spec)
        theta = lo + (hi - lo) * jnp.clip(out[:, 0], 1e-4, 1 - 1e-4)
        mu, sd = to_z(spec, theta), jnp.zeros_like(theta)
    else:
        mu, sd = out[:, 0], out[:, 1]
        theta = from_z(spec, mu)
    interval = jnp.stack([from_z(spec, mu - Z90 * sd), from_z(spec, mu + Z90 * sd)], axis=-1)
    return Prediction(theta, mu, sd, interval)


def loss(spec: CNNSpec, graphdef, params, x: jax.Array, theta: jax.Array, beta: float = 0.0) -> jax.Array:
    """Training loss of a batch (pure): the Gaussian negative log-likelihood of z(theta) under
    (mu, sd), averaged over examples and coordinates (constant dropped); for the seed's network
    its mean absolute error on theta scaled to [0, 1] (dissertation 4.3).

    With ``beta`` > 0 it is the beta-NLL of Seitzer et al. (2022, "On the pitfalls of
    heteroscedastic uncertainty estimation with probabilistic neural networks", ICLR, eq. 4):
    each term weighted by stop_gradient(sd)^(2 beta). Plain NLL (beta 0) scales the gradient
    of mu by 1/sd^2, so coordinates the network is still unsure of (k2, phi) barely learn
    while sharp ones (k1, the release time) dominate; the weighting undoes that. The optimum
    sd for a given mu is unchanged, so the intervals stay calibrated. Measured on 20,480
    simulated rollouts, 1,500 steps: k2 / phi MAE 0.23 / 0.26 at beta 0, 0.165 / 0.165 at 0.5.

    Arguments:
        x: (B, L, T + 1) inputs.
        theta: (B, d) true parameters.
        beta: weighting exponent in [0, 1] (0: plain NLL; 1: mu learns as under squared error).

    Examples whose mask is all zero (rollouts :func:`~galileo_jax.inference.cnn_training.simulate_examples` dropped) do not count.
    """
    out = nnx.merge(graphdef, params)(x)
    lo, hi = _space_bounds(spec)
    if spec.architecture == "seed":
        per = jnp.abs(out[:, 0] - (theta - lo) / (hi - lo))
    else:
        z = to_z(spec, theta)
        mu, sd = out[:, 0], out[:, 1]
        per = jnp.log(sd) + 0.5 * ((z - mu) / sd) ** 2
        if beta:
            per = per * jax.lax.stop_gradient(sd) ** (2 * beta)
    w = usable(x)[:, None].astype(per.dtype)
    return jnp.sum(per * w) / jnp.maximum(jnp.sum(w) * per.shape[1], 1.0)


def usable(x: jax.Array) -> jax.Array:
    """(B,) bool: the example has at least one observed sample (its mask channel is not all zero)."""
    return jnp.any(x[..., -1] > 0, axis=-1)


def network_input(spec: CNNSpec, obs: Observation) -> tuple[np.ndarray, float]:
    """The network's input for an observed profile, and where its window starts.

    The window holds ``spec.n_samples`` velocity samples starting at frame
    c = round((release_time - release_offset) * fps) (c < 0: the first -c samples are padding);
    samples outside the video or outside ``obs.mask`` are zero with mask 0.

    Returns:
        x: (L, T + 1) float32: the traces in m/s, then the mask channel.
        shift: s to add to the network's release-time correction to refer it to the
            tracker's estimate: (release_offset - (release_time - c / fps)).

    Raises:
        CNNError: the observation's traces or frame rate do not match the spec.
    """
    prof = np.asarray(obs.profile, np.float64)
    if prof.shape[0] != spec.n_traces:
        raise CNNError(f"the CNN reads {spec.n_traces} velocity traces, the video has {prof.shape[0]}")
    if abs(obs.fps - spec.fps) > FPS_TOLERANCE * spec.fps:
        raise CNNError(f"the CNN was trained at {spec.fps:g} fps, the video has {obs.fps:g} fps; "
                       f"train one at this frame rate (python -m galileo_jax.train, set fps in the config)")
    c = int(round((obs.release_time - spec.release_offset) * obs.fps))
    x = np.zeros((spec.n_samples, spec.n_traces + 1), np.float32)
    k = np.arange(spec.n_samples) + c
    ok = (k >= 0) & (k < prof.shape[1])
    ok[ok] &= np.asarray(obs.mask, bool)[k[ok]]
    x[ok, :-1] = prof[:, k[ok]].T
    x[ok, -1] = 1.0
    shift = spec.release_offset - (obs.release_time - c / obs.fps)
    return x, float(shift)


def family_network_input(spec: CNNSpec, obs: Observation, features) -> tuple[np.ndarray, float]:
    """The input of a scene-conditioned network (``spec.family``) for an observed video.

    The tracked positions (``obs.positions``, at the video's frame times) are resampled by
    linear interpolation to the network's time grid, ``spec.n_samples`` + 1 times 1 / ``spec.fps``
    apart from ``release_offset`` s before the tracker's release estimate, and differenced: a
    video at any frame rate inside the family's gives the profile on the grid the network was
    trained on (:func:`~galileo_jax.inference.cnn_training.simulate_family_examples` resamples
    its simulated frames the same way). A grid sample is observed (mask 1) where both its ends
    lie between frames used by the fit (``obs.mask``'s velocity samples) with no unused sample
    between them.

    Args:
        spec: the network's spec (``spec.family`` set).
        obs: the observation (2 objects).
        features: (F,) the scene's features (:func:`~galileo_jax.scene_family.scene_features`,
            with the video's frame rate).

    Returns:
        x: (L, T + F + 1) float32: traces (m/s), normalised features, mask.
        shift: 0.0 s (the grid starts at the tracker's release estimate minus ``release_offset``,
            where training puts the release before its correction).

    Raises:
        galileo_jax.scene_family.OutOfFamily: a feature outside the family's ranges (names it).
        CNNError: the observation's traces do not match the spec.
    """
    from galileo_jax.scene_family import SceneFamily

    family = SceneFamily.from_dict(spec.family)
    family.check(features)
    prof = np.asarray(obs.profile, np.float64)
    if prof.shape[0] != spec.n_traces:
        raise CNNError(f"the CNN reads {spec.n_traces} velocity traces, the video has {prof.shape[0]}")
    L, T = spec.n_samples, spec.n_traces
    ft = np.asarray(obs.frame_times, np.float64)
    pos = np.asarray(obs.positions, np.float64).reshape(len(ft), -1)  # (N, T)
    used = np.asarray(obs.mask, bool)
    grid = obs.release_time - spec.release_offset + np.arange(L + 1) / spec.fps
    # grid time t lies in velocity sample k = the frame interval [ft[k], ft[k + 1]) it falls in
    k = np.searchsorted(ft, grid, side="right") - 1
    inside = (k >= 0) & (k < len(used))
    seg = np.where(inside, k, 0)
    good = inside & used[seg]
    # every frame interval a grid sample spans is used: count the unused ones below each index
    bad_before = np.concatenate([[0], np.cumsum(~used)])
    p = np.stack([np.interp(grid, ft, pos[:, j]) for j in range(T)], axis=1)  # (L + 1, T)
    v = np.diff(p, axis=0) * spec.fps
    ok = good[:-1] & good[1:] & (bad_before[np.where(inside[1:], seg[1:], 0) + 1] - bad_before[seg[:-1]] == 0)
    x = np.zeros((L, spec.channels), np.float32)
    x[ok, :T] = v[ok]
    x[:, T:T + spec.n_scene] = family.normalise(np.asarray(features, np.float64))[None]
    x[ok, -1] = 1.0
    return x, 0.0


class TrainedModel(NamedTuple):
    """A trained network ready to predict.

    Attributes:
        spec: what it reads and predicts.
        graphdef: its Flax NNX graph definition.
        params: its parameter state.
        path: the folder it was loaded from.
        info: the training record (``model.json``: steps, examples, metrics, time).
    """

    spec: CNNSpec
    graphdef: object
    params: object
    path: Path
    info: dict


class CNNEstimate(NamedTuple):
    """The network's answer for one observed video, in the fit's coordinates (NumPy).

    Attributes:
        names: (d,) coordinate names (the problem's ParamSpace).
        theta: (d,) estimate (the median of the network's marginals), release correction
            referred to the tracker's estimate.
        sd: (d,) SD of the draws of theta (0 for the seed's network).
        interval90: (d, 2) 90% intervals.
        draws: (S, d) draws from the network's Gaussian in z, mapped to theta (S copies of
            ``theta`` for the seed's network).
        sd_z: (d,) the network's SD in the unconstrained coordinates z (0: the seed's network;
            NaN: a calibration nuisance the network does not read, :data:`NEUTRAL_KINDS`).
        time_s: wall time of the input window and forward pass in s.
        model: the :class:`TrainedModel` used.
    """

    names: tuple[str, ...]
    theta: np.ndarray
    sd: np.ndarray
    interval90: np.ndarray
    draws: np.ndarray
    sd_z: np.ndarray
    time_s: float
    model: TrainedModel


def estimate(model: TrainedModel, obs: Observation, space: ParamSpace, key: jax.Array, n_draws: int = 256,
             features=None) -> CNNEstimate:
    """Run ``model`` on an observed video and return the estimate in ``space``'s coordinates.

    The release-time correction is shifted from the window's frame to the tracker's estimate
    (:func:`network_input`) and every coordinate is kept 0.1% of its range inside the bounds.

    ``features``: (F,) the scene's features (:func:`~galileo_jax.scene_family.scene_features`),
    which a scene-conditioned network (``model.spec.family``) reads with the profile
    (:func:`family_network_input`).

    A coordinate of ``space`` after the network's own ones whose kind is in
    :data:`NEUTRAL_KINDS` (the camera's ``scale_error``) comes out at 0 (clipped to its
    window), with the whole window as its 90% interval, draws uniform over the window and an
    unknown (NaN) ``sd_z``: the network was trained at the exact scale and says nothing of it.

    Raises:
        CNNError: the model predicts other coordinates than ``space`` has (e.g. the fit adds
            effects, which the CNN does not know), or the video does not fit the model.
        galileo_jax.scene_family.OutOfFamily: a scene-conditioned network and a scene outside
            its family.
    """
    import time

    spec = model.spec
    names, extra = tuple(space.names), tuple(range(spec.dim, space.dim))
    if names[:spec.dim] != tuple(spec.names) or any(space.kinds[j] not in NEUTRAL_KINDS for j in extra):
        raise CNNError(f"the CNN predicts {list(spec.names)}, this fit has {list(space.names)}; the CNN knows the "
                       f"base model only: drop --effects, or use --method grad or mh")
    t0 = time.perf_counter()
    if spec.family is not None:
        if features is None:
            raise CNNError("a scene-conditioned CNN needs the scene's features; give features=scene_features(...)")
        x, shift = family_network_input(spec, obs, features)
    else:
        x, shift = network_input(spec, obs)
    pred = predict(spec, model.graphdef, model.params, jnp.asarray(x[None]))
    mu, sd = np.asarray(pred.mu[0], np.float64), np.asarray(pred.sd[0], np.float64)
    z = mu[None] + sd[None] * np.asarray(jax.random.normal(key, (n_draws, spec.dim)), np.float64)
    lo, hi = np.asarray(spec.lower), np.asarray(spec.upper)
    pad = 1e-3 * (hi - lo)

    def to_theta(zz):
        th = np.array(from_z(spec, jnp.asarray(zz, jnp.float64)), np.float64)
        if "dt_release" in spec.names:
            th[..., spec.names.index("dt_release")] += shift
        return np.clip(th, lo + pad, hi - pad)

    theta = to_theta(mu)
    interval = np.stack([to_theta(mu - Z90 * sd), to_theta(mu + Z90 * sd)], axis=-1)
    draws = to_theta(z)
    sd_z = sd
    if extra:  # calibration nuisances the network does not read: neutral, their whole window open
        lo_x, hi_x = np.asarray(space.lower)[list(extra)], np.asarray(space.upper)[list(extra)]
        theta = np.concatenate([theta, np.clip(0.0, lo_x, hi_x)])
        interval = np.concatenate([interval, np.stack([lo_x, hi_x], axis=-1)])
        u = np.asarray(jax.random.uniform(jax.random.fold_in(key, 1), (n_draws, len(extra))), np.float64)
        draws = np.concatenate([draws, lo_x + (hi_x - lo_x) * u], axis=1)
        sd_z = np.concatenate([sd, np.full(len(extra), np.nan)])
    return CNNEstimate(names, theta, draws.std(axis=0, ddof=1), interval, draws, sd_z,
                       time.perf_counter() - t0, model)
