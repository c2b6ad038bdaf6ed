"""The models a diagnosis compares: unions of candidate effects in one parameter space
(:class:`Union`, :class:`Workspace`), their fits (:func:`fit_model`: Levenberg-Marquardt, then a
CMA-ES search) and what each fit shows (:class:`ModelFit`, :class:`VideoFit`).

The loop that uses them is :mod:`galileo_jax.criticism.diagnosis` (its module docstring says why
each step is there).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

import jax
import numpy as np

from galileo_jax.criticism import noise
from galileo_jax.criticism import residuals as criticism
from galileo_jax.criticism.adequacy import profile_rmse
from galileo_jax.criticism.settings import DiagnoseSettings
from galileo_jax.effects import Effect, available_effects, resolve_effects
from galileo_jax.inference.grad import GradResult, fit_grad
from galileo_jax.inference.joint import JointProblem
from galileo_jax.inference.problem import Problem
from galileo_jax.inference.search import cma_search
from galileo_jax.inference.summary import summarize_grad
from galileo_jax.physics.simulate import scene_effects
from galileo_jax.scene import Scene


@dataclass
class VideoFit:
    """One video's view of a fitted model.

    Attributes:
        simulated: (2n_obj, N-1) simulated profile over the whole video, m/s.
        poses: (N, n_obj, 3) simulated poses at the frame times (x m, z m, pitch rad).
        residuals: (T * m,) standardised residuals at the used samples.
        rmse: RMSE of observed - simulated velocity over the fit window, all traces, m/s.
        criticism: :func:`galileo_jax.criticism.residuals.summarize` dict (phases, table, verdict).
        test_residuals: (T * m,) residuals standardised in the test likelihood
            (:mod:`galileo_jax.criticism.diagnosis`), trace-major over the used samples; None before it is set up.
    """

    simulated: np.ndarray
    poses: np.ndarray
    residuals: np.ndarray
    rmse: float
    criticism: dict
    test_residuals: np.ndarray | None = None


@dataclass
class EffectTest:
    """One refitted effect tested against the current model
    (:func:`~galileo_jax.criticism.nested.compare`, :func:`~galileo_jax.criticism.nested.test_effect`;
    JSON through :meth:`as_dict`).

    Attributes:
        effect: the effect's name; model: the refitted model's name.
        lr: 2 (log L_alt - log L_current) in the fit's likelihood (nats x 2).
        lr_scaled: the likelihood ratio on the test likelihood with per-trace noise scales
            (:func:`~galileo_jax.inference.screen.scaled_lr`); dispersion: those scales per trace.
        delta_loglik: log L_alt - log L_current (nats).
        p_value: the test's p-value; test: which test ("likelihood ratio, chi2(k)", "Vuong ...").
        vuong_z: Vuong's statistic for a structural effect (None for a nested test).
        rmse_before, rmse_after: RMSE (m/s) of the current and the refitted model; rmse_drop:
            1 - rmse_after / rmse_before.
        parameters: the effect's parameters in the refit's summary.
        looks_like_noise: the refit's residuals look like noise.
        fit_index: the refit's index in ``Diagnosis.fits``; engine: the engine it ran on.
        negligible: the refit passed its test and the RMSE guard, but its fitted value lies
            within the effect's region of practical equivalence
            (:func:`~galileo_jax.criticism.nested.negligible`), so it is not supported.
        supported: p below the round's threshold, an RMSE drop of at least ``min_rmse_drop``, and
            not ``negligible``.
        vuong_p_vs_winner: for a supported effect other than the winner, Vuong's p against the
            winner (:func:`~galileo_jax.criticism.nested.indistinguishable`), else None.
    """

    effect: str
    model: str
    lr: float
    lr_scaled: float
    dispersion: list
    delta_loglik: float
    p_value: float
    test: str
    vuong_z: float | None
    rmse_before: float
    rmse_after: float
    rmse_drop: float
    parameters: dict
    looks_like_noise: bool
    fit_index: int = -1
    engine: str = ""
    negligible: bool = False
    supported: bool = False
    vuong_p_vs_winner: float | None = None

    def as_dict(self) -> dict:
        """The JSON record (``vuong_p_vs_winner`` only where it was computed)."""
        out = asdict(self)
        if self.vuong_p_vs_winner is None:
            del out["vuong_p_vs_winner"]
        return out


@dataclass
class Round:
    """What one round of :func:`~galileo_jax.criticism.diagnosis.diagnose` did and found
    (``Diagnosis.rounds``; JSON through :meth:`as_dict`).

    Attributes:
        round: 1, 2, ... (one effect is added per round).
        base: name of the model the round tests effects against.
        threshold_p: the p-value an effect must stay below (alpha / candidates).
        screen: the screen's rows (:func:`~galileo_jax.criticism.screening.screen_candidates`),
            largest statistic first.
        engines: {effect: engine its model was fitted on}.
        transfers: the current model refitted on another engine (one dict each).
        refits: each refitted effect's :class:`EffectTest` (:func:`~galileo_jax.criticism.nested.test_effect`).
        winner: the effect named in this round, or None.
        indistinguishable: {"effects", "vuong_p", "message"} when supported effects cannot be
            told apart, else None.
        adequate: the current model was adequate (step 3): nothing left to explain.
        null_refit: the current model refitted from an alternative's estimate (one dict per union).
        quiet: the screen pointed at nothing (step 4b) and no refit ran.
        calm_rmse, calm_fraction: with ``adequate``, the RMSE (m/s) away from contact events and
            the share of samples it covers.
    """

    round: int
    base: str
    threshold_p: float
    screen: list = field(default_factory=list)
    engines: dict = field(default_factory=dict)
    transfers: list = field(default_factory=list)
    refits: list[EffectTest] = field(default_factory=list)
    winner: str | None = None
    indistinguishable: dict | None = None
    adequate: bool = False
    null_refit: list = field(default_factory=list)
    quiet: bool = False
    calm_rmse: float | None = None
    calm_fraction: float | None = None

    def as_dict(self) -> dict:
        """The JSON record (``quiet`` and the calm RMSE only where they apply)."""
        out = {k: getattr(self, k) for k in ("round", "base", "threshold_p", "screen", "engines", "transfers",
                                              "refits", "winner", "indistinguishable", "adequate", "null_refit")}
        out["refits"] = [t.as_dict() for t in self.refits]
        if self.quiet:
            out["quiet"] = True
        if self.calm_rmse is not None:
            out.update(calm_rmse=self.calm_rmse, calm_fraction=self.calm_fraction)
        return out


@dataclass
class ModelFit:
    """One fitted model (base or base + effects) and how well it fits.

    Attributes:
        name: "base" or "base + effect + ...".
        effects: names of the added effects (the scene's own are always included).
        union: the :class:`Union` problem the model lives in (:mod:`galileo_jax.criticism.diagnosis`).
        result: the Levenberg-Marquardt result (in the problem's coordinates; the effects
            the model does not contain are held, ``result.fixed``).
        summary: :func:`summarize_grad` dict (estimates, 90% intervals) of a single video,
            or {"parameters": ...} of a joint fit.
        loglik: log-likelihood at the estimate (nats).
        residuals: (n,) standardised residuals at the used samples of all videos.
        rmse: RMSE of observed - simulated velocity over every video's fit window, m/s.
        videos: per video its :class:`VideoFit`.
        criticism: {"verdict", "looks_like_noise", "videos": per-video criticism dicts}.
        test_residuals: (n,) residuals of all videos in the test likelihood (None before it is set up).
        search: a refit's CMA-ES search after LM (:func:`fit_model`): generations, evaluations,
            log-likelihoods of LM's end, of the search's best point and of the result, the
            RMSE at LM's end (m/s), whether it was used, time; None when no search ran.
        polish: the named model's second search (:func:`polish`), with the RMSE before
            (``rmse_lm``) and after (``rmse``, m/s) when it was used; None for the other models.
    """

    name: str
    effects: tuple[str, ...]
    union: "Union"
    result: GradResult
    summary: dict
    loglik: float
    residuals: np.ndarray
    rmse: float
    videos: list[VideoFit]
    criticism: dict = field(default_factory=dict)
    test_residuals: np.ndarray | None = None
    search: dict | None = None
    polish: dict | None = None

    @property
    def problem(self):
        """The problem (single-video Problem or JointProblem) the model was fitted in."""
        return self.union.problem

    @property
    def simulated(self) -> np.ndarray:
        """The first video's simulated profile (the only one for a single-video diagnosis)."""
        return self.videos[0].simulated

    @property
    def poses(self) -> np.ndarray:
        """The first video's simulated poses."""
        return self.videos[0].poses

    def as_dict(self) -> dict:
        return {"name": self.name, "effects": list(self.effects), "engine": self.union.engine,
                "parameters": self.summary["parameters"], "loglik": self.loglik, "rmse_m_per_s": self.rmse,
                "rmse_per_video_m_per_s": [v.rmse for v in self.videos], "iterations": int(self.result.iterations),
                "converged": bool(self.result.converged), "time_s": float(self.result.time_s),
                "search": self.search, "polish": self.polish, "criticism": self.criticism}


#: Parameters that describe the camera's calibration, not the physics (fitted as nuisances,
#: :attr:`DiagnoseSettings.scale_tolerance`).
CALIBRATION_NUISANCES = ("scale_error",)


def pooled_rms(values: Sequence[float], weights: Sequence[float]) -> float:
    """sqrt(sum w v^2 / sum w): RMS values of several videos pooled by their sample counts."""
    v, w = np.asarray(values, np.float64), np.asarray(weights, np.float64)
    return float(np.sqrt(np.sum(w * v**2) / np.sum(w)))


def with_calibration_nuisances(scene: Scene, settings: DiagnoseSettings) -> Scene:
    """``scene`` with the diagnosis's default calibration tolerance where it states none
    (``camera.scale_tolerance`` unset: ``settings.scale_tolerance``); a stated one, 0 included, is kept."""
    return scene.with_scale_tolerance(settings.scale_tolerance)


def candidate_effects(scene: Scene, names=None, exclude=()) -> tuple[Effect, ...]:
    """Effects to consider for ``scene``: the named ones (default: all registered) that apply to
    the scene and are not already in it or in ``exclude``."""
    pool = resolve_effects(names) if names is not None else tuple(available_effects().values())
    have = {e.name for e in scene_effects(scene)} | set(exclude)
    return tuple(e for e in pool if e.name not in have and not e.applies(scene))


# ---------------------------------------------------------------------------- the union problem
def base_name(name: str) -> str:
    """A joint coordinate's parameter name: ``"v0@2"`` -> ``"v0"``."""
    return name.split("@", 1)[0]


class Union:
    """The problem holding the base model and a set of effects, and which coordinates each effect owns.

    Arguments:
        scenes, observations: the videos.
        effects: the effects simulated (all held at neutral unless a model frees them).
        settings: likelihood kind and floor, per-video names.
        sd_events: None (no test likelihood yet), or per video the (2n, N-1) event SDs of
            the test likelihood (:mod:`galileo_jax.criticism.diagnosis`; set by :func:`~galileo_jax.criticism.diagnosis.diagnose` from the base fit).
        engine: the simulation engine of every model in it, "mjx" or "mujoco".
    """

    def __init__(self, scenes, observations, effects, settings: DiagnoseSettings, sd_events=None,
                 engine: str = "mjx"):
        self.effects = tuple(effects)
        self.engine = engine
        self.scenes, self.observations = list(scenes), list(observations)
        self.sd_events = list(sd_events) if sd_events is not None else None
        self.sd_test = settings.sd_test
        problems = [Problem(s, o, likelihood=settings.likelihood, sd_model=settings.sd_model, effects=self.effects,
                            engine=engine) for s, o in zip(scenes, observations)]
        self.problems = problems
        self.problem = problems[0] if len(problems) == 1 else JointProblem(problems, settings.per_video)
        owner = {p.name: (e, p) for e in self.effects for p in e.params}
        self.coords: dict[str, list[int]] = {e.name: [] for e in self.effects}
        self.neutral: dict[str, float] = {}
        for j, name in enumerate(self.problem.names):
            if base_name(name) in owner:
                e, prm = owner[base_name(name)]
                self.coords[e.name].append(j)
                self.neutral[name] = prm.neutral

    def residual_groups(self) -> np.ndarray:
        """(n,) trace index (0, 1, ... over all videos) of every used residual, in the order of
        :attr:`ModelFit.residuals` (video by video, trace-major)."""
        out, offset = [], 0
        for p in self.problems:
            t, m = p.likelihood.obs.shape[0], p.likelihood.idx.size
            out.append(offset + np.repeat(np.arange(t), m))
            offset += t
        return np.concatenate(out)

    def samples_used(self) -> list[int]:
        """Per video the number of fitted velocity samples, all traces (the RMSE pooling weights)."""
        return [int(np.sum(p.observation.mask)) * p.likelihood.obs.shape[0] for p in self.problems]

    def theta_for(self, j: int, theta: np.ndarray) -> np.ndarray:
        """Video j's coordinates of the union's theta."""
        if isinstance(self.problem, JointProblem):
            return np.asarray(self.problem.theta_for(j, theta))
        return np.asarray(theta)

    def held(self, free_effects) -> dict[str, float]:
        """{coordinate: neutral value} of the effects NOT in ``free_effects``."""
        free = {j for e in free_effects for j in self.coords.get(e, [])}
        return {n: v for n, v in self.neutral.items() if self.problem.names.index(n) not in free}

    @property
    def structural(self) -> frozenset[str]:
        """Names of the structural effects simulated (they change the model even when nothing is freed)."""
        return frozenset(e.name for e in self.effects if e.structural)

    def theta_from(self, other: "Union", theta: np.ndarray) -> np.ndarray:
        """``theta`` of a model in ``other`` expressed in this union's coordinates: shared names
        keep their values, this union's extra effect coordinates take their neutral values.

        Raises:
            ValueError: a coordinate of this union that is neither in ``other`` nor an effect's.
        """
        src = list(other.problem.names)
        out = []
        for name in self.problem.names:
            if name in src:
                out.append(float(theta[src.index(name)]))
            elif name in self.neutral:
                out.append(self.neutral[name])
            else:
                raise ValueError(f"coordinate {name!r} has no value in the other model ({src})")
        return np.asarray(out, np.float64)


def model_engine(scenes, effects, settings: DiagnoseSettings) -> str:
    """The engine of a model with the scenes' own effects plus ``effects``: with ``--engine
    auto``, MJX if any of them acts every physics step, else C MuJoCo.

    Unlike ``fit`` (:func:`~galileo_jax.config.resolve_engine`), an effect that acts every step
    stays on MJX here even where it has a C form (``quadratic_drag``): the per-step candidates
    are ranked by their log-likelihood gain over their own engine's null, so they must share
    one. Measured on the calibration render quadratic_drag_0 with quadratic drag on C MuJoCo:
    its refit took 29 s instead of 70-115 s on MJX and fitted best (RMSE 0.0030 m/s against
    velocity friction's 0.0060), yet velocity friction was named: its gain over the MJX null
    (29.5 nats) beat quadratic drag's over the C null (27.4), the C null having reached a 3.1
    nats better optimum."""
    from galileo_jax.config import pick_engine
    from galileo_jax.effects.runtime import has_step_hooks

    return pick_engine(settings.engine, any(has_step_hooks(scene_effects(s, effects)) for s in scenes))


def search_budget(union: Union, settings: DiagnoseSettings, generations: int) -> tuple[int, int]:
    """(points per generation, generations) of a CMA-ES search in ``union``: ``search_popsize``
    and ``generations`` on MJX; ``search_popsize_c`` and ``search_generations_c`` on the C engine
    (0 generations stay 0: the search is off)."""
    if union.engine == "mujoco":
        return settings.search_popsize_c, (settings.search_generations_c if generations > 0 else 0)
    return settings.search_popsize, generations


def fit_model(union: Union, free_effects, settings: DiagnoseSettings, key, *, init: np.ndarray | None = None,
              starts: int | None = None, screen: int | None = None, search: bool = True) -> ModelFit:
    """Fit base + ``free_effects`` inside ``union`` and evaluate it (residuals, profiles, criticism);
    from ``init``, LM is followed by the CMA-ES search (:func:`search_then_lm`) unless ``search`` is False."""
    free_effects = tuple(free_effects)
    n_starts = settings.base_starts if starts is None else starts
    n_screen = settings.base_screen if screen is None else screen
    held = union.held(free_effects) or None
    res = fit_grad(union.problem, key, n_starts=n_starts, n_screen=max(n_screen, n_starts), init=init,
                   fixed=held, max_steps=settings.max_steps,
                   local_screen=None if init is None else settings.refit_spread)
    record = None
    if search and init is not None and search_budget(union, settings, settings.refit_search)[1] > 0:
        # LM stops in the rough cost's ripples: search on
        restarts = search_restarts(union, free_effects)
        starts = ()
        if restarts > 1:  # a multimodal cost: also search from a global screen's fit
            glob = fit_grad(union.problem, jax.random.fold_in(key, 7), n_starts=settings.base_starts,
                            n_screen=settings.base_screen, fixed=held, max_steps=settings.max_steps)
            starts = (glob.theta,)
            if glob.loglik > res.loglik:
                res = glob
        res, record = search_then_lm(union, res, held, settings, key, settings.refit_search, settings.search_sigma,
                                     restarts=restarts, starts=starts, patience=settings.search_patience)
    fit = evaluate(union, res, free_effects, settings)
    if record is not None:
        record.setdefault("rmse_lm", fit.rmse)  # the search's point was not used: LM's end is the fit
    fit.search = record
    return fit


def search_restarts(union: Union, free_effects) -> int:
    """CMA-ES searches of a refit freeing ``free_effects``: the largest ``Effect.search_restarts`` among them (>= 1)."""
    by_name = {e.name: e for e in union.effects}
    return max([1] + [by_name[n].search_restarts for n in free_effects if n in by_name])


def search_then_lm(union: Union, res: GradResult, held, settings: DiagnoseSettings, key, generations: int,
                   sigma: float, rmse_lm: float | None = None, restarts: int = 1,
                   starts: Sequence[np.ndarray] = (), patience: int | None = None) -> tuple[GradResult, dict]:
    """CMA-ES from ``res``'s estimate (:func:`search_budget` of ``generations``, initial step
    ``sigma`` in z), then LM again from its best point if that is better; returns the better
    result and a record of the search (log-likelihoods of LM's end, of the search and of the result,
    and, when the search's point is used, the RMSE at LM's end: ``rmse_lm`` if known, else one rollout).

    With ``restarts`` > 1, that many independent searches (seeds) run, alternating between
    ``res``'s estimate and ``starts`` (e.g. a global screen's fit), and the best point of all is
    used: where the cost has several basins (impacts, :attr:`Effect.search_restarts`) one
    search finds the best one only some of the time. ``patience``: each search stops after that
    many generations without a gain of 0.5 nats (:func:`~galileo_jax.inference.search.cma_search`)."""
    popsize, generations = search_budget(union, settings, generations)
    seed = int(jax.random.randint(key, (), 0, 2**30))
    points = [res.theta] + [np.asarray(s, np.float64) for s in starts]
    runs = [cma_search(union.problem, points[r % len(points)], sigma=sigma, popsize=popsize,
                       generations=generations, seed=seed + r, fixed=held, patience=patience)
            for r in range(max(int(restarts), 1))]
    found = max(runs, key=lambda f: f.loglik)
    search = {"method": "CMA-ES (pycma)", "generations": found.generations,
              "evaluations": sum(f.evaluations for f in runs), "loglik_lm": res.loglik,
              "loglik_search": found.loglik, "time_s": sum(f.time_s for f in runs), "used": False,
              "generations_run": [int(f.generations) for f in runs]}
    if len(runs) > 1:
        search["restarts"] = len(runs)
        search["loglik_runs"] = [float(f.loglik) for f in runs]
    if found.loglik > res.loglik + 1e-6:  # LM again from the search's best point, for the covariance
        again = fit_grad(union.problem, jax.random.fold_in(key, 1), n_starts=0, n_screen=0, init=found.theta,
                         fixed=held, max_steps=settings.max_steps)
        if again.loglik > res.loglik:
            search.update(used=True, rmse_lm=union_rmse(union, res.theta) if rmse_lm is None else rmse_lm)
            res = again
    search["loglik"] = res.loglik
    return res, search


def polish(fit: ModelFit, settings: DiagnoseSettings, key) -> ModelFit:
    """The named model refitted once more: a second CMA-ES search of ``settings.winner_search``
    generations from its estimate, with half the refit's initial step, then LM; the better of the
    two fits (by log-likelihood) is returned, with the second search recorded in ``polish``. Runs
    after the decision, so it changes the reported fit, never which effect is named."""
    if search_budget(fit.union, settings, settings.winner_search)[1] <= 0:
        return fit
    held = fit.union.held(fit.effects) or None
    res, search = search_then_lm(fit.union, fit.result, held, settings, key, settings.winner_search,
                                 settings.search_sigma / 2, rmse_lm=fit.rmse)
    if not search["used"]:
        fit.polish = search
        return fit
    better = evaluate(fit.union, res, fit.effects, settings)
    better.search, better.polish = fit.search, {**search, "rmse": better.rmse}
    return better


def simulate_video(problem: Problem, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(poses, simulated profile (2n, N-1) in m/s) of one video at ``theta``: one whole-video
    rollout gives the poses, the profile and the residuals."""
    poses = problem.poses(theta)
    simulated = np.diff(poses[..., :2], axis=0) / np.diff(problem.observation.frame_times)[:, None, None]
    return poses, simulated.reshape(simulated.shape[0], -1).T


def union_rmse(union: Union, theta: np.ndarray) -> float:
    """Profile RMSE (m/s) over every video's fit window at the union's ``theta``."""
    rmse = [profile_rmse(p.observation, simulate_video(p, union.theta_for(j, theta))[1])
            for j, p in enumerate(union.problems)]
    return pooled_rms(rmse, union.samples_used())


def evaluate(union: Union, res: GradResult, free_effects, settings: DiagnoseSettings) -> ModelFit:
    """A :class:`ModelFit` of the fitted ``res``: profiles, residuals (the fit's and, once
    ``union.sd_events`` is set, the test likelihood's), RMSE and criticism."""
    free_effects = tuple(free_effects)
    videos = []
    for j, p in enumerate(union.problems):
        poses, simulated = simulate_video(p, union.theta_for(j, res.theta))
        obs = p.observation
        z_test = None
        if union.sd_events is not None:
            z_test = noise.standardised_residuals(obs, simulated, union.sd_test, union.sd_events[j])
            z_test = z_test[:, np.asarray(obs.mask, bool)].reshape(-1)
        # the criticism keeps the fit's likelihood (0.05 m/s floor): its structure tests assume the
        # MA(1) noise model, and with the bare tracking noise (lag-1 correlation -> -1/2) the
        # whitened CUSUM flagged the heavy-tailed but unstructured residuals of a real clip (p = 4e-24)
        videos.append(VideoFit(simulated, poses, p.likelihood.used_residuals(simulated),
                               profile_rmse(obs, simulated),
                               criticism.summarize(obs, simulated, poses, settings.sd_model), z_test))
    n_used = union.samples_used()
    name = "base" if not free_effects else "base + " + " + ".join(free_effects)
    if isinstance(union.problem, JointProblem):
        summary = {"parameters": {n: {"mean": float(t), "sd": float(s), "interval90": [float(a), float(b)]}
                                  for n, t, s, (a, b) in zip(res.names, res.theta, res.sd, res.interval90)
                                  if n not in res.fixed or base_name(n) not in union.neutral}}
    else:
        summary = summarize_grad(res, union.problem.space)
    verdicts = [v.criticism["verdict"] for v in videos]
    crit = {"verdict": verdicts[0] if len(videos) == 1 else " ".join(f"Video {j + 1}: {v}" for j, v in enumerate(verdicts)),
            "looks_like_noise": all(v.criticism["looks_like_noise"] for v in videos),
            "videos": [v.criticism for v in videos]}
    test = None if union.sd_events is None else np.concatenate([v.test_residuals for v in videos])
    return ModelFit(name, free_effects, union, res, summary, float(res.loglik),
                    np.concatenate([v.residuals for v in videos]), pooled_rms([v.rmse for v in videos], n_used),
                    videos, crit, test)


class Workspace:
    """The unions of one diagnosis (:mod:`galileo_jax.criticism.diagnosis`, "Engines"): each model lives in the union of
    its engine and structural effects that holds the effects it is compared with.

    Arguments:
        scenes, observations: the videos.
        settings: the diagnosis settings.
    """

    def __init__(self, scenes, observations, settings: DiagnoseSettings):
        self.scenes, self.observations, self.settings = list(scenes), list(observations), settings
        self.unions: list[Union] = []
        self.sd_events = None

    def union(self, engine: str, effects) -> Union:
        """A union on ``engine`` simulating ``effects`` and no other structural effect: an existing
        one that holds them all, else a new one."""
        effects = tuple(effects)
        names = {e.name for e in effects}
        structural = frozenset(e.name for e in effects if e.structural)
        for u in self.unions:
            if u.engine == engine and u.structural == structural and names <= {e.name for e in u.effects}:
                return u
        u = Union(self.scenes, self.observations, effects, self.settings, sd_events=self.sd_events, engine=engine)
        self.unions.append(u)
        return u

    def set_events(self, sd_events) -> None:
        """Set the test likelihood's event SDs in every union, present and future."""
        self.sd_events = list(sd_events)
        for u in self.unions:
            u.sd_events = self.sd_events


#: How the engines are named in progress messages and reports.
ENGINE_NAMES = {"mjx": "MJX", "mujoco": "C MuJoCo"}
