"""Joint fit of several videos of one setup: shared and per-video parameters.

Several videos of the same objects (e.g. one pipe released on one board at four tilts)
constrain the same physical constants, and a model is only right if ONE set of them fits
all the videos. :class:`JointProblem` ties single-video :class:`~galileo_jax.inference.problem.Problem`
objects together:

* a parameter name that occurs in several videos (``k1``, ``phi``, ``drag_quadratic`` ...) is
  ONE coordinate of the joint ``theta``, shared by every video that has it;
* a name listed in ``per_video`` gets one coordinate per video that has it, named
  ``name@j`` (j = 0-based video index), e.g. ``k1@2``; the release speed ``v0`` of the
  ``initial_push`` effect is per-video by default (:data:`DEFAULT_PER_VIDEO`: every release by
  hand differs).

Joint coordinates are ordered by first appearance (video 0's parameters, then the new ones
of video 1, ...). A shared coordinate's bounds are the intersection of the videos' bounds
(its prior is uniform there). The videos are independent given theta, so the joint
log-likelihood is the sum of the videos' log-likelihoods and the joint residual vector is
the concatenation of their standardised residuals; least squares on it (``fit_grad``) is
joint maximum likelihood.

The videos may differ in length, frame rate and model (ramp angle, objects, effects): the
joint functions loop over the videos in Python inside the traced function (one MJX rollout
per video per evaluation, each vmapped over the batch), which XLA compiles into one program.

:class:`JointSpace` has the interface of :class:`~galileo_jax.params.ParamSpace` that the
optimisers use (``names``, ``lower``, ``upper``, ``dim``, ``index``, ``_bounds``,
``to_unconstrained``, ``from_unconstrained``, ``dtheta_dz``, ``log_prior``); the transform
methods ARE ParamSpace's (borrowed functions that only read ``names``/``lower``/``upper``/
``kinds``/``mass_prior``), so the two cannot drift apart.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from galileo_jax.inference.problem import DEFAULT_FD_STEP, BatchedAPI, Problem, check_residual_args, fd_jacobian_fn
from galileo_jax.params import BoxSpaceMethods, ParamSpace

#: Parameters that are per-video unless stated otherwise: the release-time correction, the
#: camera's scale error and the ``initial_push`` release speed (every release by hand differs,
#: every clip has its own calibration).
DEFAULT_PER_VIDEO = ("dt_release", "scale_error", "v0")


def joint_name(name: str, video: int) -> str:
    """Name of the per-video copy of ``name`` for video ``video``: ``"k1@2"``."""
    return f"{name}@{video}"


@dataclass(frozen=True, eq=False)
class JointSpace(BoxSpaceMethods):
    """The joint parameter space of several videos (build with :meth:`from_spaces`).

    Attributes:
        names: joint coordinate names, shared ones plain (``"k1"``), per-video ones ``"k1@j"``.
        lower, upper: (D,) bounds (a shared coordinate: the intersection of the videos' bounds).
        kinds: per coordinate the ParamSpace kind ("friction", "phi", "mass", "effect").
        maps: per video, for each of that video's coordinates (in its own order), the index
            of the joint coordinate it reads.
        spaces: the videos' :class:`ParamSpace` objects.
        per_video: the base names that were made per-video.
        mass_prior: the (common) mass prior range (used by the phi prior); None if they differ.
    """

    names: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    kinds: tuple[str, ...]
    maps: tuple[tuple[int, ...], ...]
    spaces: tuple[ParamSpace, ...]
    per_video: tuple[str, ...]
    mass_prior: tuple[float, float] | None


    @classmethod
    def from_spaces(cls, spaces: Sequence[ParamSpace], per_video: Iterable[str] = ()) -> JointSpace:
        """Joint space of ``spaces`` with the names in ``per_video`` (plus :data:`DEFAULT_PER_VIDEO`) per video.

        Raises:
            ValueError: no spaces; a ``per_video`` name that no video has; a shared name of
                different kinds in two videos; or shared bounds that do not overlap.
        """
        spaces = tuple(spaces)
        if not spaces:
            raise ValueError("a joint problem needs at least one video")
        per_video = tuple(dict.fromkeys(per_video))
        all_names = {n for s in spaces for n in s.names}
        unknown = [n for n in per_video if n not in all_names]
        if unknown:
            raise ValueError(f"per_video names {unknown} are not parameters of any video; "
                             f"the videos' parameters are {sorted(all_names)}")
        split = set(per_video) | set(DEFAULT_PER_VIDEO)
        names: list[str] = []
        lower: list[float] = []
        upper: list[float] = []
        kinds: list[str] = []
        maps = []
        for j, s in enumerate(spaces):
            m = []
            for name, lo, hi, kind in zip(s.names, s.lower, s.upper, s.kinds):
                jn = joint_name(name, j) if name in split else name
                if jn in names:
                    k = names.index(jn)
                    if kinds[k] != kind:
                        raise ValueError(f"parameter {name!r} is a {kinds[k]} in one video and a {kind} in video {j}; "
                                         f"list it in per_video")
                    lower[k], upper[k] = max(lower[k], lo), min(upper[k], hi)
                    if not lower[k] < upper[k]:
                        raise ValueError(f"shared parameter {name!r}: the videos' bounds do not overlap "
                                         f"(video {j}: ({lo}, {hi})); list it in per_video")
                else:
                    k = len(names)
                    names.append(jn); lower.append(float(lo)); upper.append(float(hi)); kinds.append(kind)
                m.append(k)
            maps.append(tuple(m))
        priors = {s.mass_prior for s in spaces}
        return cls(tuple(names), tuple(lower), tuple(upper), tuple(kinds), tuple(maps), spaces,
                   tuple(sorted(split & all_names)), priors.pop() if len(priors) == 1 else None)

    @property
    def n_videos(self) -> int:
        return len(self.spaces)

    def theta_for(self, j: int, theta: jax.Array) -> jax.Array:
        """Video ``j``'s theta (..., d_j) from the joint theta (..., D) (pure)."""
        return jnp.asarray(theta)[..., jnp.asarray(self.maps[j], jnp.int32)]

    def log_prior_theta(self, theta: jax.Array) -> jax.Array:
        """Log prior density of the joint theta: independent coordinates, each with its
        ParamSpace prior on the joint bounds (uniform; phi: the induced mass-ratio prior).

        Raises:
            ValueError: a phi coordinate and videos with different mass priors.
        """
        if "phi" in self.kinds and self.mass_prior is None:
            raise ValueError("the videos have different mass priors; the joint phi prior is undefined")
        return ParamSpace.log_prior_theta(self, theta)


@dataclass(frozen=True, eq=False)
class JointLikelihood:
    """The videos' likelihoods together (what ``fit_grad`` and reports read).

    Attributes:
        likelihoods: per video its :class:`~galileo_jax.likelihood.Likelihood`.
    """

    likelihoods: tuple

    @property
    def log_norm(self) -> float:
        """Sum of the videos' normalising constants: log L = -|r|^2 / 2 + log_norm."""
        return float(sum(float(lik.log_norm) for lik in self.likelihoods))

    @property
    def is_gaussian(self) -> bool:
        return all(lik.is_gaussian for lik in self.likelihoods)

    @property
    def kind(self) -> str:
        kinds = list(dict.fromkeys(lik.kind for lik in self.likelihoods))
        return kinds[0] if len(kinds) == 1 else "+".join(kinds)

    @property
    def n_residuals(self) -> int:
        return int(sum(lik.n_residuals for lik in self.likelihoods))

    @property
    def sizes(self) -> tuple[int, ...]:
        """Number of residuals of each video (the blocks of the joint residual vector)."""
        return tuple(lik.n_residuals for lik in self.likelihoods)

    def used(self, r) -> np.ndarray:
        """The used samples of joint residual vectors (..., n_residuals) -> (..., n_used), NumPy."""
        blocks = np.split(np.asarray(r), np.cumsum(self.sizes)[:-1], axis=-1)
        return np.concatenate([lik.used(b) for lik, b in zip(self.likelihoods, blocks)], axis=-1)


class JointProblem(BatchedAPI):
    """Several videos of one setup fitted together (module docstring).

    Arguments:
        problems: the single-video :class:`Problem` objects (any scenes, lengths, effects).
        per_video: parameter names to fit separately for each video (``name@j``); all
            other names are shared. ``v0`` (``initial_push``) is always per-video.

    Raises:
        ValueError: see :meth:`JointSpace.from_spaces`.
        TypeError: an entry that is not a Problem.

    Interface (as :class:`Problem`, for ``fit_grad`` and ``run_mh``): ``space``, ``dim``,
    ``names``, ``data`` (the tuple of the videos' data), ``static_key``, ``likelihood``
    (``log_norm``, ``is_gaussian``), ``loglik_fn``, ``residual_fn``, ``log_likelihood``,
    ``log_density``, ``residuals``, ``simulate``, ``map_batch``.
    """

    def __init__(self, problems: Sequence[Problem], per_video: Iterable[str] = ()):
        problems = tuple(problems)
        for p in problems:
            if not isinstance(p, Problem):
                raise TypeError(f"JointProblem needs Problem objects, got {type(p).__name__}")
        self.problems = problems
        self.space = JointSpace.from_spaces([p.space for p in problems], per_video)
        self.likelihood = JointLikelihood(tuple(p.likelihood for p in problems))
        #: "mujoco" when any video's rollouts run on the C engine (no derivatives), else "mjx".
        self.simulator_engine = "mujoco" if any(p.simulator_engine == "mujoco" for p in problems) else "mjx"
        self.max_batch = min(p.max_batch for p in problems)
        self.data = tuple(p.data for p in problems)
        self.static_key = ("joint", tuple(p.static_key for p in problems), self.space.names)
        self._engines = tuple(p.engine for p in problems)
        self._maps = tuple(jnp.asarray(m, jnp.int32) for m in self.space.maps)

    @property
    def n_videos(self) -> int:
        return len(self.problems)

    def theta_for(self, j: int, theta: jax.Array) -> jax.Array:
        """Video ``j``'s theta (..., d_j) from the joint theta (..., D)."""
        return self.space.theta_for(j, theta)

    # ------------------------------------------------------------------ pure building blocks
    # (they read only the engines, the space and the data argument)
    def _profile(self, j: int, theta: jax.Array, data) -> jax.Array:
        return self._engines[j].profile_theta(jnp.asarray(theta)[..., self._maps[j]], data[j])

    def video_loglik_theta(self, theta: jax.Array, data) -> jax.Array:
        """Unbatched per-video log-likelihoods (n_videos,) at joint theta (D,); -inf where not finite."""
        out = []
        for j in range(self.n_videos):
            ll = data[j].likelihood(self._profile(j, theta, data))
            out.append(jnp.where(jnp.isfinite(ll), ll, -jnp.inf))
        return jnp.stack(out)

    def loglik_fn(self, z: jax.Array, data) -> jax.Array:
        """Unbatched joint log-likelihood at z (D,): the sum over videos (pure)."""
        return jnp.sum(self.video_loglik_theta(self.space.from_unconstrained(z), data))

    def residuals_theta(self, theta: jax.Array, data) -> jax.Array:
        """Unbatched concatenated standardised residuals at joint theta (D,) (pure)."""
        return jnp.concatenate([data[j].likelihood.residuals(self._profile(j, theta, data))
                                for j in range(self.n_videos)])

    def residual_fn(self, jacobian: str = "fd", fd_step: float = DEFAULT_FD_STEP) -> Callable[[jax.Array, Any], jax.Array]:
        """Pure ``f(z (D,), data)`` -> concatenated standardised residuals of all videos, with an
        AD or central-difference (``fd_jacobian_fn`` on the joint function) derivative.

        Raises:
            ValueError: unknown ``jacobian``, non-positive step, or a non-Gaussian likelihood.
        """
        check_residual_args(jacobian, fd_step, self.likelihood)

        def res(z, data):
            return self.residuals_theta(self.space.from_unconstrained(z), data)

        return fd_jacobian_fn(res, fd_step) if jacobian == "fd" else res

    # ------------------------------------------------------------------ jitted batched API
    def video_log_likelihoods(self, theta: jax.Array) -> np.ndarray:
        """Per-video log-likelihoods at joint theta: (D,) -> (n_videos,), (B, D) -> (B, n_videos)."""
        theta = jnp.asarray(theta, jnp.float64)
        f = self.jitted("video_ll", lambda tb, data: self.map_batch(lambda t: self.video_loglik_theta(t, data), tb))
        return np.asarray(f(theta[None], self.data)[0] if theta.ndim == 1 else f(theta, self.data))

    def residuals(self, theta: jax.Array) -> jax.Array:
        """Concatenated standardised residuals at joint theta: (D,) -> (n,), (B, D) -> (B, n)."""
        theta = jnp.asarray(theta, jnp.float64)
        if not self.likelihood.is_gaussian:
            raise ValueError(f"likelihood {self.likelihood.kind!r} has no residuals")
        out = self.in_chunks("residuals", lambda tb, data: self.map_batch(lambda t: self.residuals_theta(t, data), tb),
                             theta.reshape(-1, theta.shape[-1]))
        return out[0] if theta.ndim == 1 else out

    def split_residuals(self, r) -> list[np.ndarray]:
        """Split a concatenated residual vector (..., n) into the videos' blocks."""
        r = np.asarray(r)
        return np.split(r, np.cumsum(self.likelihood.sizes)[:-1], axis=-1)

    def simulate(self, theta: jax.Array) -> list[jax.Array]:
        """Simulated profiles over each WHOLE video at joint theta: a list with, per video,
        (2n_j, N_j - 1) for theta (D,), or (B, 2n_j, N_j - 1) for theta (B, D), m/s."""
        theta = jnp.asarray(theta, jnp.float64)
        return [p.simulate(self.theta_for(j, theta)) for j, p in enumerate(self.problems)]
