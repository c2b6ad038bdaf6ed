"""An inference problem: simulator + observation + parameter space + likelihood.

Coordinates: ``theta`` (d,) are the identifiable parameters of :class:`~galileo_jax.params.ParamSpace`
(e.g. k1, k2, phi); ``z`` (d,) their unconstrained transform (samplers and optimisers work in z).

Code and data are kept apart, so that one compiled program serves many videos:

* :class:`Engine` is the static part: the MJX simulator of the scene (with its effects), the
  parameter space, the likelihood kind and the rollout lengths. Its methods are the pure
  functions of the problem, ``f(z, data)``; they never read an observation.
* :class:`ProblemData` is the video-dependent part, a pytree of arrays (frame times,
  release time, the :class:`~galileo_jax.likelihood.Likelihood` with the observed profile and
  its whitening, and the scene's own numbers, :class:`~galileo_jax.physics.simulate.SimArrays`),
  passed INTO the jitted functions as an argument.

Every :class:`Problem` of the same scene structure (:func:`~galileo_jax.physics.simulate.structure_key`:
the objects, their shapes and contacts, not the ramp angle, lengths, start positions or
sizes), effects and (bucketed) video length shares one set of jitted functions (module-level
caches), so a second video, even of a new scene, costs no tracing or compilation in the same
process, and JAX's persistent cache serves the next process. Shapes are bucketed: the profile
is padded to a multiple of :data:`PAD_SAMPLES` samples (padding is outside the likelihood's
mask) and rollouts cover a whole number of :data:`PAD_SAMPLES`-frame blocks after the release.

Every batched entry point runs ONE vmapped MJX rollout per call (chunked with
``jax.lax.map(..., batch_size=max_batch)`` above ``max_batch`` rollouts: see
:data:`DEFAULT_MAX_BATCH`). Every rollout covers the whole padded video from t = 0 (plus the
release-time window): its length depends on the padded number of frames only, not on the
release time or the fit window, so that videos of one scene and length share programs.

Finite-difference Jacobians. AD through MJX contacts misses how parameters move event times
(the end of the ramp, the impact), so the residual Jacobian can be wrong in sign.
:func:`fd_jacobian_fn` wraps a function in a ``jax.custom_jvp`` whose JVP is t . J with J the
central difference (f(z + h e_j) - f(z - h e_j)) / (2 h), computed in one vmapped batch of
2d + 1 rollouts; the rule is linear in the tangent t, so ``jacfwd``, ``linearize`` and
transposition (as used by optimistix) all work.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any, Callable, Hashable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from galileo_jax.effects.runtime import release_delay, split_values
from galileo_jax.likelihood import DEFAULT_KIND, DEFAULT_SD_MODEL, Likelihood, make_likelihood
from galileo_jax.observation import Observation
from galileo_jax.params import ParamSpace
from galileo_jax.physics.simulate import (
    PhysParams,
    SimArrays,
    Simulator,
    make_simulator,
    rollout,
    sample_poses,
    scene_effects,
    steps_needed,
    structure_key,
    velocity_profile,
)
from galileo_jax.scene import Scene, scene_key

#: Default central-difference step in unconstrained coordinates z (see inference/grad.py for
#: the measurement that chose it).
DEFAULT_FD_STEP = 0.05
#: Largest number of rollouts vmapped at once; bigger batches are chunked with lax.map.
#: Measured on 2 CPU cores (two-box scene, 1.6 s at 240 Hz, float64): 30 rollouts/s at
#: batch 1, 155/s at 16, 115/s at 64, 127/s at 256.
DEFAULT_MAX_BATCH = 16
#: The same on a GPU. Measured on an H100 (``benchmarks/results/engines_gpu.md``): one vmap of 4096
#: rollouts ran 8x the rollouts/s of one of 256; a CNN training step of 1,024 rollouts in one vmap
#: took 65 GB of the card's 80 (``cnn_throughput_gpu.md``), hence 1,024.
GPU_MAX_BATCH = 1024


def default_max_batch() -> int:
    """Largest vmapped batch of rollouts for JAX's default backend: :data:`DEFAULT_MAX_BATCH` on a CPU,
    :data:`GPU_MAX_BATCH` on an accelerator."""
    return DEFAULT_MAX_BATCH if jax.default_backend() == "cpu" else GPU_MAX_BATCH


#: Profiles are padded to a multiple of this many samples, and rollouts to whole blocks of
#: this many frames, so that videos of similar length share compiled programs.
PAD_SAMPLES = 8


def fd_jacobian_fn(f: Callable[..., jax.Array], step: float) -> Callable[..., jax.Array]:
    """``f(z, data)`` with its derivative in z replaced by central finite differences.

    Arguments:
        f: pure function (z (d,), data) -> (...), vmappable in z.
        step: difference step h in the units of z.

    Returns:
        g with g(z, data) = f(z, data) and jvp in z: sum_j t_j (f(z + h e_j) - f(z - h e_j)) / (2 h).
        The 2d + 1 evaluations run as one vmapped batch. ``data`` is treated as constant
        (its tangent is ignored).
    """

    @jax.custom_jvp
    def g(z, data):
        return f(z, data)

    @g.defjvp
    def g_jvp(primals, tangents):
        (z, data), (t, _) = primals, tangents
        d = z.shape[-1]
        eye = jnp.eye(d, dtype=z.dtype) * step
        pts = jnp.concatenate([z[None], z[None] + eye, z[None] - eye])
        out = jax.vmap(f, in_axes=(0, None))(pts, data)
        jac = (out[1:d + 1] - out[d + 1:]) / (2.0 * step)  # (d, ...)
        return out[0], jnp.tensordot(t, jac, axes=(0, 0))

    return g


def pad_rows(x: np.ndarray, size: int) -> np.ndarray:
    """``x`` (n, ...) with copies of its last row appended up to ``size`` rows (>= n): a batch
    of a fixed shape, so one compiled program serves every n; the copies' outputs are dropped."""
    x = np.asarray(x)
    return np.concatenate([x, np.repeat(x[-1:], size - x.shape[0], axis=0)]) if size > x.shape[0] else x


def map_batch(f: Callable, xs, max_batch: int):
    """Apply unbatched ``f`` over the leading axis of the pytree ``xs``: vmap, or lax.map with
    batch_size ``max_batch`` for bigger batches (pure; use inside jit)."""
    n = jax.tree_util.tree_leaves(xs)[0].shape[0]
    if n <= max_batch:
        return jax.vmap(f)(xs)
    return jax.lax.map(f, xs, batch_size=max_batch)


# ---------------------------------------------------------------------------- shared jit cache
_JIT_CACHE: "OrderedDict[tuple, Callable]" = OrderedDict()
_JIT_CACHE_SIZE = 128


def clear_caches() -> None:
    """Forget the shared engines and jitted functions, and JAX's own caches.

    Every compiled XLA:CPU program keeps hundreds of memory mappings; a process that compiles
    many different programs (a test session: ~200) reaches Linux's default limit of 65530 maps
    (``vm.max_map_count``) and aborts inside XLA. Long-running callers that move on to other
    scenes (test modules, benchmark suites) call this between them.
    """
    _JIT_CACHE.clear()
    _ENGINES.clear()
    jax.clear_caches()


def cached_jit(static_key: Hashable, name: Hashable, fn: Callable, **jit_kw) -> Callable:
    """``jax.jit(fn)``, shared by every caller with the same (static_key, name).

    ``fn`` must depend only on what ``static_key`` identifies (never on an observation: pass
    those as arguments); the first caller's ``fn`` serves all later ones.
    """
    key = (static_key, name)
    if key in _JIT_CACHE:
        _JIT_CACHE.move_to_end(key)
        return _JIT_CACHE[key]
    jitted = jax.jit(fn, **jit_kw)
    _JIT_CACHE[key] = jitted
    while len(_JIT_CACHE) > _JIT_CACHE_SIZE:
        _JIT_CACHE.popitem(last=False)
    return jitted


# ---------------------------------------------------------------------------- static / dynamic parts
class ProblemData(NamedTuple):
    """The observation-dependent inputs of an :class:`Engine`'s pure functions (a pytree).

    Attributes:
        frame_times: (M + 1,) frame times in s (padded past the video's end at 1 / fps).
        release_time: () video time in s at which the objects are released.
        likelihood: the observation's :class:`~galileo_jax.likelihood.Likelihood`, length M.
        physics: the scene's :class:`~galileo_jax.physics.simulate.SimArrays` (None: the engine's own
            scene; only for callers that jit an engine's functions themselves).
        live_steps: () physics steps after the earliest release that the likelihood uses (to
            the fit window's end); the C engine simulates only these
            (:func:`~galileo_jax.physics.simulate.rollout`); ``n_steps`` for the whole video
            (reports, :attr:`Problem.whole_data`). None: the whole rollout without the skip (a
            separately compiled program).
    """

    frame_times: jax.Array
    release_time: jax.Array
    likelihood: Likelihood
    physics: SimArrays | None = None
    live_steps: jax.Array | None = None


@dataclass(frozen=True, eq=False)
class Engine:
    """The static part of a :class:`Problem` (module docstring): shared, never holds an observation.

    One Engine per scene and settings; engines of scenes of one structure share ``key`` and so
    their jitted functions (:func:`cached_jit`). Its pure functions therefore take the scene's
    numbers from ``data.physics`` (:meth:`sim_for`), never from ``sim``.

    Attributes:
        key: hashable identity of the compiled programs: (scene structure, fps, effects, batch
            size, engine, parameter space, rollout length in s; see :func:`get_engine`). The
            likelihood's kind is static metadata of its pytree, so jit tells kinds apart itself.
        sim: the simulator of the engine's own scene.
        space: the parameter space.
        n_steps: physics steps of a rollout (static).
        max_batch: largest vmapped batch of rollouts.
    """

    key: tuple
    sim: Simulator
    space: ParamSpace
    n_steps: int
    max_batch: int

    def sim_for(self, data: ProblemData) -> Simulator:
        """The simulator of ``data``'s scene: ``sim`` with ``data.physics`` in place of its numbers
        (``sim`` itself where ``data.physics`` is None)."""
        return self.sim if data.physics is None else self.sim.with_arrays(data.physics)

    def profile_physical(self, params: PhysParams, data: ProblemData) -> jax.Array:
        """Unbatched simulated profile (2n, M) in m/s for :class:`PhysParams`, released at the
        tracker's estimate (pure)."""
        return velocity_profile(self.sim_for(data), params, data.frame_times, data.release_time, self.n_steps,
                                data.live_steps)

    def release_time(self, theta: jax.Array, data: ProblemData) -> jax.Array:
        """Video time (s) at which the simulated objects start to move at theta (d,) (pure): the
        tracker's estimate plus theta's ``dt_release``, plus the effects' ``release_delay``
        (:mod:`galileo_jax.effects.base`; 0 without such an effect)."""
        release = data.release_time + self.space.release_offset(theta)
        effects = self.sim.effects
        if any(e.release_delay is not None for e in effects):
            params = self.space.physical(theta)
            release = release + release_delay(effects, split_values(effects, params.effects), params.friction,
                                              self.sim_for(data).ctx)
        return release

    def profile_theta(self, theta: jax.Array, data: ProblemData) -> jax.Array:
        """Unbatched simulated profile (2n, M) at theta (d,) (pure), as the camera sees it:
        released at :meth:`release_time`, velocities stretched by the scale factor
        1 + ``scale_error`` (1 when the scale is exact)."""
        release = self.release_time(theta, data)
        profile = velocity_profile(self.sim_for(data), self.space.physical(theta), data.frame_times, release,
                                   self.n_steps, data.live_steps)
        return profile * self.space.scale_factor(theta)

    def profile_z(self, z: jax.Array, data: ProblemData) -> jax.Array:
        """Unbatched simulated profile (2n, M) at unconstrained z (d,) (pure, fit window)."""
        return self.profile_theta(self.space.from_unconstrained(z), data)

    def loglik_z(self, z: jax.Array, data: ProblemData) -> jax.Array:
        """Unbatched log-likelihood (or similarity) at z (d,); -inf if the rollout is not finite."""
        ll = data.likelihood(self.profile_z(z, data))
        return jnp.where(jnp.isfinite(ll), ll, -jnp.inf)

    def residuals_z(self, z: jax.Array, data: ProblemData) -> jax.Array:
        """Unbatched standardised residuals (T * M,) at z (d,) (pure)."""
        return data.likelihood.residuals(self.profile_z(z, data))

    def poses(self, theta: jax.Array, data: ProblemData) -> jax.Array:
        """(M + 1, n_objects, 3) simulated poses (x m, z m, pitch rad) at the frame times (pure),
        as the camera sees them: displacements from the start stretched by 1 + ``scale_error``."""
        traj = rollout(self.sim_for(data), self.space.physical(theta), self.n_steps, data.live_steps)
        poses = sample_poses(traj, data.frame_times - self.release_time(theta, data))
        start = poses[:1, :, :2]
        xy = start + self.space.scale_factor(theta) * (poses[..., :2] - start)
        return poses.at[..., :2].set(xy)


_ENGINES: "OrderedDict[tuple, Engine]" = OrderedDict()
_ENGINES_SIZE = 16


def _blocks(seconds: float, fps: float) -> float:
    """``seconds`` rounded up to whole blocks of PAD_SAMPLES frames (at least one)."""
    frames = max(math.ceil(seconds * fps - 1e-9), 1)
    return PAD_SAMPLES * math.ceil(frames / PAD_SAMPLES) / fps


def release_margin(scene: Scene) -> float:
    """Seconds by which the fitted release can precede the tracker's estimate (``dt_release``'s
    lower bound, ``simulation.release_window``; 0 when the release is not fitted): a rollout
    must run that much longer."""
    return float(scene.simulation.release_window) if scene.simulation.fit_release else 0.0


def get_engine(scene: Scene, fps: float, effects: tuple, seconds: float, max_batch: int,
               engine: str = "mjx", ensemble: int = 1) -> Engine:
    """The shared :class:`Engine` for these settings (built once per process and key); its
    rollouts cover ``seconds`` after the release plus the release-time window, on the
    simulation ``engine`` ("mjx" or "mujoco", see :func:`~galileo_jax.physics.simulate.make_simulator`),
    each the mean of ``ensemble`` rollouts (:func:`~galileo_jax.physics.simulate.ensemble_offsets`)."""
    length = _blocks(seconds + release_margin(scene), fps)  # an earlier release runs longer
    # K = 1 leaves the key as it was: the compiled programs of plain fits (persistent cache) stay valid
    settings = (float(fps), tuple(effects), int(max_batch), engine) + ((int(ensemble),) if ensemble != 1 else ())
    scene_id = ("scene", scene_key(scene), float(scene.camera.scale_tolerance or 0.0))
    own = scene_id + settings + (length,)
    if own in _ENGINES:
        _ENGINES.move_to_end(own)
        return _ENGINES[own]
    sim = make_simulator(scene, float(fps), effects, engine, ensemble)
    space = ParamSpace.from_scene(scene, effects)
    # The C engine's rollouts read the MjModel on the host: its programs are the scene's own.
    shared = structure_key(sim) if engine == "mjx" else scene_id
    engine = Engine((shared,) + settings + (space, length), sim, space, steps_needed(sim, length), int(max_batch))
    _ENGINES[own] = engine
    while len(_ENGINES) > _ENGINES_SIZE:
        _ENGINES.popitem(last=False)
    return engine


def live_steps(scene: Scene, sim: Simulator, observation, frame_times: np.ndarray, n_steps: int) -> int:
    """Physics steps a rollout needs for the samples the likelihood uses: from the earliest
    release the fit allows (the tracker's estimate minus ``simulation.release_window``) to the
    last frame of the fit window (``observation.mask``), plus 2 for the interpolation; at most
    ``n_steps``. The frames after the fit window (objects at rest, a second collision left
    out) are simulated only for the reports (measured on README command 1's example: the fit
    window ends 1.5 s after the release of a 3 s video; 420 of 833 steps, the rollouts' time
    9.1 -> 5.2-5.6 s)."""
    used = np.flatnonzero(np.asarray(observation.mask, bool))
    if used.size == 0:
        return int(n_steps)
    seconds = float(frame_times[used[-1] + 1]) - float(observation.release_time) + release_margin(scene)
    return int(min(max(steps_needed(sim, max(seconds, 0.0)) + 2, 2), n_steps))


def padded_frame_times(frame_times: np.ndarray, fps: float, n_samples: int) -> np.ndarray:
    """(N,) frame times extended at 1 / fps to n_samples + 1 entries."""
    ft = np.asarray(frame_times, np.float64)
    extra = n_samples + 1 - ft.size
    if extra <= 0:
        return ft
    return np.concatenate([ft, ft[-1] + np.arange(1, extra + 1) / float(fps)])


class BatchedAPI:
    """The jitted batched API every problem type shares (Problem, JointProblem, FixedProblem).

    Needs ``space``, ``loglik_fn`` (pure ``f(z, data)``), ``max_batch``, ``data`` and
    ``static_key``; the jitted functions take ``data`` as an argument and are shared through
    :func:`cached_jit` by every problem with the same ``static_key``.
    """

    @property
    def dim(self) -> int:
        return self.space.dim

    @property
    def names(self) -> tuple[str, ...]:
        return self.space.names

    def map_batch(self, f: Callable, xs):
        """:func:`map_batch` with this problem's ``max_batch``."""
        return map_batch(f, xs, self.max_batch)

    def jitted(self, name: Hashable, fn: Callable) -> Callable:
        """``jax.jit(fn)`` shared by every problem with this ``static_key`` (see :func:`cached_jit`)."""
        return cached_jit(self.static_key, name, fn)

    def log_density_fn(self, zb: jax.Array, data) -> jax.Array:
        """Pure batched log posterior density (unnormalised), (B, d) -> (B,); for use inside jit/scan.

        log p(z | obs) = log_lik(z) + log_prior(z) (prior includes the transform's
        log-Jacobian); -inf where the rollout or the prior is not finite. One vmapped rollout.
        """
        return batched_log_density(self.space, self.loglik_fn, self.max_batch, zb, data)

    @property
    def pads_batches(self) -> bool:
        """Whether every batched call of up to ``max_batch`` rows runs one program (:meth:`batch_size`):
        on the C engine, whose rollout cache simulates padded copies once (each shape is a
        program compiled once, 0.1-2 s, then taken from the persistent cache). MJX pads only to
        the next power of two (a padded row costs a rollout there)."""
        return self.simulator_engine == "mujoco"

    def batch_size(self, n: int) -> int:
        """Rows (>= n, for 1 <= n <= ``max_batch``) that a batch of n runs as in :meth:`in_chunks`:
        ``max_batch`` where :attr:`pads_batches`, else the next power of two (at most
        ``max_batch``). Each size is a compiled program of every batched function; an MJX one
        takes 6-10 s to compile on a 2-core CPU (the user-effect diagnose test compiled its
        log-likelihood at 6 sizes), and padding costs at most 2x the rollouts of a small call."""
        if self.pads_batches:
            return self.max_batch
        return min(1 << max(int(n) - 1, 0).bit_length(), self.max_batch)

    def in_chunks(self, name: Hashable, fn: Callable, z, data=None) -> jax.Array:
        """``fn(zb, data)`` ((B, d) -> (B, ...)) jitted, over the rows of ``z`` (B, d), with
        ``data`` (default the problem's), in chunks of ``max_batch`` rows, the last padded with
        copies of its last row to :meth:`batch_size`: a few compiled programs for every batch size
        (measured on README command 1 on the C engine: eight sizes, 0.15-0.35 s of compilation
        each, in every process). Returns (B, ...)."""
        jitted = self.jitted(name, fn)
        data = self.data if data is None else data
        z = np.asarray(z, np.float64)
        if z.shape[0] == 0:
            return jitted(jnp.asarray(z), data)
        mb = self.max_batch
        out = []
        for i in range(0, z.shape[0], mb):
            part = z[i:i + mb]
            out.append(np.asarray(jitted(jnp.asarray(pad_rows(part, self.batch_size(part.shape[0]))), data))
                       [:part.shape[0]])
        return jnp.asarray(np.concatenate(out))

    def log_density(self, z: jax.Array) -> jax.Array:
        """Jitted :meth:`log_density_fn` at this problem's data: (B, d) -> (B,) (:meth:`in_chunks`)."""
        space, f, mb = self.space, self.loglik_fn, self.max_batch
        return self.in_chunks("log_density", lambda zb, data: batched_log_density(space, f, mb, zb, data), z)

    def log_likelihood(self, z: jax.Array) -> jax.Array:
        """Log-likelihood (or similarity) at unconstrained points, (B, d) -> (B,) (:meth:`in_chunks`)."""
        f, mb = self.loglik_fn, self.max_batch
        return self.in_chunks("log_likelihood", lambda zb, data: map_batch(lambda z: f(z, data), zb, mb), z)


class Problem(BatchedAPI):
    """Simulator, observation, parameter space and likelihood of one fit.

    Arguments:
        scene: the validated scene (free parameters, priors, geometry).
        observation: the observed profile (frame rate, mask, noise SDs).
        likelihood: a likelihood kind (``galileo_jax.likelihood.KINDS``), default "gaussian_iid".
        sd_model: model-error floor in m/s for the Gaussian kinds.
        max_batch: largest vmapped batch of rollouts; larger batches are chunked (default
            :func:`default_max_batch`: 16 on a CPU, 1024 on a GPU).
        effects: extra physical effects (names or :class:`~galileo_jax.effects.Effect`), added
            to the scene's own ``effects``; their parameters follow the base ones in theta.
        engine: simulation engine, "mjx" (default; differentiable) or "mujoco" (C MuJoCo's
            batched rollouts, faster on CPU; finite-difference Jacobians only).
        pad_to: optional length (samples) to pad the profile to at least (rounded up to
            :data:`PAD_SAMPLES`): videos fitted as one batch
            (:func:`~galileo_jax.inference.batch.fit_grad_batch`) share one length.
        ensemble: simulated profiles as the mean of this many rollouts from start positions
            shifted by fractions of a physics step's travel
            (:func:`~galileo_jax.physics.simulate.ensemble_offsets`): a likelihood smoothed over
            where in a step the contact events fall, at ``ensemble`` times the rollouts.

    Raises:
        ValueError: the observation does not match the scene (number of objects), or any
            error of :func:`~galileo_jax.likelihood.make_likelihood` / ``ParamSpace.from_scene``.
        GalileoError: an unknown engine, or effects the C engine cannot simulate.

    Interface shared with :class:`~galileo_jax.inference.joint.JointProblem` and
    :class:`~galileo_jax.inference.fixed.FixedProblem` (what the optimisers and samplers use):
    ``space``, ``dim``, ``names``, ``data``, ``static_key``, ``likelihood`` (``log_norm``,
    ``is_gaussian``), the pure ``loglik_fn(z, data)`` and ``residual_fn(...)(z, data)``, the
    jitted batched ``log_likelihood``, ``log_density``, ``residuals``, and ``jitted``.
    """

    def __init__(self, scene: Scene, observation: Observation, likelihood: str = DEFAULT_KIND,
                 sd_model: float = DEFAULT_SD_MODEL, max_batch: int | None = None, effects=(),
                 engine: str = "mjx", pad_to: int | None = None, ensemble: int = 1):
        n_traces = 2 * scene.n_objects
        if np.shape(observation.profile)[0] != n_traces:
            raise ValueError(f"observation has {np.shape(observation.profile)[0]} velocity traces, "
                             f"the scene's {scene.n_objects} object(s) need {n_traces}")
        max_batch = default_max_batch() if max_batch is None else max_batch
        if max_batch < 1:
            raise ValueError(f"max_batch must be >= 1, got {max_batch}")
        self.scene = scene
        self.observation = observation
        self.effects = scene_effects(scene, effects)
        fps = float(observation.fps)
        n = int(np.shape(observation.profile)[1])
        n_pad = PAD_SAMPLES * math.ceil(max(n, int(pad_to or 0)) / PAD_SAMPLES)
        lik = make_likelihood(observation, likelihood, sd_model, n_samples=n_pad)
        ft = padded_frame_times(observation.frame_times, fps, n_pad)
        self.engine = get_engine(scene, fps, self.effects, float(ft[-1]), max_batch, engine, ensemble)
        release = float(observation.release_time)
        self.data = ProblemData(jnp.asarray(ft), jnp.asarray(release), lik, self.engine.sim.arrays,
                                jnp.asarray(live_steps(scene, self.engine.sim, observation, ft, self.n_steps)))
        self.n_samples = n

    # ------------------------------------------------------------------ static parts
    @property
    def sim(self) -> Simulator:
        return self.engine.sim

    @property
    def space(self) -> ParamSpace:
        return self.engine.space

    @property
    def max_batch(self) -> int:
        return self.engine.max_batch

    @property
    def static_key(self) -> tuple:
        return self.engine.key

    @property
    def simulator_engine(self) -> str:
        """The simulation engine of the rollouts: "mjx" or "mujoco"."""
        return self.engine.sim.engine

    @property
    def likelihood(self) -> Likelihood:
        return self.data.likelihood

    @property
    def n_steps(self) -> int:
        return self.engine.n_steps

    @property
    def whole_data(self) -> ProblemData:
        """:attr:`data` for rollouts of the whole video (reports), not only the fit window.

        Its ``live_steps`` is every step, not None: the reports then run the same compiled
        rollout as the fit, so their profile in the fit window is the fit's to the last bit
        (an MJX program built otherwise rounds differently, and an impact amplifies rounding
        differences into mm/s; measured 0.012 m/s, 1.9 nats, on one of two test rollouts)."""
        return self.data._replace(live_steps=jnp.asarray(self.n_steps, self.data.live_steps.dtype))

    # ------------------------------------------------------------------ pure building blocks
    @property
    def loglik_fn(self) -> Callable[[jax.Array, ProblemData], jax.Array]:
        """Pure unbatched log-likelihood ``f(z (d,), data) -> ()``."""
        return self.engine.loglik_z

    def residual_fn(self, jacobian: str = "fd", fd_step: float = DEFAULT_FD_STEP) -> Callable[[jax.Array, Any], jax.Array]:
        """Pure ``f(z (d,), data) -> standardised residuals (n_residuals,)``, whose z-derivative is AD or FD.

        Arguments:
            jacobian: "fd" (central differences via ``custom_jvp``, see module docstring) or "ad".
            fd_step: difference step in z.

        Raises:
            ValueError: unknown ``jacobian``, non-positive step, or a non-Gaussian likelihood.
        """
        check_residual_args(jacobian, fd_step, self.likelihood)
        res = self.engine.residuals_z
        return fd_jacobian_fn(res, fd_step) if jacobian == "fd" else res

    # ------------------------------------------------------------------ jitted batched API
    def profiles_physical(self, params: PhysParams) -> jax.Array:
        """Simulated profiles (B, 2n, N-1) in m/s for batched PhysParams (leaves (B, n)), released at the estimate."""
        eng = self.engine
        fn = self.jitted("profiles_physical",
                         lambda p, data: map_batch(lambda q: eng.profile_physical(q, data), p, eng.max_batch))
        out = fn(jax.tree_util.tree_map(lambda a: jnp.asarray(a, jnp.float64), params), self.whole_data)
        return out[..., :self.n_samples]

    def residuals(self, theta: jax.Array) -> jax.Array:
        """Standardised residuals at theta: (d,) -> (n_residuals,), or (B, d) -> (B, n_residuals).

        Length T * M with zeros at unused samples; ``problem.likelihood.used(r)`` selects the used ones.
        """
        theta = jnp.asarray(theta, jnp.float64)
        if not self.likelihood.is_gaussian:
            raise ValueError(f"likelihood {self.likelihood.kind!r} has no residuals")
        eng = self.engine
        out = self.in_chunks("residuals", lambda tb, data: map_batch(
            lambda t: data.likelihood.residuals(eng.profile_theta(t, data)), tb, eng.max_batch),
            theta.reshape(-1, theta.shape[-1]))
        return out[0] if theta.ndim == 1 else out

    def simulate(self, theta: jax.Array) -> jax.Array:
        """Simulated profile over the WHOLE video at theta: (d,) -> (2n, N-1), or (B, d) -> (B, 2n, N-1), m/s."""
        theta = jnp.asarray(theta, jnp.float64)
        eng = self.engine
        out = self.in_chunks("simulate", lambda tb, data: map_batch(
            lambda t: eng.profile_theta(t, data), tb, eng.max_batch),
            theta.reshape(-1, theta.shape[-1]), self.whole_data)
        return (out[0] if theta.ndim == 1 else out)[..., :self.n_samples]

    def poses(self, theta: jax.Array) -> np.ndarray:
        """(N, n_objects, 3) simulated poses (x m, z m, pitch rad) at the video's frame times."""
        fn = self.jitted("poses", self.engine.poses)
        out = fn(jnp.asarray(theta, jnp.float64), self.whole_data)
        return np.asarray(out)[:self.n_samples + 1]


def check_residual_args(jacobian: str, fd_step: float, likelihood) -> None:
    """Python-side validation shared by the problems' ``residual_fn``.

    Raises:
        ValueError: unknown ``jacobian``, non-positive step, or a non-Gaussian likelihood.
    """
    if jacobian not in ("fd", "ad"):
        raise ValueError(f"jacobian must be 'fd' or 'ad', got {jacobian!r}")
    if not fd_step > 0:
        raise ValueError(f"fd_step must be > 0, got {fd_step}")
    if not likelihood.is_gaussian:
        raise ValueError(f"likelihood {likelihood.kind!r} has no residuals; least squares needs a Gaussian kind")


def batched_log_density(space, loglik_fn: Callable, max_batch: int, zb: jax.Array, data) -> jax.Array:
    """log_prior(z) + loglik(z, data) for a batch zb (B, d) -> (B,); -inf where not finite (pure)."""
    lp = space.log_prior(zb) + map_batch(lambda z: loglik_fn(z, data), zb, max_batch)
    return jnp.where(jnp.isnan(lp), -jnp.inf, lp)


def simulated_observation(scene: Scene, params: PhysParams, *, fps: float = 30.0, duration: float = 1.5,
                          position_sd: float | np.ndarray = 1e-3, release_time: float = 0.1,
                          seed: int = 0, mask: np.ndarray | None = None, effects=()) -> Observation:
    """A synthetic :class:`Observation`: a rollout at ``params`` plus Gaussian position noise.

    For tests and benchmarks with known ground truth. Frame k is at k / fps, the objects are
    released at ``release_time`` (s), and each position trace gets independent N(0, sd^2)
    noise (m), exactly the observation model of :mod:`galileo_jax.likelihood`.

    Arguments:
        scene: the scene.
        params: unbatched true :class:`PhysParams`.
        fps: frame rate (frames per second).
        duration: video length in s (N = round(duration * fps) + 1 frames).
        position_sd: scalar or (2n,) position noise SD in m (also stored as ``position_sd``).
        release_time: release time in s.
        seed: NumPy seed of the noise.
        mask: optional (N - 1,) bool fit window (default: all samples).
        effects: effects simulated on top of the scene's own (values in ``params.effects``).

    Returns:
        The observation; ``pixels`` are the positions times the camera scale (no roll).
    """
    sim = make_simulator(scene, fps, scene_effects(scene, effects))
    n_frames = int(round(duration * fps)) + 1
    ft = np.arange(n_frames) / fps
    n = steps_needed(sim, ft[-1] - release_time)
    traj = jax.jit(lambda p: rollout(sim, p, n))(params)
    pos = np.asarray(sample_poses(traj, jnp.asarray(ft - release_time))[..., :2], np.float64)
    sd = np.broadcast_to(np.asarray(position_sd, np.float64), (2 * scene.n_objects,)).copy()
    rng = np.random.default_rng(seed)
    noisy = pos + rng.normal(size=pos.shape) * sd.reshape(scene.n_objects, 2)[None]
    from galileo_jax.observation import profile_from_positions

    profile = profile_from_positions(noisy, ft)
    moved = np.abs(pos[-1, :, 0] - pos[0, :, 0]) > 1e-3
    mask = np.ones(n_frames - 1, bool) if mask is None else np.asarray(mask, bool)
    return Observation(frame_times=ft, positions=noisy, pixels=noisy * scene.camera.scale, profile=profile,
                       position_sd=sd, mask=mask, release_time=float(release_time), fps=float(fps), moved=moved)
