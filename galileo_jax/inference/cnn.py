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
random (:func:`simulate_examples`).

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
import json
import math
import os
from dataclasses import asdict, dataclass
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
#: Folder of the models shipped inside the package (package data, so ``pip install .`` has
#: them too; searched first by :func:`find_model`).
MODELS_DIR = Path(__file__).resolve().parents[1] / "models"
#: Environment variable naming more folders of trained models (``os.pathsep``-separated),
#: searched after :data:`MODELS_DIR` and before ``./models`` (where ``galileo_jax.train``
#: writes by default).
MODELS_ENV = "GALILEO_JAX_MODELS"
#: Largest relative difference between a video's frame rate and the model's.
FPS_TOLERANCE = 0.02


class CNNError(GalileoError):
    """No usable trained model (none matches the scene, or the files are unreadable)."""


def scene_hash(scene: Scene) -> str:
    """Short hash of what of ``scene`` changes the simulation (its physics; not its name or
    camera), so a model trained on one scene file serves every file of the same setup."""
    from galileo_jax.inference.problem import scene_key

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

    @property
    def dim(self) -> int:
        return len(self.names)

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


# ---------------------------------------------------------------------------- networks
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
    """The default network, ``x (B, L, T + 1) -> (B, 2, d)``: row 0 the mean mu of z, row 1
    the SD s of z (softplus, at least :data:`MIN_SD`).

    Five 1-D convolutions over time (kernel 5, 5, 5, 5, 3; ``width``, ``width``, 2 ``width``,
    2 ``width``, 2 ``width`` channels; GELU), average-pooled by 2 after the 2nd, 4th and 5th,
    flattened (time positions matter: the impact's time tells k1 and where object 2 starts),
    then Dense ``hidden`` -> Dense ``hidden`` -> Dense 2d.
    """

    def __init__(self, n_traces: int, dim: int, n_samples: int, width: int = 32, hidden: int = 128, *,
                 rngs: nnx.Rngs):
        w2 = 2 * width
        self.convs = nnx.List([nnx.Conv(n_traces + 1, width, 5, rngs=rngs), nnx.Conv(width, width, 5, rngs=rngs),
                               nnx.Conv(width, w2, 5, rngs=rngs), nnx.Conv(w2, w2, 5, rngs=rngs),
                               nnx.Conv(w2, w2, 3, rngs=rngs)])
        self.dense1 = nnx.Linear((n_samples // 8) * w2, hidden, rngs=rngs)
        self.dense2 = nnx.Linear(hidden, hidden, rngs=rngs)
        self.out = nnx.Linear(hidden, 2 * dim, rngs=rngs)
        self.dim = dim

    def __call__(self, x: jax.Array) -> jax.Array:
        y = x
        for i, conv in enumerate(self.convs):
            y = nnx.gelu(conv(y))
            if i in (1, 3, 4):
                y = nnx.avg_pool(y, (2,), (2,))
        y = y.reshape(y.shape[0], -1)
        y = nnx.gelu(self.dense2(nnx.gelu(self.dense1(y))))
        out = self.out(y).reshape(-1, 2, self.dim)
        return jnp.stack([out[:, 0], jax.nn.softplus(out[:, 1]) + MIN_SD], axis=1)


def build_network(spec: CNNSpec, seed: int = 0) -> nnx.Module:
    """A freshly initialised network for ``spec`` (``rngs`` from ``seed``)."""
    rngs = nnx.Rngs(seed)
    if spec.architecture == "seed":
        return SeedCNN(spec.n_traces, spec.dim, rngs=rngs)
    return ProfileCNN(spec.n_traces, spec.dim, spec.n_samples, spec.width, spec.hidden, rngs=rngs)


# ---------------------------------------------------------------------------- predictions
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
    if x.shape[1:] != (spec.n_samples, spec.n_traces + 1):
        raise ValueError(f"network input must have shape (B, {spec.n_samples}, {spec.n_traces + 1}), got {x.shape}")
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

    Examples whose mask is all zero (rollouts :func:`simulate_examples` dropped) do not count.
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


# ---------------------------------------------------------------------------- the input window
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


# ---------------------------------------------------------------------------- simulated training data
class NoiseModel(NamedTuple):
    """How training profiles are corrupted and cut (the observation model of
    :mod:`galileo_jax.likelihood`: independent Gaussian position errors, differenced).

    Attributes:
        position_sd: (low, high) in m: each trace's position noise SD is log-uniform on it.
        min_samples: shortest valid length of a training window (samples).
        prefix: largest masked prefix (samples), drawn for a third of the examples (videos that
            start less than ``release_offset`` before the release).
    """

    position_sd: tuple[float, float] = (5e-5, 3e-3)
    min_samples: int = 24
    prefix: int = 6


def training_prior(space: ParamSpace, scene: Scene, key: jax.Array, n: int, slide_margin: float = 0.02) -> jax.Array:
    """n draws (n, d) of theta from the prior of ``space``, with object 1's friction below
    tan(ramp angle) - ``slide_margin`` when it starts on the ramp (so it slides: ``fit``
    rejects videos where it never moves). Pure; ``scene`` is read in Python only.
    """
    theta = space.sample_prior(key, n)
    if "k1" in space.names and scene.placement(0) == "ramp":
        j = space.index("k1")
        lo = space.lower[j]
        hi = min(space.upper[j], math.tan(scene.ramp.angle) - slide_margin)
        u = jax.random.uniform(jax.random.fold_in(key, 1), (n,), minval=1e-6, maxval=1 - 1e-6)
        theta = theta.at[:, j].set(lo + (hi - lo) * u)
    return theta


#: The seed's training and test prior (NOTES.md "CNN", dissertation 4.3): frictions uniform on
#: (0, SEED_FRICTION), masses on (0, 1).
SEED_FRICTION = 0.3


def seed_prior(space: ParamSpace, key: jax.Array, n: int) -> jax.Array:
    """n draws (n, d) of theta from the seed's prior: k1, k2 ~ U(0, 0.3), phi = (m1 - m2) / (m1 + m2)
    with m1, m2 ~ U(0, 1) (so phi is not uniform), the other coordinates (the release time) from
    ``space``'s prior. Pure. The like-for-like setting of the seed's error table."""
    k = jax.random.split(key, 3)
    theta = space.sample_prior(k[0], n)
    fr = jax.random.uniform(k[1], (n, 2), minval=0.0, maxval=SEED_FRICTION)
    m = jax.random.uniform(k[2], (n, 2), minval=1e-3, maxval=1.0)
    cols = {"k1": fr[:, 0], "k2": fr[:, 1], "phi": (m[:, 0] - m[:, 1]) / (m[:, 0] + m[:, 1])}
    for name, col in cols.items():
        if name in space.names:
            theta = theta.at[:, space.index(name)].set(col.astype(theta.dtype))
    return theta


def simulate_examples(engine, spec: CNNSpec, noise: NoiseModel, theta: jax.Array, key: jax.Array,
                      views: int = 1) -> jax.Array:
    """Network inputs (n * views, L, T + 1) float32 for parameters ``theta`` (n, d) (pure, jittable).

    One rollout per row of ``theta`` on ``engine`` (MJX: vmapped in chunks of ``engine.max_batch``;
    C MuJoCo: one batched native call through a callback), at the window's frame times t_k = k / fps, the
    release at ``release_offset`` + theta's ``dt_release``), then ``views`` noisy, cut copies of
    each: position noise e ~ N(0, sd^2) per trace with sd log-uniform on ``noise.position_sd``,
    velocity noise (e[k+1] - e[k]) * fps; a valid length uniform on [min_samples, L]; a masked
    prefix for a third of the copies. Rows of the output are grouped by view (view-major).
    """
    from galileo_jax.inference.problem import ProblemData, map_batch

    n = theta.shape[0]
    L, T = spec.n_samples, spec.n_traces
    data = ProblemData(jnp.arange(L + 1) / spec.fps, jnp.asarray(spec.release_offset), None)
    prof = map_batch(lambda t: engine.profile_theta(t, data), jnp.asarray(theta, jnp.float64), engine.max_batch)
    # A rollout that blew up (extreme mass ratios: phi near +-1 leaves an object of ~0 kg) is
    # dropped: all-zero input and mask, which the loss skips (:func:`usable`).
    ok = jnp.all(jnp.isfinite(prof) & (jnp.abs(prof) <= MAX_SPEED), axis=(1, 2))
    prof = jnp.where(ok[:, None, None], prof, 0.0)
    ok = jnp.tile(ok, views)
    prof = jnp.tile(jnp.swapaxes(prof, 1, 2).astype(jnp.float32), (views, 1, 1))  # (B, L, T)
    b = prof.shape[0]
    k_sd, k_e, k_len, k_pre, k_has = jax.random.split(key, 5)
    lo, hi = math.log(noise.position_sd[0]), math.log(noise.position_sd[1])
    sd = jnp.exp(jax.random.uniform(k_sd, (b, 1, T), jnp.float32, minval=lo, maxval=hi))
    e = sd * jax.random.normal(k_e, (b, L + 1, T), jnp.float32)
    v = prof + jnp.diff(e, axis=1) * spec.fps
    length = jax.random.randint(k_len, (b, 1), noise.min_samples, L + 1)
    prefix = jnp.where(jax.random.uniform(k_has, (b, 1)) < 1 / 3,
                       jax.random.randint(k_pre, (b, 1), 0, noise.prefix + 1), 0)
    k = jnp.arange(L)[None]
    mask = ((k >= prefix) & (k < length) & ok[:, None]).astype(jnp.float32)[..., None]  # (B, L, 1)
    # float32 throughout: with x64 on, float64 inputs would promote the convolutions to float64,
    # 3x slower per training step (measured: 2.8 s vs 0.9 s of simulation).
    return jnp.concatenate([v * mask, mask], axis=-1).astype(jnp.float32)


# ---------------------------------------------------------------------------- saved models
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


def save_model(path: Path, spec: CNNSpec, params, info: dict) -> None:
    """Write a trained model to folder ``path`` atomically: ``model.json`` (spec and training
    record) and ``weights/`` (an Orbax checkpoint of the parameter state). An existing model
    there is replaced only once the new one is complete."""
    import shutil
    import orbax.checkpoint as ocp

    path = Path(path).resolve()
    tmp = path.with_name(path.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    with ocp.StandardCheckpointer() as ckpt:
        ckpt.save(tmp / "weights", jax.tree_util.tree_map(np.asarray, nnx.to_pure_dict(params)))
    (tmp / "model.json").write_text(json.dumps({"spec": spec.to_json(), **info}, indent=1, default=float))
    old = path.with_name(path.name + ".old")
    shutil.rmtree(old, ignore_errors=True)
    if path.exists():
        path.rename(old)
    tmp.rename(path)
    shutil.rmtree(old, ignore_errors=True)


def load_model(path: Path) -> TrainedModel:
    """Load a model folder written by :func:`save_model` (or by ``python -m galileo_jax.train``).

    Raises:
        CNNError: the folder is missing or not a model.
    """
    import orbax.checkpoint as ocp

    path = Path(path).resolve()
    meta = path / "model.json"
    if not meta.is_file():
        raise CNNError(f"{path} is not a trained CNN model (no model.json); train one with python -m galileo_jax.train")
    try:
        info = json.loads(meta.read_text())
        spec = CNNSpec.from_json(info.pop("spec"))
    except (ValueError, KeyError, TypeError) as err:
        raise CNNError(f"{meta} is unreadable ({err}); retrain the model") from None
    graphdef, params = nnx.split(build_network(spec), nnx.Param)
    target = jax.tree_util.tree_map(np.asarray, nnx.to_pure_dict(params))
    try:
        with ocp.StandardCheckpointer() as ckpt:
            restored = ckpt.restore(path / "weights", target)
    except Exception as err:  # noqa: BLE001 - orbax raises many kinds; any means an unusable model
        raise CNNError(f"cannot read the weights in {path / 'weights'} ({type(err).__name__}); retrain the model") from None
    nnx.replace_by_pure_dict(params, jax.tree_util.tree_map(jnp.asarray, restored))
    return TrainedModel(spec, graphdef, params, path, info)


def find_model(scene: Scene, fps: float, path: Path | str | None = None,
               architecture: str | None = None) -> TrainedModel:
    """The trained model for ``scene`` at ``fps``: ``path`` if given, else the first folder
    under :func:`model_dirs` whose spec matches the scene's physics (:func:`scene_hash`) and
    frame rate (within :data:`FPS_TOLERANCE`), preferring the default architecture (and,
    among equals, the earlier folder).

    Raises:
        CNNError: ``path`` does not fit the scene, or no shipped model does (the message says
            how to train one).
    """
    want = scene_hash(scene)
    if path is not None:
        model = load_model(Path(path))
        if model.spec.scene_hash != want:
            raise CNNError(f"the CNN in {path} was trained on scene {model.spec.scene!r}, whose physics differ "
                           f"from scene {scene.name!r}; train one for this scene (python -m galileo_jax.train)")
        return model
    found = []
    metas = [m for d in model_dirs() for m in sorted(d.glob("*/model.json"))]
    for order, meta in enumerate(metas):
        try:
            spec = CNNSpec.from_json(json.loads(meta.read_text())["spec"])
        except (ValueError, KeyError, TypeError):
            continue
        if spec.scene_hash == want and abs(spec.fps - fps) <= FPS_TOLERANCE * spec.fps \
                and (architecture is None or spec.architecture == architecture):
            found.append((spec.architecture != "profile", order, meta.parent))
    if not found:
        raise CNNError(f"no trained CNN matches scene {scene.name!r} at {fps:g} fps; train one: python -m "
                       f"galileo_jax.train --config configs/cnn_ramp20.yaml --scene YOUR_SCENE.yaml --out models/NAME")
    return load_model(sorted(found)[0][2])


def model_dirs() -> list[Path]:
    """Folders searched for trained models, in order: the package's own (:data:`MODELS_DIR`),
    those named by ``$GALILEO_JAX_MODELS`` (:data:`MODELS_ENV`), and ``./models``."""
    extra = [Path(p) for p in os.environ.get(MODELS_ENV, "").split(os.pathsep) if p]
    out = []
    for d in [MODELS_DIR, *extra, Path.cwd() / "models"]:
        if d.is_dir() and all(d.resolve() != o.resolve() for o in out):
            out.append(d)
    return out


# ---------------------------------------------------------------------------- an estimate for one video
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
        sd_z: (d,) the network's SD in the unconstrained coordinates z (0: the seed's network).
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


def estimate(model: TrainedModel, obs: Observation, space: ParamSpace, key: jax.Array, n_draws: int = 256) -> CNNEstimate:
    """Run ``model`` on an observed video and return the estimate in ``space``'s coordinates.

    The release-time correction is shifted from the window's frame to the tracker's estimate
    (:func:`network_input`) and every coordinate is kept 0.1% of its range inside the bounds.

    Raises:
        CNNError: the model predicts other coordinates than ``space`` has (e.g. the fit adds
            effects, which the CNN does not know), or the video does not fit the model.
    """
    import time

    spec = model.spec
    if tuple(space.names) != tuple(spec.names):
        raise CNNError(f"the CNN predicts {list(spec.names)}, this fit has {list(space.names)}; the CNN knows the "
                       f"base model only: drop --effects, or use --method grad or mh")
    t0 = time.perf_counter()
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
    return CNNEstimate(tuple(spec.names), theta, draws.std(axis=0, ddof=1), interval, draws, sd,
                       time.perf_counter() - t0, model)
