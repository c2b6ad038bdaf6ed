"""Many videos of one scene fitted as ONE batched computation, sharded over the local devices.

:func:`~galileo_jax.inference.grad.fit_grad` fits one video per call: a screen of prior points,
Levenberg-Marquardt from the best few (vmapped over the starts), a Gauss-Newton covariance and
a polish. :func:`fit_grad_batch` runs the same fit for B videos of one scene at once: their
:class:`~galileo_jax.inference.problem.ProblemData` (every leaf gets a leading video axis;
profiles are padded to one length with the likelihood's mask, :class:`Problem`'s ``pad_to``)
go into one pure, jitted function that vmaps the per-video fit over the video axis, so every
LM iteration is one batched set of rollouts for all videos and starts together.

Starts: every video screens the same ``n_screen`` Latin-hypercube points (one key) and solves
from its own ``n_starts`` of them (``grad.diverse_best``), exactly as it would alone (the
screen ranks its own likelihood); the polish draws the same normals for every video. So a
video fitted in a batch ends where :func:`fit_grad` with the same key ends (up to
floating-point order; the batched while loop freezes each start once it has converged).

Sharding: with more than one local device (GPUs, or CPU devices forced with
``XLA_FLAGS=--xla_force_host_platform_device_count=N``) the video axis is laid on a
``jax.sharding.Mesh`` of all local devices, axis ``"videos"``: the inputs are placed with
``NamedSharding(mesh, P("videos"))`` (B padded up to a multiple of the device count with
copies of the last video, dropped from the results) and the jitted function's inputs and
outputs are sharded so, so XLA's SPMD partitioner splits the vmapped fit over the devices
(each device runs its own videos' rollouts; the batched LM loop's stopping test is the only
cross-device reduction). With one device the same function just runs under ``jit``. The C
MuJoCo engine's host callback is not partitioned: XLA gathers its inputs to one device and
calls it once for the whole batch (its own thread pool spreads the rollouts over the cores),
and says so in a warning ("Involuntary full rematerialization"). ``jax.shard_map`` would
split it too, but optimistix's linear solves reject its per-device values (lineax's
structure check, JAX 0.10.2).
"""

from __future__ import annotations

import time
from typing import Callable, NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from galileo_jax.inference.covariance import gauss_newton_covariance, widened
from galileo_jax.inference.grad import (
    MAX_LM_STARTS,
    GradResult,
    _lm_solver,
    grad_result,
    residual_jacobian,
)
from galileo_jax.inference.polish import polish_many
from galileo_jax.inference.problem import (
    DEFAULT_FD_STEP,
    Engine,
    Problem,
    ProblemData,
    cached_jit,
    check_residual_args,
    fd_jacobian_fn,
    map_batch,
)
from galileo_jax.inference.starts import diverse_best, latin_hypercube_starts, unit_box

#: Name of the mesh axis the videos are sharded over.
AXIS = "videos"


class BatchSolve(NamedTuple):
    """Per-video output of :func:`solve_batch` (JAX arrays, leading video axis B, sharded over
    the mesh when there is one).

    Attributes:
        z0: (B, S, d) LM starts in z (S screened points of each video, the best spread out).
        z_end: (B, S, d) LM end points in z.
        cost: (B, S) end costs |r|^2 / 2 (inf where not finite).
        steps: (B, S) LM steps per start.
        ok: (B, S) whether each start met the tolerances.
        codes: (B, S) optimistix result codes.
        best: (B,) index of each video's winning start.
        jac: (B, R, d) finite-difference Jacobian of the standardised residuals at each video's
            winning end point (R residuals, 1 / unit of z).
        resid: (B, R) the standardised residuals there.
    """

    z0: jax.Array
    z_end: jax.Array
    cost: jax.Array
    steps: jax.Array
    ok: jax.Array
    codes: jax.Array
    best: jax.Array
    jac: jax.Array
    resid: jax.Array


def video_mesh(devices: Sequence | None = None) -> Mesh | None:
    """A 1-D mesh, axis :data:`AXIS`, over ``devices`` (default: all local devices); None for one device."""
    devices = list(jax.local_devices() if devices is None else devices)
    return Mesh(np.array(devices), (AXIS,)) if len(devices) > 1 else None


def stack_data(problems: Sequence[Problem]) -> tuple[Engine, ProblemData]:
    """The shared :class:`Engine` and the videos' :class:`ProblemData` stacked on a leading axis.

    The engine is the one with the longest rollouts (a longer rollout gives the same profile
    at the earlier frames).

    Raises:
        ValueError: no problems, a problem that is not a single-video :class:`Problem`, videos
            of different scenes, frame rates, effects, likelihoods or engines, or of different
            padded lengths (build them with :func:`batch_problems` or a common ``pad_to``).
    """
    if not problems:
        raise ValueError("fit_grad_batch needs at least one video, got none")
    if not all(isinstance(p, Problem) for p in problems):
        raise ValueError("fit_grad_batch fits single-video Problems; a joint fit of several videos is fit_grad")
    compat = {p.engine.key[:-1] for p in problems}  # all but the rollout length
    if len(compat) > 1:
        raise ValueError("a batch needs videos of one scene structure, frame rate, effects and engine; got "
                         f"{len(compat)} different ones (fit each group as its own batch)")
    meta = {(p.likelihood.kind, p.likelihood.sd_model, p.likelihood.whiten.shape) for p in problems}
    if len(meta) > 1:
        raise ValueError(f"a batch needs one likelihood kind, sd_model and padded length; got {sorted(map(str, meta))} "
                         "(build the problems with batch_problems or one pad_to)")
    engine = max((p.engine for p in problems), key=lambda e: e.n_steps)
    data = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *[p.data for p in problems])
    return engine, data


def batch_problems(scene, observations: Sequence, **problem_kw) -> list[Problem]:
    """One :class:`Problem` per observation of ``scene``, all padded to the longest video
    (``problem_kw``: :class:`Problem`'s likelihood, sd_model, max_batch, effects, engine).

    Raises:
        ValueError: any error of :class:`Problem`.
    """
    n = max(int(np.shape(o.profile)[1]) for o in observations)
    return [Problem(scene, o, pad_to=n, **problem_kw) for o in observations]


def _pad_videos(tree, n: int):
    """Every leaf's leading (video) axis padded to ``n`` with copies of its last entry."""
    def pad(a):
        extra = n - a.shape[0]
        return a if extra == 0 else jnp.concatenate([a, jnp.repeat(a[-1:], extra, axis=0)])

    return jax.tree_util.tree_map(pad, tree)


def map_videos(engine: Engine, name, fn: Callable, args: tuple, mesh: Mesh | None):
    """``vmap(fn)`` over the leading video axis of every leaf of ``args``, jitted (shared per
    engine, ``name`` and devices through :func:`cached_jit`); with a ``mesh`` the inputs are
    placed on it and the jitted function's inputs and outputs sharded with
    ``NamedSharding(mesh, P("videos"))``, so the computation runs split over its devices.

    ``fn(*per_video_args)`` must be pure; ``name`` must identify it (with the engine's key).
    The leading axis must be a multiple of the mesh size. Returns the stacked outputs.
    """
    batched = jax.vmap(fn)
    if mesh is None:
        return cached_jit(engine.key, name, batched)(*args)
    place = NamedSharding(mesh, P(AXIS))
    args = jax.device_put(args, place)
    devices = tuple(d.id for d in mesh.devices.flat)
    return cached_jit(engine.key, (name, devices), batched, in_shardings=place, out_shardings=place)(*args)


def _logliks(engine: Engine) -> Callable:
    """Pure ``f(zs (C, d), data) -> (C,)``: one video's log-likelihood (nats) at C points in z."""
    return lambda zs, d: map_batch(lambda z: engine.loglik_z(z, d), zs, engine.max_batch)


def solve_batch(engine: Engine, z_cand: jax.Array, data: ProblemData, *, n_starts: int, jacobian: str = "fd",
                fd_step: float = DEFAULT_FD_STEP, rtol: float = 1e-4, atol: float = 1e-4, max_steps: int = 40,
                mesh: Mesh | None = None) -> BatchSolve:
    """Screen, Levenberg-Marquardt and Jacobian of B videos as one (sharded) computation.

    Per video (pure, vmapped over the videos): the log-likelihood of the ``C`` candidates,
    ``n_starts`` of them (the best, spread over the screen: ``grad.diverse_best``), LM from
    each (``grad._lm_solver``), the winning start and the FD Jacobian of the residuals there.

    Arguments:
        engine: the shared engine (:func:`stack_data`).
        z_cand: (C, d) screened candidates in z, the same for every video.
        data: :class:`ProblemData` with a leading video axis B (a multiple of the mesh size).
        n_starts: LM starts per video (1 <= n_starts <= C).
        jacobian, fd_step, rtol, atol, max_steps: as :func:`~galileo_jax.inference.grad.fit_grad`.
        mesh: :func:`video_mesh`, or None to run on the default device.

    Returns:
        :class:`BatchSolve`.
    """
    n_cand = int(z_cand.shape[0])
    if not 1 <= n_starts <= n_cand:
        raise ValueError(f"n_starts must be in 1..{n_cand} (the screened points), got {n_starts}")
    res_fn = fd_jacobian_fn(engine.residuals_z, fd_step) if jacobian == "fd" else engine.residuals_z
    jac_fd = residual_jacobian(fd_jacobian_fn(engine.residuals_z, fd_step))
    solve = _lm_solver(res_fn, rtol, atol, max_steps)
    logliks = _logliks(engine)

    def one(zc, d):
        ll = logliks(zc, d)
        u = unit_box(engine.space.from_unconstrained(zc), *engine.space._bounds(), engine.space.kinds)
        z0 = zc[diverse_best(u, ll, n_starts)]
        z_end, cost, steps, ok, codes = solve(z0, d)
        cost = jnp.where(jnp.isfinite(cost), cost, jnp.inf)
        best = jnp.argmin(cost)
        resid, jac = jac_fd(z_end[best], d)
        return BatchSolve(z0, z_end, cost, steps, ok, codes, best, jac, resid)

    b = jax.tree_util.tree_leaves(data)[0].shape[0]
    zc = jnp.broadcast_to(jnp.asarray(z_cand, jnp.float64), (b, *z_cand.shape))
    name = ("batch_lm", n_cand, n_starts, jacobian, fd_step, rtol, atol, max_steps)
    return map_videos(engine, name, one, (zc, data), mesh)


def fit_grad_batch(problems: Sequence[Problem], key: jax.Array, *, n_starts: int = 4, n_screen: int = 256,
                   jacobian: str = "fd", fd_step: float = DEFAULT_FD_STEP, rtol: float = 1e-4, atol: float = 1e-4,
                   max_steps: int = 40, polish_rounds: int = 3, polish_points: int = 64,
                   devices: Sequence | None = None) -> list[GradResult]:
    """:func:`~galileo_jax.inference.grad.fit_grad` of B videos of one scene as one batched
    computation, sharded over ``devices`` (default: all local devices) when there are several.

    Each video is fitted separately (its own parameters; a JOINT fit with shared parameters is
    ``fit_grad`` of a :class:`~galileo_jax.inference.joint.JointProblem`), from its own
    ``n_starts`` of the same ``n_screen`` screened points (module docstring), so its result
    matches ``fit_grad(problem, key, ...)`` with the same arguments. LM runs in calls of at most
    ``MAX_LM_STARTS // n_starts`` videos per device (``fit_grad``'s start chunking).

    Arguments:
        problems: B single-video problems of one scene and padded length (:func:`batch_problems`).
        key: PRNG key of the screen and the polish (the same for every video).
        n_starts, n_screen, jacobian, fd_step, rtol, atol, max_steps, polish_rounds,
            polish_points: as ``fit_grad`` (no ``init``, ``fixed`` or ``local_screen``).
        devices: the devices to shard the videos over (default ``jax.local_devices()``).

    Returns:
        B :class:`~galileo_jax.inference.grad.GradResult`, in the order of ``problems``; each
        ``time_s`` is the whole batch's wall time divided by B.

    Raises:
        ValueError: any error of :func:`stack_data`; n_starts < 1 or > n_screen; unknown
            jacobian, non-positive fd_step or a non-Gaussian likelihood; jacobian "ad" on the
            C MuJoCo engine.
    """
    engine, data = stack_data(problems)
    check_residual_args(jacobian, fd_step, problems[0].likelihood)
    if jacobian == "ad" and engine.sim.engine != "mjx":
        raise ValueError(f"jacobian 'ad' needs the MJX engine (the {engine.sim.engine} engine has no derivatives); "
                         "use jacobian 'fd' or engine 'mjx'")
    if not 1 <= n_starts <= n_screen:
        raise ValueError(f"need 1 <= n_starts <= n_screen, got n_starts = {n_starts}, n_screen = {n_screen}")
    t0 = time.perf_counter()
    space = engine.space
    b = len(problems)
    mesh = video_mesh(devices)
    n_dev = 1 if mesh is None else mesh.size
    # LM runs in calls of at most MAX_LM_STARTS vmapped starts per device (fit_grad's chunking:
    # 64 vmapped starts deadlocked MJX), all calls of one compiled shape (the last one padded).
    chunk = n_dev * max(1, MAX_LM_STARTS // n_starts)
    b_pad = -(-b // n_dev) * n_dev
    data = _pad_videos(data, b_pad)
    z_cand = space.to_unconstrained(latin_hypercube_starts(problems[0], key, n_screen))
    parts = []
    for i in range(0, b, chunk):
        part = jax.tree_util.tree_map(lambda a: a[i:i + chunk], data)
        n_part = min(chunk, b - i)
        part = _pad_videos(part, chunk if b > chunk else b_pad)
        out = solve_batch(engine, z_cand, part, n_starts=n_starts, jacobian=jacobian, fd_step=fd_step, rtol=rtol,
                          atol=atol, max_steps=max_steps, mesh=mesh)
        parts.append([np.asarray(a)[:n_part] for a in out])
    out = BatchSolve(*(np.concatenate(a) for a in zip(*parts)))
    best = out.best.astype(int)
    z_hat = out.z_end[np.arange(b), best]
    cost_best = out.cost[np.arange(b), best].astype(np.float64)
    cov_z = np.stack([gauss_newton_covariance(j) for j in out.jac])
    if polish_rounds > 0:
        norm = np.array([float(p.likelihood.log_norm) for p in problems])

        def loglik(pts):  # (B, points, d) -> (B, points): one sharded batch of rollouts
            pts = _pad_videos(jnp.asarray(pts, jnp.float64), b_pad)
            return np.asarray(map_videos(engine, ("batch_loglik", pts.shape[1]), _logliks(engine), (pts, data),
                                         mesh))[:b]

        z_pol, cost_pol = polish_many(loglik, jax.random.fold_in(key, 7), z_hat, cost_best, cov_z, norm,
                                      rounds=polish_rounds, points=polish_points)
        moved = cost_pol < cost_best
        if moved.any():
            jac_fn = residual_jacobian(fd_jacobian_fn(engine.residuals_z, fd_step))
            resid, jac = (np.asarray(a)[:b] for a in map_videos(engine, ("batch_residuals_jacobian", fd_step), jac_fn,
                                                               (_pad_videos(jnp.asarray(z_pol), b_pad), data), mesh))
            for j in np.flatnonzero(moved):
                cov_z[j] = gauss_newton_covariance(jac[j])
                out.jac[j], out.resid[j] = jac[j], resid[j]
            z_hat = np.where(moved[:, None], z_pol, z_hat)
            cost_best = np.where(moved, cost_pol, cost_best)
    elapsed = (time.perf_counter() - t0) / b
    theta0 = np.asarray(space.from_unconstrained(jnp.asarray(out.z0)), np.float64)
    widen = [widened(out.jac[j], out.resid[j], p.likelihood, cov_z[j]) for j, p in enumerate(problems)]
    return [grad_result(space, p.likelihood.log_norm, z_hat[j], widen[j][0], float(cost_best[j]), theta0[j],
                        out.z_end[j], out.cost[j].astype(np.float64), out.steps[j], out.ok[j], out.codes[j],
                        int(best[j]), jacobian, elapsed, widen[j][1])
            for j, p in enumerate(problems)]
