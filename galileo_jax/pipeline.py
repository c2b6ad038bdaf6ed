"""One fit from video to written results: the library function behind ``fit``.

:func:`run_fit` observes the video, builds the inference :class:`Problem`, runs the chosen
method, simulates the estimate (and posterior draws) over the whole video and beyond, and
writes ``result.json``, ``profiles.png``, ``tracking.png``, ``posterior.nc`` and ``overlay.mp4`` atomically
into the output folder (:mod:`galileo_jax.report.fit_files`). It returns a :class:`~galileo_jax.fit_report.FitReport` for the console summary.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from galileo_jax.criticism.adequacy import adequacy as fit_adequacy
from galileo_jax.config import INITS, FitConfig, ensemble_for
from galileo_jax.errors import GalileoError
from galileo_jax.fit_report import FitReport, JointFitReport, Posterior
from galileo_jax.inference.problem import Problem
from galileo_jax.observation import Observation, trace_names
from galileo_jax.predict import RestPrediction, predict_rest, slides
from galileo_jax.report.fit_files import write_fit, write_joint_fit
from galileo_jax.scene import Scene


#: Draws of a Gaussian approximation (grad) written to ``posterior.nc``.
APPROXIMATION_DRAWS = 1000


@dataclass
class Tracked:
    """A read and tracked video (:func:`track_video`).

    Attributes:
        video: path of the video.
        clip: the decoded video (frames, frame rate).
        observation: the tracked :class:`Observation`.
        cnn_model: the trained CNN for the scene, when the fit needs one (else None).
        seconds: wall time of reading and tracking (s).
        cnn_note: for ``init`` auto, why no network reads the scene (one line), else None.
    """

    video: Path
    clip: object
    observation: Observation
    cnn_model: object
    seconds: float
    cnn_note: str | None = None


def _with_estimate(summary_dict: dict, key: str) -> tuple[dict, dict]:
    """Add ``estimate`` (the entry's ``key`` value) to each parameter entry of a summary."""
    params = summary_dict["parameters"]
    for entry in params.values():
        entry["estimate"] = entry.get(key)
    return params, summary_dict["diagnostics"]


def draw_subset(draws: np.ndarray, n: int, key) -> np.ndarray:
    """``min(n, S)`` of the (S, d) posterior ``draws``, chosen without replacement from ``key``
    (the user's seed): the draws a fit simulates for its predictive band and predictions."""
    pick = jax.random.choice(key, len(draws), (min(int(n), len(draws)),), replace=False)
    return np.asarray(draws)[np.asarray(pick)]


def _estimate_and_draws(problem: Problem, method: str, cfg: FitConfig, key, progress: bool, init: str = "prior",
                        cnn_model=None, cnn_note: str | None = None):
    """Run the method; return (parameters dict, diagnostics, theta_best (d,), draws (S, d) or None,
    :class:`Posterior` or None).

    ``init="auto"`` (``fit``'s default): grad as ``init="cnn"`` where a trained network reads
    the video (``cnn_model`` found, :func:`track_video`, and its coordinates the fit's), else as
    ``init="prior"``, saying why in ``diagnostics["init_note"]``; mh and seed from the prior.
    ``init="cnn"``: grad and mh start from the trained CNN's estimate (:func:`cnn_estimate`):
    grad runs one Levenberg-Marquardt start from it plus the best of a screen around it, as
    wide as the CNN's 90% interval and at least +-``cfg.cnn.local_screen`` of each range
    (:func:`cnn_screen`); mh starts its chains at draws from
    the CNN's posterior, with the usual annealing, for ``cfg.mh.warmup_cnn`` warm-up steps
    (unless ``--warmup`` is given). Without annealing, chains started where the CNN is unsure
    (k2, phi) stuck in wrong modes: R-hat 2.5 (benchmarks/results/cnn_videos_mh.md). The CNN's
    own estimate and time go into the diagnostics. ``cnn_model``: the trained model, if
    already loaded (else found for the scene); ``cnn_note``: why none reads the scene
    (:func:`cnn_model_for`), said in ``init_note``.
    """
    from galileo_jax.inference import summary

    k_run, k_sum = jax.random.split(key)
    if init not in INITS:
        raise GalileoError(f"unknown --init {init!r}; choose one of {', '.join(INITS)}")
    start, auto_note = None, None
    if init == "cnn" or method == "cnn":
        if method == "seed":
            raise GalileoError("--init cnn works with --method grad or mh; the seed's sampler starts from the prior")
        start = cnn_estimate(problem, cfg, jax.random.fold_in(key, 7), cnn_model)
        if method == "cnn":
            loglik = float(problem.log_likelihood(problem.space.to_unconstrained(jnp.asarray(start.theta))[None])[0])
            result = summary.summarize_cnn(start, problem.space, loglik)
            params, diag = _with_estimate(result, "median")
            post = Posterior(summary.posterior_draws(np.asarray(start.draws)[None], problem.space, k_sum), None, "cnn")
            return params, diag, start.theta, start.draws[:cfg.prediction.draws], post
    elif init == "auto" and method == "grad":  # from the CNN where a network reads this video, else the prior
        if cnn_model is None:
            auto_note = cnn_note or "no trained CNN reads this scene"
        else:
            try:
                start = cnn_estimate(problem, cfg, jax.random.fold_in(key, 7), cnn_model)
            except GalileoError as err:  # CNNError, OutOfFamily: the network cannot read this fit
                auto_note = _reason(err)
    cnn_diag = {"init": "prior"} if start is None else {
        "init": "cnn", "cnn_theta": dict(zip(start.names, map(float, start.theta))),
        "cnn_time_s": float(start.time_s), "cnn_model": str(start.model.path)}
    if auto_note:
        cnn_diag["init_note"] = f"started from the prior: {auto_note}"
    if method == "grad":
        from galileo_jax.inference.grad import fit_grad

        if start is None:
            res = fit_grad(problem, k_run, **grad_options(cfg), profile=cfg.grad.profile,
                           search_generations=cfg.grad.search_generations, inside=cfg.grad.inside)
        else:
            res = fit_grad(problem, k_run, **grad_start_from_cnn(start, problem.space, cfg),
                           jacobian=cfg.grad.jacobian, max_steps=cfg.grad.max_steps, profile=cfg.grad.profile,
                           search_generations=cfg.grad.search_generations, inside=cfg.grad.inside)
        params, diag, theta, draws = grad_estimate(res, problem.space, k_sum, cfg)
        return params, {**diag, **cnn_diag}, theta, draws, gauss_newton_posterior(res, problem.space, k_sum)
    if method == "mh":
        from galileo_jax.inference.mh import run_mh

        if start is None:
            res = run_mh(problem, k_run, n_chains=cfg.mh.chains, n_warmup=cfg.mh.warmup, n_samples=cfg.mh.samples,
                         jump=cfg.mh.jump, independent=cfg.mh.independent, progress=progress)
        else:
            res = run_mh(problem, k_run, n_chains=cfg.mh.chains, n_warmup=cfg.mh.warmup_cnn, n_samples=cfg.mh.samples,
                         jump=cfg.mh.jump, independent=cfg.mh.independent, **mh_start_from_cnn(start, cfg.mh.chains),
                         progress=progress)
        params, diag = _with_estimate(summary.summarize_mh(res, problem.space, k_sum), "median")
        flat = res.theta.reshape(-1, res.theta.shape[-1])
        post = Posterior(summary.posterior_draws(res.theta, problem.space, k_sum),
                         {"lp": res.logdensity, "log_likelihood_total": res.loglik}, "mcmc")
        return (params, {**diag, **cnn_diag}, np.asarray(res.best_theta),
                draw_subset(flat, cfg.prediction.draws, jax.random.fold_in(key, 11)), post)
    if method == "seed":
        from galileo_jax.inference.seed_mh import run_seed_mh

        res = run_seed_mh(problem, k_run, n_chains=cfg.seed_mh.chains, n_steps=cfg.seed_mh.steps, progress=progress)
        params = {name: {"estimate": float(v), "best": float(v), "identifiable": name not in ("m1", "m2")
                         or problem.scene.mass_scale_known()} for name, v in res.best.items()}
        diag = {"best_similarity": float(res.best_similarity), "acceptance": float(np.mean(res.accepted)),
                "likelihood": res.likelihood, "time_s": float(res.time_s)}
        # The seed samples masses and frictions only: the release-time and scale corrections stay
        # at 0, the effects at their neutral values (what its rollouts simulated).
        neutral = {p.name: p.neutral for e in problem.space.effects for p in e.params}
        theta = np.array([params[n]["estimate"] if n in params else neutral.get(n, 0.0) for n in problem.space.names])
        return params, diag, theta, None, None
    raise GalileoError(f"unknown method {method!r}; choose grad, mh, cnn or seed")


def gauss_newton_posterior(res, space, key) -> Posterior:
    """:data:`APPROXIMATION_DRAWS` draws of grad's Gauss-Newton normal approximation (one chain)."""
    from galileo_jax.inference import summary
    from galileo_jax.inference.covariance import gauss_newton_draws

    k_draw, k_mass = jax.random.split(jax.random.fold_in(key, 13))
    theta = gauss_newton_draws(res, space, k_draw, APPROXIMATION_DRAWS)[None]
    return Posterior(summary.posterior_draws(theta, space, k_mass), None, "gauss_newton")


def grad_options(cfg: FitConfig) -> dict:
    """``fit_grad`` / ``fit_grad_batch`` options of a fit from the prior: ``cfg.grad``'s starts,
    screen (at least the starts), Jacobian and LM steps."""
    return dict(n_starts=cfg.grad.starts, n_screen=max(cfg.grad.screen, cfg.grad.starts),
                jacobian=cfg.grad.jacobian, max_steps=cfg.grad.max_steps)


def grad_estimate(res, space, key, cfg: FitConfig) -> tuple[dict, dict, np.ndarray, np.ndarray]:
    """A :class:`~galileo_jax.inference.grad.GradResult` as a fit reports it: (parameters dict,
    diagnostics, theta (d,), ``cfg.prediction.draws`` Gauss-Newton draws (S, d) from ``key``)."""
    from galileo_jax.inference import summary
    from galileo_jax.inference.covariance import gauss_newton_draws

    params, diag = _with_estimate(summary.summarize_grad(res, space), "mean")
    return params, diag, np.asarray(res.theta), gauss_newton_draws(res, space, key, cfg.prediction.draws)


def cnn_screen(est, space, minimum: float) -> np.ndarray:
    """(d,) half-widths, as fractions of each range, of grad's screen around the CNN's estimate:
    the farther end of the CNN's 90% interval from its estimate, at least ``minimum``. Where
    the network is sure (k1, the release) the screen is narrow; where the video told it little
    (k2, phi when object 2 barely moves) it spans what the network could not rule out."""
    lo, hi = np.asarray(space.lower), np.asarray(space.upper)
    half = np.maximum(np.abs(est.theta - est.interval90[:, 0]), np.abs(est.interval90[:, 1] - est.theta))
    return np.maximum(half / (hi - lo), minimum)


def grad_start_from_cnn(est, space, cfg: FitConfig) -> dict:
    """``fit_grad`` options of ``fit --init cnn``: one start at the CNN's estimate plus the best
    ``cfg.grad.starts - 1`` (at least 1) of a ``cfg.grad.screen``-point screen around it
    (:func:`cnn_screen`, kept apart by :func:`~galileo_jax.inference.starts.diverse_best`): as
    many Levenberg-Marquardt starts as a fit from the prior, at no extra time on the C engine,
    which pads a solve to :data:`~galileo_jax.inference.grad.LM_PAD` starts anyway. Measured on
    the coverage benchmark's 100 videos against one screened start (same networks): the
    estimate's k2 error smaller by over 10% on 27 videos and larger on 17, phi 24 against 20,
    k1 19 against 20; the cost surface is rough enough that starts 0.0003 apart in k1 can end
    1.35 nats apart."""
    return dict(n_starts=max(cfg.grad.starts - 1, 1), n_screen=cfg.grad.screen, init=est.theta,
                local_screen=cnn_screen(est, space, cfg.cnn.local_screen))


def mh_start_from_cnn(est, n_chains: int) -> dict:
    """``run_mh`` options of ``fit --init cnn``: the chains start at ``n_chains`` of the CNN's
    draws (fixed choice), with the initial proposal SD the median of the CNN's SDs in z (clipped
    to [0.01, 0.5]; 0.1 for a network without uncertainty)."""
    idx = np.random.default_rng(1).choice(len(est.draws), size=n_chains, replace=len(est.draws) < n_chains)
    known = np.asarray(est.sd_z)[np.isfinite(est.sd_z)]  # NaN: a nuisance the network does not read
    sd_z = float(np.clip(np.median(known), 0.01, 0.5)) if np.any(known > 0) else 0.1
    return dict(init_theta=est.draws[idx], init_sd=sd_z)


def cnn_estimate(problem: Problem, cfg: FitConfig, key, model=None):
    """The trained CNN's estimate for ``problem``'s video (:func:`galileo_jax.inference.cnn.estimate`),
    with ``model`` if given, else the model ``cfg.cnn.model`` or the shipped one matching the scene.

    Raises:
        CNNError: no model fits the scene, frame rate or the fit's coordinates (one line, with
            how to train one).
    """
    from galileo_jax.inference import cnn
    from galileo_jax.inference import cnn_files

    if model is None:
        model = cnn_files.find_model(problem.scene, problem.observation.fps, cfg.cnn.model)
    features = None
    if model.spec.family is not None:  # a scene-conditioned network reads the scene too
        from galileo_jax.scene_family import scene_features

        features = scene_features(problem.scene, problem.observation.fps)
    return cnn.estimate(model, problem.observation, problem.space, key, features=features)


def _simulate_batch(problem: Problem, thetas: np.ndarray) -> np.ndarray:
    """(S, d) thetas -> (S, 2n, N-1) simulated profiles over the whole video."""
    return np.asarray(problem.simulate(jnp.asarray(thetas)))


def _rmse(obs: Observation, simulated: np.ndarray) -> dict:
    names = trace_names(obs.n_objects)
    m = np.asarray(obs.mask, bool)
    diff = (obs.profile - simulated)[:, m]
    rmse = np.sqrt(np.mean(diff ** 2, axis=1))
    out = {name: {"rmse": float(r), "noise_sd": float(s), "ratio": float(r / s)}
           for name, r, s in zip(names, rmse, obs.velocity_sd)}
    out["all"] = {"rmse": float(np.sqrt(np.mean(diff ** 2)))}
    return out


def _prediction(problem: Problem, scene: Scene, obs: Observation, theta_best: np.ndarray,
                draws: np.ndarray | None, tail: float) -> dict:
    duration = float(obs.frame_times[-1] - obs.release_time) + tail
    thetas = theta_best[None] if draws is None else np.concatenate([theta_best[None], draws])
    phys = problem.space.physical(jnp.asarray(thetas))
    rest: RestPrediction = predict_rest(problem.sim, phys, duration)
    k1 = np.asarray(phys.friction)[:, 0]
    out = {"simulated_seconds_after_release": duration, "objects": []}
    for i in range(scene.n_objects):
        x = rest.rest_x[:, i]
        entry = {
            "object": i + 1,
            "rest_x_m": float(x[0]),
            "distance_past_foot_m": float(x[0]),
            "stop_time_after_release_s": None if np.isnan(rest.stop_time[0, i]) else float(rest.stop_time[0, i]),
            "still_moving_at_end": bool(rest.moving_at_end[0, i]),
        }
        if draws is not None:
            entry["rest_x_interval90_m"] = [float(np.quantile(x[1:], 0.05)), float(np.quantile(x[1:], 0.95))]
        out["objects"].append(entry)
    tan = math.tan(scene.ramp.angle)
    out["will_object1_slide"] = {
        "answer": bool(slides(scene, k1[0])),
        "rule": f"slides from rest when k1 < tan(theta) = {tan:.3f}",
        "probability": float(np.mean(slides(scene, k1[1:]))) if draws is not None else None,
    }
    return out


def simulated_poses(problem: Problem, theta: np.ndarray) -> np.ndarray:
    """(N, n_objects, 3) simulated poses (x m, z m, pitch rad) at the video's frame times."""
    return problem.poses(theta)


def fit_engine(scene: Scene, cfg: FitConfig) -> str:
    """The simulation engine of a fit of ``scene`` (:func:`~galileo_jax.config.resolve_engine`
    with the scene's own effects and ``cfg.effects``)."""
    from galileo_jax.config import resolve_engine
    from galileo_jax.physics.simulate import scene_effects

    return resolve_engine(cfg, scene_effects(scene, cfg.effects))


def cnn_model_for(scene: Scene, fps: float, cfg: FitConfig, method: str, init: str) -> tuple[object, str | None]:
    """``(model, note)``: the trained CNN a fit of ``scene`` filmed at ``fps`` uses (or None),
    and for ``init`` auto with method grad why none is used (or None).

    ``method`` cnn, ``init`` cnn, or a network named by ``cfg.cnn.model``: that network, else
    the shipped one that reads the scene (:func:`~galileo_jax.inference.cnn_files.find_model`).
    ``init`` auto with method grad: the same where one reads the scene and the fit adds no
    ``cfg.effects`` (a network knows the base model only), else None and the reason (grad then
    starts from the prior). Otherwise None.

    Raises:
        CNNError, OutOfFamily: method cnn or init cnn (or a named network that does not read the
            scene), and no network reads the scene (one line).
    """
    from galileo_jax.inference.cnn_files import find_model

    if method == "cnn" or init == "cnn":
        return find_model(scene, fps, cfg.cnn.model), None
    if init != "auto" or method != "grad":
        return None, None
    if cfg.effects:
        return None, f"a trained CNN knows the base model only, not --effects {','.join(cfg.effects)}"
    if cfg.cnn.model:  # the user's own network: an error of theirs is said, not stepped round
        return find_model(scene, fps, cfg.cnn.model), None
    try:
        return find_model(scene, fps), None
    except GalileoError as err:  # CNNError, OutOfFamily: no shipped network reads this scene
        return None, _reason(err)


def _reason(err: Exception) -> str:
    """A CNN error's reason without its advice ("; use --method grad or mh", "; train one: ..."),
    for a grad fit that starts from the prior instead."""
    return str(err).split("; use --method")[0].split("; train one")[0]


def track_video(video: Path, scene: Scene, cfg: FitConfig, *, fps: float | None = None, method: str = "grad",
                init: str = "auto", progress: bool = True) -> Tracked:
    """Read and track one video (the first stage of :func:`run_fit`).

    For method cnn or init cnn the trained model is found first, so a scene without one fails
    before tracking; for init auto (grad, no ``cfg.effects``) it is looked for, and None where
    no network reads the scene.

    Raises:
        GalileoError: bad video, tracking failure, no CNN for the scene (method cnn or init cnn).
    """
    from galileo_jax.observe import observe, read_video

    t = time.perf_counter()
    clip = read_video(video, fps_override=fps or scene.video.fps)
    cnn_model, cnn_note = cnn_model_for(scene, clip.fps, cfg, method, init)  # before tracking: fail early
    obs = observe(clip, scene, progress=progress)
    return Tracked(Path(video), clip, obs, cnn_model, time.perf_counter() - t, cnn_note)


def scene_for_fit(scene: Scene, cfg: FitConfig, method: str = "grad") -> Scene:
    """The scene a fit of ``method`` works with: where the camera states no ``scale_tolerance``,
    ``cfg.scale_tolerance`` (:attr:`~galileo_jax.config.FitConfig.scale_tolerance`), so that grad
    and mh fit the nuisance ``scale_error`` (started from the CNN too: the network's estimate
    leaves it at 0 with its window open, :data:`~galileo_jax.inference.cnn.NEUTRAL_KINDS`). The
    CNN's network reads the base model's coordinates only and the seed's sampler the physical
    ones: ``--method cnn`` and ``--method seed`` keep the scene as stated."""
    if method in ("cnn", "seed"):
        return scene
    return scene.with_scale_tolerance(cfg.scale_tolerance)


def problem_options(scene: Scene, cfg: FitConfig, method: str) -> dict:
    """:class:`Problem`'s likelihood, sd_model, ensemble (:func:`~galileo_jax.config.ensemble_for`
    ``method``), effects and engine for a fit of ``scene`` with ``cfg``."""
    return dict(likelihood=cfg.likelihood.kind, sd_model=cfg.likelihood.sd_model, effects=cfg.effects,
                engine=fit_engine(scene, cfg), ensemble=ensemble_for(cfg, method))


def run_fit(video: Path, scene: Scene, cfg: FitConfig, *, method: str, out: Path, fps: float | None = None,
            seed: int = 0, overlay: bool = True, progress: bool = True, init: str = "auto") -> FitReport:
    """Fit one video and write the results (see module docstring).

    Args:
        video: video path.
        scene: validated scene of the video.
        cfg: settings.
        method: "grad", "mh", "cnn" or "seed".
        out: output folder (created; existing files are replaced atomically).
        fps: frame-rate override.
        seed: random seed.
        overlay: write the overlay video.
        progress: show progress bars.
        init: "prior", "cnn" (grad and mh start from the trained CNN's estimate) or "auto"
            (grad from the CNN where a network reads the video, else from the prior; mh from
            the prior).

    Raises:
        GalileoError: bad video, tracking failure, unknown method or likelihood, no CNN for
            the scene (method cnn or init cnn).
    """
    tracked = track_video(video, scene, cfg, fps=fps, method=method, init=init, progress=progress)
    t = time.perf_counter()
    scene = scene_for_fit(scene, cfg, method)
    try:
        problem = Problem(scene, tracked.observation, **problem_options(scene, cfg, method))
    except ValueError as err:
        raise GalileoError(f"{err}") from None
    key = jax.random.PRNGKey(seed)
    parameters, diagnostics, theta_best, draws, posterior = _estimate_and_draws(problem, method, cfg, key, progress,
                                                                                 init, tracked.cnn_model,
                                                                                 tracked.cnn_note)
    diagnostics["engine"] = problem.simulator_engine
    timings = {"observe_s": tracked.seconds, "inference_s": time.perf_counter() - t}
    return finish_fit(tracked, problem, cfg, method=method, parameters=parameters, diagnostics=diagnostics,
                      theta_best=theta_best, draws=draws, timings=timings, out=out, seed=seed, overlay=overlay,
                      progress=progress, posterior=posterior)


def finish_fit(tracked: Tracked, problem: Problem, cfg: FitConfig, *, method: str, parameters: dict,
               diagnostics: dict, theta_best: np.ndarray, draws: np.ndarray | None, timings: dict, out: Path,
               seed: int = 0, overlay: bool = True, progress: bool = True,
               posterior: Posterior | None = None) -> FitReport:
    """The last stages of :func:`run_fit`: simulate the estimate (d,) and the draws (S, d) over
    the whole video, predict beyond it, and write ``result.json``, ``profiles.png``,
    ``tracking.png``, ``posterior.nc`` (with a ``posterior``) and ``overlay.mp4`` (if
    ``overlay``) into ``out``; ``timings`` (seconds per stage) is completed.

    Raises:
        OSError: ``out`` cannot be written.
    """
    obs, scene = tracked.observation, problem.scene
    t = time.perf_counter()
    simulated = _simulate_batch(problem, theta_best[None])[0]
    band = None
    if draws is not None and len(draws) >= 8:
        profiles = _simulate_batch(problem, draws)
        band = np.quantile(profiles, [0.05, 0.95], axis=0)
    rmse = _rmse(obs, simulated)
    prediction = _prediction(problem, scene, obs, theta_best, draws, cfg.prediction.tail)
    poses = simulated_poses(problem, theta_best)
    adequacy = fit_adequacy(obs, simulated, poses, cfg.likelihood.sd_model)
    timings["simulate_and_predict_s"] = time.perf_counter() - t

    report = FitReport(tracked.video, scene, method, obs, parameters, diagnostics, simulated, band, rmse, prediction,
                       timings=timings, adequacy=adequacy, posterior=posterior)
    t = time.perf_counter()
    write_fit(report, poses, tracked.clip, out, cfg, seed, overlay, progress)
    timings["write_s"] = time.perf_counter() - t
    return report


def run_fit_batch(videos: list[Path], scene: Scene, cfg: FitConfig, *, outs: list[Path], fps: float | None = None,
                  seed: int = 0, overlay: bool = False, progress: bool = True) -> list[FitReport | Exception]:
    """``run_fit(..., method="grad", init="prior")`` of several videos of one scene, their fits as one batched
    computation (:func:`~galileo_jax.inference.batch.fit_grad_batch`, sharded over the local
    devices when there are several; one call per frame rate among the videos).

    Each video is tracked (:func:`track_video`) and written (:func:`finish_fit`, into its own
    ``outs[j]``) as ``run_fit`` does, and gets the estimate ``run_fit`` gives it with the same
    ``seed`` (the same screen, LM and draws; up to floating-point order). Its
    ``timings["inference_s"]`` is the batch's inference time divided by the videos in it;
    ``diagnostics["batch_videos"]`` says how many videos were fitted together.

    Args:
        videos: B video paths.
        scene: their validated scene.
        cfg: settings (grad from the prior: ``cfg.grad``'s starts, screen, jacobian, max_steps).
        outs: B output folders, one per video.
        fps, seed, overlay, progress: as :func:`run_fit`.

    Returns:
        B entries in the order of ``videos``: the video's :class:`FitReport`, or the exception
        that stopped it (tracking failed, the batch's fit failed, writing failed); one video's
        failure does not stop the others.

    Raises:
        ValueError: ``outs`` is not one folder per video.
    """
    from galileo_jax.inference.batch import batch_problems, fit_grad_batch

    if len(outs) != len(videos):
        raise ValueError(f"run_fit_batch needs one output folder per video: {len(videos)} videos, {len(outs)} outs")
    results: list[FitReport | Exception | None] = [None] * len(videos)
    tracked: dict[int, Tracked] = {}
    for j, video in enumerate(videos):
        try:
            tracked[j] = track_video(video, scene, cfg, fps=fps, init="prior", progress=progress)
        except Exception as err:  # noqa: BLE001 - recorded for this video; the others still fit
            results[j] = err
    k_run, k_sum = jax.random.split(jax.random.PRNGKey(seed))
    by_fps: dict[float, list[int]] = {}
    for j, tr in tracked.items():
        by_fps.setdefault(float(tr.observation.fps), []).append(j)
    scene = scene_for_fit(scene, cfg)
    for members in by_fps.values():
        t = time.perf_counter()
        try:
            problems = batch_problems(scene, [tracked[j].observation for j in members],
                                      **problem_options(scene, cfg, "grad"))
            fits = fit_grad_batch(problems, k_run, **grad_options(cfg))
            from galileo_jax.inference.grad import after_lm

            # as a single fit does: the search and the profile check, per video, from the same key
            fits = [after_lm(res, problem, k_run, search_generations=cfg.grad.search_generations,
                             profile=cfg.grad.profile, inside=cfg.grad.inside, max_steps=cfg.grad.max_steps)
                    for problem, res in zip(problems, fits)]
        except Exception as err:  # noqa: BLE001 - the batch failed: every video in it records why
            for j in members:
                results[j] = GalileoError(str(err)) if isinstance(err, ValueError) else err
            continue
        inference_s = (time.perf_counter() - t) / len(members)
        for j, problem, res in zip(members, problems, fits):
            try:
                parameters, diagnostics, theta_best, draws = grad_estimate(res, problem.space, k_sum, cfg)
                diagnostics.update(engine=problem.simulator_engine, batch_videos=len(members))
                timings = {"observe_s": tracked[j].seconds, "inference_s": inference_s}
                results[j] = finish_fit(tracked[j], problem, cfg, method="grad", parameters=parameters,
                                        diagnostics=diagnostics, theta_best=theta_best, draws=draws,
                                        timings=timings, out=outs[j], seed=seed, overlay=overlay, progress=progress,
                                        posterior=gauss_newton_posterior(res, problem.space, k_sum))
            except Exception as err:  # noqa: BLE001 - recorded for this video
                results[j] = err
    return results


# ---------------------------------------------------------------------------- several videos
def run_joint_fit(inputs: list[tuple[Path, Scene]], cfg: FitConfig, *, method: str, out: Path,
                  fps: float | None = None, seed: int = 0, per_video: tuple[str, ...] = (),
                  progress: bool = True) -> JointFitReport:
    """Fit several videos of one setup together (:class:`~galileo_jax.inference.joint.JointProblem`:
    one set of shared parameters, ``dt_release``, ``v0`` and ``per_video`` names per video) and
    write ``result.json`` and one ``profiles_<j>.png`` per video into ``out``.

    Raises:
        GalileoError: bad videos, tracking failures, an unknown method, or parameters the
            videos cannot share (e.g. a ``per_video`` name that no video has).
    """
    from galileo_jax.inference import summary
    from galileo_jax.inference.joint import JointProblem
    from galileo_jax.observe import observe, read_video

    if method not in ("grad", "mh"):
        raise GalileoError(f"a joint fit of several videos supports --method grad or mh, not {method!r}")
    timings = {}
    t = time.perf_counter()
    observations = [observe(read_video(v, fps_override=fps or s.video.fps), s, progress=progress) for v, s in inputs]
    timings["observe_s"] = time.perf_counter() - t
    t = time.perf_counter()
    try:
        scenes = [scene_for_fit(s, cfg, method) for _, s in inputs]
        problems = [Problem(s, o, **problem_options(s, cfg, method)) for s, o in zip(scenes, observations)]
        joint = JointProblem(problems, per_video)
    except ValueError as err:
        raise GalileoError(str(err)) from None
    key = jax.random.PRNGKey(seed)
    k_run, k_draw = jax.random.split(key)
    if method == "grad":
        from galileo_jax.inference.covariance import gauss_newton_draws
        from galileo_jax.inference.grad import fit_grad

        res = fit_grad(joint, k_run, n_starts=cfg.grad.starts, n_screen=max(cfg.grad.screen, cfg.grad.starts),
                       jacobian=cfg.grad.jacobian, max_steps=cfg.grad.max_steps)
        theta_best, draws = np.asarray(res.theta), gauss_newton_draws(res, joint.space, k_draw, cfg.prediction.draws)
    else:
        from galileo_jax.inference.mh import run_mh

        res = run_mh(joint, k_run, n_chains=cfg.mh.chains, n_warmup=cfg.mh.warmup, n_samples=cfg.mh.samples,
                     jump=cfg.mh.jump, independent=cfg.mh.independent, progress=progress)
        flat = res.theta.reshape(-1, res.theta.shape[-1])
        theta_best, draws = np.asarray(res.best_theta), draw_subset(flat, cfg.prediction.draws, k_draw)
    summ = summary.summarize_coordinates(res, method)
    summ["diagnostics"]["engine"] = joint.simulator_engine
    timings["inference_s"] = time.perf_counter() - t
    t = time.perf_counter()
    simulated = [np.asarray(s) for s in joint.simulate(theta_best)]
    bands = [np.quantile(np.asarray(s), [0.05, 0.95], axis=0) for s in joint.simulate(draws)]
    rmse = [_rmse(o, s) for o, s in zip(observations, simulated)]
    video_ll = [float(x) for x in joint.video_log_likelihoods(theta_best)]
    adequacy = [fit_adequacy(o, s, simulated_poses(p, np.asarray(joint.theta_for(j, theta_best))),
                                   cfg.likelihood.sd_model)
                for j, (o, s, p) in enumerate(zip(observations, simulated, joint.problems))]
    timings["simulate_s"] = time.perf_counter() - t
    report = JointFitReport([v for v, _ in inputs], [s for _, s in inputs], method, observations, joint.space.per_video,
                            summ["parameters"], summ["diagnostics"], simulated, bands, rmse, video_ll, timings=timings,
                            adequacy=adequacy)
    write_joint_fit(report, out, cfg, seed, shared=[n for n in joint.names if "@" not in n])
    return report
