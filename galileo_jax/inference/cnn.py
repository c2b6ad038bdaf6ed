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

All functions here are pure JAX (the model is split into a graph definition and a parameter
state with :func:`flax.nnx.split`), except loading and the input window, which are I/O and NumPy.
"""

from __future__ import annotations

import hashlib
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
        return cls(**d)

    @classmethod
    def for_scene(cls, scene: Scene, fps: float, **kw) -> "CNNSpec":
        """The spec of a network for ``scene`` at ``fps`` (base model: no effects).

        Raises:
            ValueError: unknown architecture, or a window too short for the release offset.
        """
        space = ParamSpace.from_scene(scene)
        spec = cls(scene.name, scene_hash(scene), float(fps), space.names, space.lower, space.upper,
                   2 * scene.n_objects, **kw)
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
                 n_scene: int = 0, *, rngs: nnx.Rngs):
        w2 = 2 * width
        self.n_traces, self.n_scene = n_traces, n_scene
        self.convs = nnx.List([nnx.Conv(n_traces + 1, width, 5, rngs=rngs), nnx.Conv(width, width, 5, rngs=rngs),
                               nnx.Conv(width, w2, 5, rngs=rngs), nnx.Conv(w2, w2, 5, rngs=rngs),
                               nnx.Conv(w2, w2, 3, rngs=rngs)])
        self.dense1 = nnx.Linear((n_samples // 8) * w2 + n_scene, hidden, rngs=rngs)
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
        y = nnx.gelu(self.dense2(nnx.gelu(self.dense1(y))))
        out = self.out(y).reshape(-1, 2, self.dim)
        return jnp.stack([out[:, 0], jax.nn.softplus(out[:, 1]) + MIN_SD], axis=1)


def build_network(spec: CNNSpec, seed: int = 0) -> nnx.Module:
    """A freshly initialised network for ``spec`` (``rngs`` from ``seed``)."""
    rngs = nnx.Rngs(seed)
    if spec.architecture == "seed":
        return SeedCNN(spec.n_traces, spec.dim, rngs=rngs)
    return ProfileCNN(spec.n_traces, spec.dim, spec.n_samples, spec.width, spec.hidden, spec.n_scene, rngs=rngs)


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
