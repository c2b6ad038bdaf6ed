"""Which physics is the model missing? Fit, criticise, screen candidate effects, refit, decide.

:func:`diagnose` runs the model-criticism loop of issue 3 on one video's observation:

1. **Base fit**: the scene's model (the sliding block plus the scene's own effects) by
   Levenberg-Marquardt (:func:`~galileo_jax.inference.grad.fit_grad`).
2. **Criticism**: residuals per motion phase and trace with tests for structure
   (:mod:`galileo_jax.criticism`) and a one-line verdict.
3. **Screen**: for every candidate effect with a parameter, the score statistic of
   :func:`~galileo_jax.inference.screen.score_test` (the residual projected on the effect's
   sensitivity after projecting out the base parameters) and a coarse profile over the
   parameter's range with the same first-order re-adjustment (:func:`screen_candidates`):
   one batched set of rollouts.
4. **Refit** the ``refits`` best-scoring candidates (and every structural effect, which the
   screen cannot rank) from the base estimate plus the screen's linearised step.
5. **Decide**: an effect is *supported* when its likelihood-ratio test against the current
   model (boundary-corrected, or Vuong's test for structural effects) has p below
   ``alpha / m``, m the number of candidates considered (Bonferroni over everything screened,
   because the screen picks the refits from the same data), and the fit's RMSE falls by at
   least ``min_rmse_drop``. The winner is the supported effect with the largest log-likelihood;
   when the runner-up is also supported and Vuong's test between the two has p > 0.05, the
   two cannot be told apart with this video and the report says so, naming the measurement
   that would separate them (each effect's ``evidence``). Without a supported effect the
   answer is "no missing effect".

Why this criterion (and not cross-validation or an information criterion): the question is a
test ("is the base model enough?") with a controlled false-alarm rate, and LR tests are the
most powerful for nested effects; the 0.05 m/s model-error floor in the likelihood makes the
statistics conservative (the floor is larger than the simulator's own error), and the RMSE
guard keeps a significant but negligible improvement from being called a missing effect.
The false-alarm rate is measured on rendered videos without a hidden effect
(``benchmarks/diagnose_calibration.py``).

With ``max_effects > 1`` the loop repeats with the winner added, so a report can show the
error falling step by step. Everything here is orchestration; the physics and statistics live
in :mod:`galileo_jax.effects`, :mod:`galileo_jax.inference` and :mod:`galileo_jax.criticism`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from galileo_jax.effects import Effect, available_effects, resolve_effects
from galileo_jax.effects.runtime import neutral_values
from galileo_jax.inference.grad import GradResult, fit_grad
from galileo_jax.inference.problem import Problem
from galileo_jax.inference.screen import lr_pvalue, project_out, score_test, vuong_test
from galileo_jax.inference.summary import summarize_grad
from galileo_jax.likelihood import DEFAULT_KIND, DEFAULT_SD_MODEL
from galileo_jax.observation import Observation, profile_from_positions
from galileo_jax.scene import Scene
from galileo_jax.pipeline import simulated_poses
from galileo_jax.simulate import scene_effects


@dataclass(frozen=True)
class DiagnoseSettings:
    """Settings of :func:`diagnose`.

    Attributes:
        candidates: effect names to consider (None: every registered effect that applies).
        refits: how many of the best-screened candidates to refit (structural effects are
            always refitted).
        alpha: family-wise false-alarm rate of "an effect is missing" (Bonferroni over candidates).
        min_rmse_drop: smallest relative RMSE reduction that counts (0.05 = 5%).
        max_effects: effects added one after another at most.
        likelihood, sd_model: likelihood kind and model-error floor (m/s), as in ``fit``.
        base_starts, base_screen: multi-start settings of the base fit.
        refit_starts, refit_screen: extra screened starts of each refit besides the start
            from the current estimate plus the screen's step (0: that start only, which saves
            a compilation per refit).
        max_steps: Levenberg-Marquardt step limit.
        indistinct_p: Vuong p-value above which two supported effects count as indistinguishable.
    """

    candidates: tuple[str, ...] | None = None
    refits: int = 3
    alpha: float = 0.05
    min_rmse_drop: float = 0.05
    max_effects: int = 1
    likelihood: str = DEFAULT_KIND
    sd_model: float = DEFAULT_SD_MODEL
    base_starts: int = 4
    base_screen: int = 256
    refit_starts: int = 0
    refit_screen: int = 64
    max_steps: int = 40
    indistinct_p: float = 0.05


@dataclass
class ModelFit:
    """One fitted model (base or base + effects) and how well it fits.

    Attributes:
        name: "base" or "base + effect + ...".
        effects: names of the added effects (the scene's own are always included).
        problem: the inference problem.
        result: the Levenberg-Marquardt result.
        summary: :func:`summarize_grad` dict (estimates, 90% intervals).
        residuals: (n,) standardised residuals at the estimate.
        loglik: log-likelihood at the estimate (nats).
        simulated: (2n_obj, N-1) simulated profile over the whole video, m/s.
        poses: (N, n_obj, 3) simulated poses at the frame times.
        rmse: RMSE of observed - simulated velocity over the fit window, all traces, m/s.
        criticism: :func:`galileo_jax.criticism.summarize` dict (phases, table, verdict).
    """

    name: str
    effects: tuple[str, ...]
    problem: Problem
    result: GradResult
    summary: dict
    residuals: np.ndarray
    loglik: float
    simulated: np.ndarray
    poses: np.ndarray
    rmse: float
    criticism: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return {"name": self.name, "effects": list(self.effects), "parameters": self.summary["parameters"],
                "loglik": self.loglik, "rmse_m_per_s": self.rmse, "iterations": int(self.result.iterations),
                "converged": bool(self.result.converged), "time_s": float(self.result.time_s),
                "criticism": self.criticism}


@dataclass
class Diagnosis:
    """Result of :func:`diagnose` (JSON-ready through :meth:`as_dict`)."""

    scene: Scene
    observation: Observation
    noise_floor: float
    fits: list[ModelFit]
    rounds: list[dict]
    decision: dict
    timings: dict

    @property
    def final(self) -> ModelFit:
        """The model the diagnosis ends with (base plus the supported effects)."""
        return self.fits[self.decision.get("final_index", 0)]

    def as_dict(self) -> dict:
        return {"scene": self.scene.name, "noise_floor_m_per_s": self.noise_floor,
                "models": [f.as_dict() for f in self.fits], "rounds": self.rounds, "decision": self.decision,
                "timings_s": self.timings}


def profile_rmse(obs: Observation, simulated: np.ndarray) -> float:
    """RMSE (m/s) of observed - simulated velocity over the fit window, all traces together."""
    m = np.asarray(obs.mask, bool)
    d = (np.asarray(obs.profile) - np.asarray(simulated))[:, m]
    return float(np.sqrt(np.mean(d**2)))


def candidate_effects(scene: Scene, names=None, exclude=()) -> tuple[Effect, ...]:
    """Effects to consider for ``scene``: the named ones (default: all registered) that apply to
    the scene and are not already in it or in ``exclude``."""
    pool = resolve_effects(names) if names is not None else tuple(available_effects().values())
    have = {e.name for e in scene_effects(scene)} | set(exclude)
    return tuple(e for e in pool if e.name not in have and not e.applies(scene))


def fit_model(scene: Scene, obs: Observation, effects, settings: DiagnoseSettings, key, *,
              init: np.ndarray | None = None, starts: int | None = None, screen: int | None = None) -> ModelFit:
    """Fit base + ``effects`` by Levenberg-Marquardt and evaluate it (residuals, profiles, criticism)."""
    from galileo_jax import criticism

    effects = resolve_effects(effects)
    problem = Problem(scene, obs, likelihood=settings.likelihood, sd_model=settings.sd_model, effects=effects)
    n_starts = settings.base_starts if starts is None else starts
    n_screen = settings.base_screen if screen is None else screen
    res = fit_grad(problem, key, n_starts=n_starts, n_screen=max(n_screen, n_starts), init=init,
                   max_steps=settings.max_steps)
    # one rollout over the whole video gives the poses, the profile and the residuals (one compile)
    poses = simulated_poses(problem, res.theta)
    simulated = profile_from_positions(poses[..., :2], np.asarray(obs.frame_times, np.float64))
    residuals = np.asarray(problem.likelihood.residuals(jnp.asarray(simulated, jnp.float32)), np.float64)
    name = "base" if not effects else "base + " + " + ".join(e.name for e in effects)
    fit = ModelFit(name, tuple(e.name for e in effects), problem, res, summarize_grad(res, problem.space),
                   residuals, float(res.loglik), simulated, poses, profile_rmse(obs, simulated))
    fit.criticism = criticism.summarize(obs, simulated, poses, settings.sd_model)
    return fit


#: Fractions of a parameter's range at which the screen also evaluates each effect (a one-sided
#: parameter from its neutral bound; a two-sided one on both sides of its neutral value).
SCREEN_GRID = (0.05, 0.15, 0.4)


def screen_candidates(current: ModelFit, candidates, settings: DiagnoseSettings) -> list[dict]:
    """Rank the candidates with parameters at the current fit, in one batched set of rollouts.

    Two statistics per candidate parameter, both predicted gains in 2 log L after re-adjusting
    the current model's parameters to first order (projecting the residual change on the
    orthogonal complement of their Jacobian J):

    * ``score``: the local score test at the neutral value (:func:`score_test`), calibrated
      chi-square(1) but blind to effects that only show when large;
    * ``grid``: |r0|^2 - min_b |r(eta) - J b|^2 at the values of :data:`SCREEN_GRID` across the
      parameter's range (a coarse profile likelihood; large effects are not linear).

    Candidates are ranked by the larger of the two (``statistic``); ``best_value`` is the grid
    value with the largest gain, used to start the refit.

    Returns one dict per candidate parameter, sorted by statistic, largest first.
    """
    with_params = [e for e in candidates if e.params]
    if not with_params:
        return []
    scene, obs = current.problem.scene, current.problem.observation
    current_effects = resolve_effects(current.effects)
    problem = Problem(scene, obs, likelihood=settings.likelihood, sd_model=settings.sd_model,
                      effects=tuple(current_effects) + tuple(with_params))
    space = problem.space
    d0 = current.problem.space.dim
    theta0 = np.concatenate([np.asarray(current.result.theta, np.float64), neutral_values(with_params)])
    lo, hi = np.asarray(space.lower), np.asarray(space.upper)
    points, plan = [theta0], []

    def add(point_values: dict) -> int:
        p = theta0.copy()
        for j, v in point_values.items():
            p[j] = v
        points.append(p)
        return len(points) - 1

    for j in range(d0):  # central differences in the current model's parameters
        h = 0.01 * (hi[j] - lo[j])
        plan.append(("base", j, h, add({j: theta0[j] + h}), add({j: theta0[j] - h})))
    k = d0
    for e in with_params:
        for prm in e.params:
            plus = add({k: prm.neutral + prm.screen_step})
            minus = None if prm.one_sided else add({k: prm.neutral - prm.screen_step})
            grid = []
            for f in SCREEN_GRID:
                if prm.one_sided:
                    vals = [prm.lower + f * (prm.upper - prm.lower)]
                else:
                    vals = [prm.neutral + f * (prm.upper - prm.neutral), prm.neutral - f * (prm.neutral - prm.lower)]
                grid += [(v, add({k: v})) for v in vals]
            plan.append((e.name, prm, plus, minus, grid))
            k += 1
    res = np.asarray(problem.residuals(jnp.asarray(np.stack(points), jnp.float32)), np.float64)
    r0 = res[0]
    jac = np.stack([(res[ip] - res[im]) / (2 * h) for kind, _, h, ip, im in plan if kind == "base"], axis=1)
    cands = [x for x in plan if x[0] != "base"]
    sens, one_sided = [], []
    for name, prm, plus, minus, grid in cands:
        if minus is None:
            sens.append((res[plus] - r0) / prm.screen_step)
        else:
            sens.append((res[plus] - res[minus]) / (2 * prm.screen_step))
        one_sided.append(prm.one_sided)
    score = score_test(r0, jac, np.stack(sens, axis=1), np.asarray(one_sided))
    base_ss = float(np.sum(r0**2))
    rows = []
    for c, (name, prm, plus, minus, grid) in enumerate(cands):
        gains = []
        for v, ip in grid:
            # first-order re-adjustment of the current parameters around r0: r(eta) - J b
            dr = project_out(jac, (res[ip] - r0)[:, None])[:, 0]
            gains.append((base_ss - float(np.sum((r0 + dr) ** 2)), v))
        g_best, v_best = max(gains)
        t = float(score.statistic[c])
        rows.append({"effect": name, "parameter": prm.name, "statistic": max(t, g_best), "score": t,
                     "p_value": float(score.p_value[c]), "step": float(score.step[c]), "grid_gain": g_best,
                     "best_value": float(v_best), "identifiable": bool(score.identifiable[c])})
    return sorted(rows, key=lambda r: -r["statistic"])


def _refit_init(current: ModelFit, effect: Effect, screen_row: dict | None) -> np.ndarray:
    vals = []
    for prm in effect.params:
        span = prm.upper - prm.lower
        v = prm.neutral + prm.screen_step
        if screen_row and screen_row["parameter"] == prm.name:
            local = prm.neutral + screen_row["step"]
            # start from the grid value when the coarse profile beats the local linear step
            v = screen_row["best_value"] if screen_row["grid_gain"] > screen_row["score"] else local
        if prm.one_sided and v <= prm.neutral:
            v = prm.neutral + prm.screen_step
        vals.append(float(np.clip(v, prm.lower + 0.01 * span, prm.upper - 0.01 * span)))
    return np.concatenate([np.asarray(current.result.theta, np.float64), np.asarray(vals)])


def compare(current: ModelFit, alt: ModelFit, effect: Effect) -> dict:
    """Test ``alt`` (= current + effect) against ``current``: LR (boundary-corrected) or Vuong."""
    lr = 2.0 * (alt.loglik - current.loglik)
    if effect.params:
        boundary = len(effect.params) == 1 and effect.params[0].one_sided
        p = lr_pvalue(lr, len(effect.params), boundary)
        test = "likelihood ratio, 0.5 chi2(0) + 0.5 chi2(1)" if boundary else f"likelihood ratio, chi2({len(effect.params)})"
        z = None
    else:
        z, p = vuong_test(alt.residuals, current.residuals)
        test = "Vuong (non-nested)"
    return {"effect": effect.name, "model": alt.name, "lr": float(lr), "delta_loglik": float(alt.loglik - current.loglik),
            "p_value": float(p), "test": test, "vuong_z": z, "rmse_before": current.rmse, "rmse_after": alt.rmse,
            "rmse_drop": float(1.0 - alt.rmse / current.rmse) if current.rmse > 0 else 0.0,
            "parameters": {prm.name: alt.summary["parameters"][prm.name] for prm in effect.params},
            "looks_like_noise": bool(alt.criticism.get("looks_like_noise", False))}


def diagnose(scene: Scene, obs: Observation, settings: DiagnoseSettings = DiagnoseSettings(), *,
             seed: int = 0, progress=None) -> Diagnosis:
    """Run the criticism loop on one observation (module docstring).

    Args:
        scene: the scene.
        obs: the observation (from :func:`galileo_jax.observe.observe` or a simulation).
        settings: :class:`DiagnoseSettings`.
        seed: random seed of the multi-start points.
        progress: optional callable(str) told what is being done.

    Returns:
        :class:`Diagnosis`.

    Raises:
        GalileoError: unknown candidate names; ValueError from the problem setup.
    """
    from galileo_jax import criticism

    say = progress or (lambda msg: None)
    key = jax.random.PRNGKey(seed)
    t0 = time.perf_counter()
    timings = {}
    say("fitting the base model")
    current = fit_model(scene, obs, (), settings, key)
    fits = [current]
    timings["base_fit_s"] = time.perf_counter() - t0
    all_candidates = candidate_effects(scene, settings.candidates)
    m = max(len(all_candidates), 1)
    threshold = settings.alpha / m
    rounds, added, final_index = [], [], 0
    for rnd in range(settings.max_effects):
        candidates = [e for e in all_candidates if e.name not in added]
        if not candidates:
            break
        t = time.perf_counter()
        say(f"screening {len(candidates)} candidate effects")
        screen = screen_candidates(current, candidates, settings)
        order = []
        for row in screen:
            if row["effect"] not in order:
                order.append(row["effect"])
        chosen = order[:settings.refits] + [e.name for e in candidates if e.structural]
        timings[f"round{rnd + 1}_screen_s"] = time.perf_counter() - t
        tests = []
        for i, name in enumerate(chosen):
            effect = available_effects()[name]
            say(f"refitting with {name} ({i + 1}/{len(chosen)})")
            row = next((r for r in screen if r["effect"] == name), None)
            alt = fit_model(scene, obs, tuple(added) + (name,), settings, jax.random.fold_in(key, 100 * rnd + i),
                            init=_refit_init(current, effect, row), starts=settings.refit_starts,
                            screen=settings.refit_screen)
            fits.append(alt)
            test = compare(current, alt, effect)
            test["fit_index"] = len(fits) - 1
            test["supported"] = bool(test["p_value"] < threshold and test["rmse_drop"] >= settings.min_rmse_drop)
            tests.append(test)
        timings[f"round{rnd + 1}_refits_s"] = time.perf_counter() - t
        supported = sorted([x for x in tests if x["supported"]], key=lambda x: -x["delta_loglik"])
        rnd_info = {"round": rnd + 1, "base": current.name, "threshold_p": threshold, "screen": screen,
                    "refits": tests, "winner": None, "indistinguishable": None}
        if not supported:
            rounds.append(rnd_info)
            break
        win = supported[0]
        if len(supported) > 1:
            other = supported[1]
            z, p = vuong_test(fits[win["fit_index"]].residuals, fits[other["fit_index"]].residuals)
            if p > settings.indistinct_p:
                ea, eb = available_effects()[win["effect"]], available_effects()[other["effect"]]
                rnd_info["indistinguishable"] = {
                    "effects": [win["effect"], other["effect"]], "vuong_z": z, "p_value": p,
                    "message": (f"{win['effect']} and {other['effect']} explain this video about equally well "
                                f"(Delta log L = {win['delta_loglik'] - other['delta_loglik']:.1f}, Vuong p = {p:.2f}); "
                                f"to separate them measure {ea.evidence} ({ea.name}) and {eb.evidence} ({eb.name})")}
        rnd_info["winner"] = win["effect"]
        rounds.append(rnd_info)
        added.append(win["effect"])
        current = fits[win["fit_index"]]
        final_index = win["fit_index"]
    timings["total_s"] = time.perf_counter() - t0
    floor = criticism.noise_floor(obs)
    decision = _decision(fits, rounds, added, final_index, floor, threshold)
    return Diagnosis(scene, obs, floor, fits, rounds, decision, timings)


def _decision(fits, rounds, added, final_index, floor, threshold) -> dict:
    base, final = fits[0], fits[final_index]
    if not added:
        best = None
        if rounds and rounds[0]["refits"]:
            best = min(rounds[0]["refits"], key=lambda x: x["p_value"])
        why = (f" (best candidate {best['effect']}: p = {best['p_value']:.2g} vs threshold {threshold:.2g}, "
               f"RMSE drop {100 * best['rmse_drop']:.0f}%)") if best else ""
        message = "No missing effect: no candidate improves the fit beyond chance" + why + "."
    else:
        message = (f"Missing effect: {' then '.join(added)}. RMSE {base.rmse:.3f} -> {final.rmse:.3f} m/s "
                   f"({base.rmse / max(final.rmse, 1e-12):.1f}x lower; noise floor {floor:.3f} m/s).")
    indist = [r["indistinguishable"]["message"] for r in rounds if r.get("indistinguishable")]
    return {"missing_effects": added, "final_model": final.name, "final_index": final_index,
            "message": message, "indistinguishable": indist,
            "rmse_base": base.rmse, "rmse_final": final.rmse, "noise_floor": floor,
            "rmse_ratio_to_floor": final.rmse / floor if floor > 0 else None,
            "verdict_base": base.criticism.get("verdict"), "verdict_final": final.criticism.get("verdict"),
            "residuals_look_like_noise": bool(final.criticism.get("looks_like_noise", False))}
