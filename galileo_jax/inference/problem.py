"""An inference problem: simulator + observation + parameter space + likelihood, jitted once.

Coordinates: ``theta`` (d,) are the identifiable parameters of :class:`~galileo_jax.params.ParamSpace`
(e.g. k1, k2, phi); ``z`` (d,) their unconstrained transform (samplers and optimisers work in z).

Every batched entry point runs ONE vmapped MJX rollout per call (chunked with
``jax.lax.map(..., batch_size=max_batch)`` above ``max_batch`` rollouts: very large vmapped
batches were reported to hang XLA on CPU). The rollout covers the fit window only (up to the
last masked velocity sample); :meth:`Problem.simulate` covers the whole video.

Finite-difference Jacobians. AD through MJX contacts misses how parameters move event times
(the end of the ramp, the impact), so the residual Jacobian can be wrong in sign.
:func:`fd_jacobian_fn` wraps a function in a ``jax.custom_jvp`` whose JVP is t . J with J the
central difference (f(z + h e_j) - f(z - h e_j)) / (2 h), computed in one vmapped batch of
2d + 1 rollouts; the rule is linear in the tangent t, so ``jacfwd``, ``linearize`` and
transposition (as used by optimistix) all work.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from galileo_jax.likelihood import DEFAULT_KIND, DEFAULT_SD_MODEL, Likelihood, make_likelihood
from galileo_jax.observation import Observation
from galileo_jax.params import ParamSpace
from galileo_jax.scene import Scene
from galileo_jax.simulate import (PhysParams, Simulator, make_simulator, scene_effects, steps_needed,
                                  velocity_profile)

#: Default central-difference step in unconstrained coordinates z (see inference/grad.py for
#: the measurement that chose it).
DEFAULT_FD_STEP = 0.05
#: Largest number of rollouts vmapped at once; bigger batches are chunked with lax.map.
DEFAULT_MAX_BATCH = 64


def fd_jacobian_fn(f: Callable[[jax.Array], jax.Array], step: float) -> Callable[[jax.Array], jax.Array]:
    """``f`` with its forward-mode derivative replaced by central finite differences.

    Arguments:
        f: pure function (d,) -> (...), vmappable.
        step: difference step h in the units of the input.

    Returns:
        g with g(z) = f(z) and jvp(g, z, t) = sum_j t_j (f(z + h e_j) - f(z - h e_j)) / (2 h).
        The 2d + 1 evaluations run as one vmapped batch.
    """

    @jax.custom_jvp
    def g(z):
        return f(z)

    @g.defjvp
    def g_jvp(primals, tangents):
        (z,), (t,) = primals, tangents
        d = z.shape[-1]
        eye = jnp.eye(d, dtype=z.dtype) * step
        pts = jnp.concatenate([z[None], z[None] + eye, z[None] - eye])
        out = jax.vmap(f)(pts)
        jac = (out[1:d + 1] - out[d + 1:]) / (2.0 * step)  # (d, ...)
        return out[0], jnp.tensordot(t, jac, axes=(0, 0))

    return g


class Problem:
    """Simulator, observation, parameter space and likelihood of one fit.

    Arguments:
        scene: the validated scene (free parameters, priors, geometry).
        observation: the observed profile (frame rate, mask, noise SDs).
        likelihood: a likelihood kind (``galileo_jax.likelihood.KINDS``), default "gaussian_ma1".
        sd_model: model-error floor in m/s for the Gaussian kinds.
        max_batch: largest vmapped batch of rollouts; larger batches are chunked.
        effects: extra physical effects (names or :class:`~galileo_jax.effects.Effect`), added
            to the scene's own ``effects``; their parameters follow the base ones in theta.

    Raises:
        ValueError: the observation does not match the scene (number of objects), or any
            error of :func:`~galileo_jax.likelihood.make_likelihood` / ``ParamSpace.from_scene``.
    """

    def __init__(self, scene: Scene, observation: Observation, likelihood: str = DEFAULT_KIND,
                 sd_model: float = DEFAULT_SD_MODEL, max_batch: int = DEFAULT_MAX_BATCH, effects=()):
        n_traces = 2 * scene.n_objects
        if np.shape(observation.profile)[0] != n_traces:
            raise ValueError(f"observation has {np.shape(observation.profile)[0]} velocity traces, "
                             f"the scene's {scene.n_objects} object(s) need {n_traces}")
        if max_batch < 1:
            raise ValueError(f"max_batch must be >= 1, got {max_batch}")
        self.scene = scene
        self.observation = observation
        self.effects = scene_effects(scene, effects)
        self.space = ParamSpace.from_scene(scene, self.effects)
        self.likelihood: Likelihood = make_likelihood(observation, likelihood, sd_model)
        self.sim: Simulator = make_simulator(scene, float(observation.fps), self.effects)
        self.max_batch = int(max_batch)
        ft = np.asarray(observation.frame_times, np.float64)
        self.frame_times = jnp.asarray(ft, jnp.float32)
        self.release_time = jnp.asarray(observation.release_time, jnp.float32)
        last = int(self.likelihood.idx[-1]) + 1
        self.n_steps_fit = steps_needed(self.sim, max(ft[last] - float(observation.release_time), self.sim.dt))
        self.n_steps_full = steps_needed(self.sim, max(ft[-1] - float(observation.release_time), self.sim.dt))
        self._jit_cache: dict = {}

    # ------------------------------------------------------------------ pure building blocks
    @property
    def dim(self) -> int:
        return self.space.dim

    @property
    def names(self) -> tuple[str, ...]:
        return self.space.names

    def profile_physical(self, params: PhysParams, full: bool = False) -> jax.Array:
        """Unbatched simulated profile (2n, N-1) in m/s for :class:`PhysParams` (pure)."""
        n = self.n_steps_full if full else self.n_steps_fit
        return velocity_profile(self.sim, params, self.frame_times, self.release_time, n)

    def profile_z(self, z: jax.Array) -> jax.Array:
        """Unbatched simulated profile (2n, N-1) for unconstrained z (d,) (pure, fit window)."""
        return self.profile_physical(self.space.physical(self.space.from_unconstrained(z)))

    def loglik_z(self, z: jax.Array) -> jax.Array:
        """Unbatched log-likelihood (or similarity) at z (d,); -inf if the rollout is not finite."""
        ll = self.likelihood(self.profile_z(z))
        return jnp.where(jnp.isfinite(ll), ll, -jnp.inf)

    def residual_fn(self, jacobian: str = "fd", fd_step: float = DEFAULT_FD_STEP) -> Callable[[jax.Array], jax.Array]:
        """Pure z (d,) -> standardised residuals (n_residuals,), whose derivative is AD or FD.

        Arguments:
            jacobian: "fd" (central differences via ``custom_jvp``, see module docstring) or "ad".
            fd_step: difference step in z.

        Raises:
            ValueError: unknown ``jacobian``, non-positive step, or a non-Gaussian likelihood.
        """
        if jacobian not in ("fd", "ad"):
            raise ValueError(f"jacobian must be 'fd' or 'ad', got {jacobian!r}")
        if not fd_step > 0:
            raise ValueError(f"fd_step must be > 0, got {fd_step}")
        if not self.likelihood.is_gaussian:
            raise ValueError(f"likelihood {self.likelihood.kind!r} has no residuals; least squares needs a Gaussian kind")
        lik = self.likelihood

        def res(z):
            return lik.residuals(self.profile_z(z))

        return fd_jacobian_fn(res, fd_step) if jacobian == "fd" else res

    def map_batch(self, f: Callable, xs):
        """Apply unbatched ``f`` over the leading axis of the pytree ``xs``: vmap, or lax.map
        with batch_size ``max_batch`` for bigger batches (pure; use inside jit)."""
        n = jax.tree_util.tree_leaves(xs)[0].shape[0]
        if n <= self.max_batch:
            return jax.vmap(f)(xs)
        return jax.lax.map(f, xs, batch_size=self.max_batch)

    # ------------------------------------------------------------------ jitted batched API
    def _jitted(self, name: str, fn: Callable) -> Callable:
        if name not in self._jit_cache:
            self._jit_cache[name] = jax.jit(fn)
        return self._jit_cache[name]

    def log_density_fn(self, zb: jax.Array) -> jax.Array:
        """Pure batched log posterior density (unnormalised), (B, d) -> (B,); for use inside jit/scan.

        log p(z | obs) = log_lik(z) + log_prior(z) (prior includes the transform's
        log-Jacobian); -inf where the rollout or the prior is not finite. One vmapped rollout.
        """
        lp = self.space.log_prior(zb) + self.map_batch(self.loglik_z, zb)
        return jnp.where(jnp.isnan(lp), -jnp.inf, lp)

    def log_density(self, z: jax.Array) -> jax.Array:
        """Jitted :meth:`log_density_fn`: (B, d) -> (B,)."""
        return self._jitted("log_density", self.log_density_fn)(jnp.asarray(z, jnp.float32))

    def log_likelihood(self, z: jax.Array) -> jax.Array:
        """Log-likelihood (or similarity) at unconstrained points, (B, d) -> (B,)."""
        return self._jitted("log_likelihood", lambda zb: self.map_batch(self.loglik_z, zb))(jnp.asarray(z, jnp.float32))

    def profiles_physical(self, params: PhysParams) -> jax.Array:
        """Simulated profiles (B, 2n, N-1) in m/s for batched PhysParams (leaves (B, n)), fit window."""
        return self._jitted("profiles_physical", lambda p: self.map_batch(self.profile_physical, p))(
            jax.tree_util.tree_map(lambda a: jnp.asarray(a, jnp.float32), params))

    def residuals(self, theta: jax.Array) -> jax.Array:
        """Standardised residuals at theta (d,) -> (n_residuals,) (or (B, d) -> (B, n_residuals))."""
        theta = jnp.asarray(theta, jnp.float32)
        lik = self.likelihood
        if not lik.is_gaussian:
            raise ValueError(f"likelihood {lik.kind!r} has no residuals")
        f = self._jitted("residuals", lambda tb: self.map_batch(
            lambda t: lik.residuals(self.profile_physical(self.space.physical(t))), tb))
        return f(theta[None])[0] if theta.ndim == 1 else f(theta)

    def simulate(self, theta: jax.Array) -> jax.Array:
        """Simulated profile over the WHOLE video at theta: (d,) -> (2n, N-1), or (B, d) -> (B, 2n, N-1), m/s."""
        theta = jnp.asarray(theta, jnp.float32)
        f = self._jitted("simulate", lambda tb: self.map_batch(
            lambda t: self.profile_physical(self.space.physical(t), full=True), tb))
        return f(theta[None])[0] if theta.ndim == 1 else f(theta)


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
    from galileo_jax.simulate import rollout, sample_poses

    traj = jax.jit(lambda p: rollout(sim, p, n))(params)
    pos = np.asarray(sample_poses(traj, jnp.asarray(ft - release_time, jnp.float32))[..., :2], np.float64)
    sd = np.broadcast_to(np.asarray(position_sd, np.float64), (2 * scene.n_objects,)).copy()
    rng = np.random.default_rng(seed)
    noisy = pos + rng.normal(size=pos.shape) * sd.reshape(scene.n_objects, 2)[None]
    from galileo_jax.observation import profile_from_positions

    profile = profile_from_positions(noisy, ft)
    moved = np.abs(pos[-1, :, 0] - pos[0, :, 0]) > 1e-3
    mask = np.ones(n_frames - 1, bool) if mask is None else np.asarray(mask, bool)
    return Observation(frame_times=ft, positions=noisy, pixels=noisy * scene.camera.scale, profile=profile,
                       position_sd=sd, mask=mask, release_time=float(release_time), fps=float(fps), moved=moved)
