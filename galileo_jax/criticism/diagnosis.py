"""Which physics is the model missing? Fit, criticise, screen candidate effects, refit, decide.

:func:`diagnose` runs the model-criticism loop on one video's observation, or on
several videos of one setup at once (shared parameters, :mod:`galileo_jax.inference.joint`):

1. **Base fit**: the scene's model (the sliding block plus the scene's own effects) by
   Levenberg-Marquardt (:func:`~galileo_jax.inference.grad.fit_grad`), with the camera's
   scale error as a calibration nuisance (``DiagnoseSettings.scale_tolerance``). A base fit
   that fails step 3 is fitted once more from twice the starts (``base_retry``), and if it
   still fails, searched by CMA-ES from its best point, before anything is blamed on missing
   physics.
2. **Criticism**: residuals per motion phase and trace with tests for structure
   (:mod:`galileo_jax.criticism.residuals`) and a one-line verdict.
3. **Adequate?** A model whose RMSE away from contact events (samples more than one frame
   from a velocity jump of :data:`~galileo_jax.criticism.nested.GATE_JUMP` or more, :func:`~galileo_jax.criticism.nested.calm_rmse`) is within
   ``adequate_ratio`` (1.3) of the tracker's noise floor leaves nothing for an effect to
   explain: the answer is "no missing effect" and no refit runs. Contact events are left out
   because there the simulator itself is inexact (next paragraph and
   :func:`~galileo_jax.likelihood.event_sd`); an effect that acts at an impact (restitution)
   still shows in every later sample. Over all samples the RMSE must still be within
   ``adequate_ratio_all`` (1.6) of the floor: an effect that shows mostly around an event (a
   ramp friction, at the ramp's foot) is not waved through. (Measured on rendered videos
   without a hidden effect: the base RMSE was 0.4-1.3x the floor, except where the fitting
   simulator (MJX) and the renderer (C MuJoCo) disagree, e.g. around a second collision: 2.3x.)
4. **Screen**: for every candidate effect with a parameter, the score statistic of
   :func:`~galileo_jax.inference.screen.score_test` (the residual projected on the effect's
   sensitivity after projecting out the current parameters) and a coarse profile over the
   parameter's range with the same first-order re-adjustment (:func:`~galileo_jax.criticism.screening.screen_candidates`):
   one batched set of rollouts. It orders the refits and is reported; it decides nothing,
   except (4b) when nothing points at an effect: a model within ``quiet_max_ratio`` (2.5) of
   the floor whose residuals look like noise, every score
   test at p > ``quiet_p`` and every profile gain < ``quiet_gain`` nats (:func:`~galileo_jax.criticism.nested.quiet`) end
   the diagnosis with "no missing effect" and no refit.
5. **Refit** the ``refits`` best-scoring candidates (by default all of them) and every
   structural effect, which the screen cannot rank, from the current estimate plus the
   screen's step (and a few screened starts), then a CMA-ES search from LM's end and LM again
   from its best point (``refit_search``; :mod:`~galileo_jax.inference.search`: the cost is
   rough, and LM alone stops far along the valley where an effect trades off against
   friction; an effect whose cost has several basins, restitution at impacts, gets
   ``Effect.search_restarts`` searches, from LM's end and from a global screen's fit). The
   current model is then refitted once (LM and search) from the best refit's estimate with
   the effect held neutral (:func:`~galileo_jax.criticism.nested.refit_null`): a likelihood-ratio test needs the null at
   its maximum, and a base fit stuck in a worse optimum makes every effect look needed. If
   that finds a better optimum, the alternatives of that union are refitted from it
   (:func:`~galileo_jax.criticism.nested.refit_from_null`: LM, the null's point with the effect neutral among its starts)
   and the tests are redone against it, and the adequacy check of step 3 is applied again:
   an improved current model that now passes it ends the diagnosis with "no missing effect",
   unless a supported effect's fit has an RMSE at least ``min_rmse_drop`` below the improved
   model's (:func:`~galileo_jax.criticism.nested.clear_gain`; measured: a hidden linear drag in a foreign render, RMSE
   0.0080 -> 0.0052 m/s, was waved through by the adequacy check alone, while on our own
   render without an effect the supported effects' RMSEs were 5-6% above the improved model's),
   and unless the improved model already fits within the noise floor over all samples.
   Every refit starts, among other points, at the null's estimate with the effect neutral, and
   a refit that still ends below the null is tested at that point (:func:`~galileo_jax.criticism.nested.nested_floor`), so
   no likelihood-ratio statistic is negative.
6. **Decide**: an effect is *supported* when its likelihood-ratio test against the current
   model, on the residuals of the *test likelihood* (below), with each trace's noise scale
   estimated from the alternative's residuals (:func:`~galileo_jax.inference.screen.scaled_lr`,
   boundary-corrected; Vuong's test for structural effects) has p below ``alpha / m``, m the
   number of candidates considered (Bonferroni over everything screened, because the screen
   picks the refits from the same data), AND the fit's RMSE falls by at least
   ``min_rmse_drop`` (10%), AND the fitted value lies outside the effect's region of practical
   equivalence where it declares one (:func:`~galileo_jax.criticism.nested.negligible`; a
   restitution below 0.05 rebounds no more than the base contact: a refit at 0.008 on a foreign
   render without an effect lowered the RMSE 10% by softening the contact). The winner is the
   supported effect whose fit has the largest
   log-likelihood, and among those within 1 nat of it the one with the lowest test RMSE
   (:func:`~galileo_jax.criticism.nested.rank_supported`: the fit likelihood's 0.05 m/s
   model-error floor hardly separates fits far below it; the scaled LR tests each effect
   against the base, but as a ranking between effects it is erratic: on a hidden linear drag,
   LR 2098 for velocity friction and 588 for linear drag at the same RMSE, 0.0062 m/s);
   every other supported effect that :func:`~galileo_jax.criticism.nested.indistinguishable` cannot tell from it (Vuong's
   test p > 0.05, or an RMSE within 10% of the winner's) is reported with it: the video cannot
   separate them, and the report says so, naming the measurement that would separate them
   (each effect's ``evidence``). Without a supported effect the answer is "no missing effect".
   The named effect's fit then gets a second, narrower search (:func:`~galileo_jax.criticism.models.polish`,
   ``winner_search``): it can only improve the reported fit, not change the choice.

One problem for many models. The candidate effects with parameters of one engine (below) are
simulated in ONE problem (a "union"); a model is that problem with the effects it does not
contain held at their neutral values (:class:`~galileo_jax.inference.fixed.FixedProblem`),
which give back the base model exactly. The screen and the refits in a union therefore share
one simulator, and all its refits of one round one compiled Levenberg-Marquardt program; the
observation is an argument of those programs, so the next video of the scene compiles nothing.
Structural effects (no parameter, e.g. ``rolling``) change the model's structure and get a
union of their own.

Engines. Every model runs on the engine ``fit`` would use for it (``settings.engine``, default
"auto": :func:`~galileo_jax.criticism.models.model_engine`): the base model, and the effects that act only through
model fields, the release velocity or the model's structure (restitution, initial push,
rolling), run on C MuJoCo; the effects that act every physics step (drags, velocity-dependent
friction, a user's force law) on MJX, which the open-loop C rollout cannot do (on a GPU too).
So the diagnosis's base model is the one ``fit`` reports, and models are only ever
compared within one engine where the comparison is nested: the base fit (C) is refitted on MJX
once, by LM from its estimate, before the MJX effects are screened and refitted against it, and
the null refit of step 5 is done per union. (The two engines agree to 1e-5 m/s while objects
slide, but not at bouncy impacts: on two of five rendered restitution videos the MJX simulation
at the true parameters misfit the C-rendered video by 2.3x and 4.5x the noise floor, C MuJoCo
by 0.4x and 1.0x.) Effects are ranked across engines by their log-likelihood gain over the
current model on their own engine; a structural effect is compared with the current model by
Vuong's test, which needs no nesting. On C MuJoCo, where a rollout costs about a tenth of an
MJX one, the CMA-ES searches are larger (``search_popsize_c``, ``search_generations_c``).

The test likelihood. ``fit``'s likelihood adds a 0.05 m/s model-error floor to the tracking
noise (robust and smooth for fitting, :mod:`galileo_jax.likelihood`); every model here is
FITTED in it. Tested in it, effects smaller than the floor are invisible: a hidden ramp
friction that moved the profile by 0.005 m/s RMS changed log L by 1 nat. The tests need the
real noise, but the simulator is not equally good everywhere: measured on rendered videos (C
MuJoCo renderer vs the MJX fit at the true parameters), 0.001-0.002 m/s between contact events
and 0.02-0.1 m/s within a sample or two of an impact or the ramp's foot. So the tests
standardise the residuals with the tracking noise, a small floor ``sd_test`` (0.002 m/s) and
up to 0.05 m/s more around contact events (:func:`~galileo_jax.likelihood.event_sd`, found
once in the base fit's simulated profile and the observed one, then fixed for every model),
and, because the tracker's noise estimate itself can be off several times (measured: 1.5-4x
too large on rendered video), each trace's noise scale is re-estimated from the residuals of
the model being tested (:func:`~galileo_jax.inference.screen.scaled_lr`).

Why this criterion (and not cross-validation or an information criterion): the question is a
test ("is the base model enough?") with a controlled false-alarm rate, and LR tests are the
most powerful for nested effects; the per-trace noise scale taken from the alternative's
residuals (an F-type test) keeps it calibrated when the tracker's noise estimate is off, and
the RMSE guard keeps a significant but negligible improvement from being called a missing effect.
The false-alarm rate is measured on rendered videos without a hidden effect
(``benchmarks/diagnose_calibration.py``).

With ``max_effects > 1`` the loop (steps 3-6) repeats with the winner added, so a report can show the
error falling step by step. Everything here is orchestration; the physics and statistics live
in :mod:`galileo_jax.effects`, :mod:`galileo_jax.inference` and :mod:`galileo_jax.criticism.residuals`.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from dataclasses import dataclass

import jax
import numpy as np

from galileo_jax.criticism.alternatives import angle_alternative
from galileo_jax.criticism.models import (
    Round,
    CALIBRATION_NUISANCES,
    ENGINE_NAMES,
    ModelFit,
    Union,
    Workspace,
    base_name,
    candidate_effects,
    evaluate,
    fit_model,
    model_engine,
    polish,
    pooled_rms,
    with_calibration_nuisances,
)
from galileo_jax.criticism.nested import (
    adequate,
    adequate_round,
    calm_masks,
    calm_rmse,
    clear_gain,
    event_sds,
    indistinguishable,
    quiet,
    rank_supported,
    refit_from_null,
    refit_null,
    test_effect,
)
from galileo_jax.criticism.noise import noise_floor
from galileo_jax.criticism.screening import refit_init, screen_candidates
from galileo_jax.criticism.settings import DiagnoseSettings
from galileo_jax.effects import Effect, available_effects, resolve_effects
from galileo_jax.observation import Observation
from galileo_jax.physics.simulate import scene_effects
from galileo_jax.physics.simulate_c import check_supported
from galileo_jax.scene import Scene

__all__ = ["DiagnoseSettings", "Diagnosis", "ModelFit", "diagnose"]


@dataclass
class Diagnosis:
    """Result of :func:`diagnose` (JSON-ready through :meth:`as_dict`).

    Attributes:
        scenes, observations: per video.
        noise_floor: RMSE (m/s) a perfect model would reach on all videos together.
        fits: every fitted model, the base first.
        rounds: per round (:class:`~galileo_jax.criticism.models.Round`) the screen, the refits with
            their tests, the winner.
        decision: the answer (:func:`_decision`).
        timings: seconds per stage.
    """

    scenes: list[Scene]
    observations: list[Observation]
    noise_floor: float
    fits: list[ModelFit]
    rounds: list[Round]
    decision: dict
    timings: dict

    @property
    def scene(self) -> Scene:
        return self.scenes[0]

    @property
    def observation(self) -> Observation:
        return self.observations[0]

    @property
    def final(self) -> ModelFit:
        """The model the diagnosis ends with (base plus the supported effects)."""
        return self.fits[self.decision.get("final_index", 0)]

    def calibration(self) -> dict:
        """The calibration nuisances (``scale_error``, per video in a joint fit) of the base and
        the final model: {"base": {name: summary}, "final": {...}}, each summary with ``best``,
        ``interval90`` and the ``tolerance`` it was allowed (empty where none was fitted)."""
        tol = {f"scale_error@{j + 1}": s.camera.scale_tolerance for j, s in enumerate(self.scenes)}
        tol["scale_error"] = self.scenes[0].camera.scale_tolerance
        out = {}
        for label, fit in (("base", self.fits[0]), ("final", self.final)):
            out[label] = {n: {"best": v.get("best"), "interval90": v.get("interval90"), "tolerance": tol.get(n)}
                          for n, v in fit.summary["parameters"].items() if base_name(n) in CALIBRATION_NUISANCES}
        return out

    def as_dict(self) -> dict:
        return {"scenes": [s.name for s in self.scenes], "noise_floor_m_per_s": self.noise_floor,
                "models": [f.as_dict() for f in self.fits], "rounds": [r.as_dict() for r in self.rounds], "decision": self.decision,
                "calibration": self.calibration(), "timings_s": self.timings}


def diagnose(scene: Scene | Sequence[Scene], obs: Observation | Sequence[Observation],
             settings: DiagnoseSettings = DiagnoseSettings(), *, seed: int = 0, progress=None) -> Diagnosis:
    """Run the criticism loop on one observation, or on several videos of one setup (module docstring).

    Args:
        scene: the scene, or one scene per video.
        obs: the observation (from :func:`galileo_jax.observe.observe` or a simulation), or a
            list of them: a joint diagnosis (parameters shared by name, ``v0`` and
            ``settings.per_video`` per video).
        settings: :class:`~galileo_jax.criticism.settings.DiagnoseSettings`.
        seed: random seed of the multi-start points.
        progress: optional callable(str) told what is being done.

    Returns:
        :class:`Diagnosis`.

    Raises:
        GalileoError: unknown candidate names or engine; ValueError from the problem setup or a
            mismatch between the numbers of scenes and observations.
    """
    observations = [obs] if isinstance(obs, Observation) else list(obs)
    scenes = [scene] * len(observations) if isinstance(scene, Scene) else list(scene)
    if len(scenes) != len(observations) or not observations:
        raise ValueError(f"need one scene per video: got {len(scenes)} scenes and {len(observations)} observations")
    scenes = [with_calibration_nuisances(s, settings) for s in scenes]
    say = progress or (lambda msg: None)
    key = jax.random.PRNGKey(seed)
    t0 = time.perf_counter()
    timings = {}
    per_scene = [candidate_effects(s, settings.candidates) for s in scenes]
    all_candidates = tuple(e for e in per_scene[0] if all(e in c for c in per_scene[1:]))
    if settings.engine == "mujoco":  # say so before any fit, not after the base fit
        check_supported([e for s in scenes for e in scene_effects(s, all_candidates)])
    ws = Workspace(scenes, observations, settings)
    base_engine = model_engine(scenes, (), settings)
    say(f"fitting the base model ({ENGINE_NAMES[base_engine]})")
    union = ws.union(base_engine, [e for e in all_candidates
                                   if e.params and model_engine(scenes, (e,), settings) == base_engine])
    current = fit_model(union, (), settings, key)
    if settings.events:  # the test likelihood's event SDs come from the base fit (module docstring)
        ws.set_events(event_sds(current, observations))
        current = evaluate(union, current.result, (), settings)
    masks = calm_masks(current, observations)
    n_used = [int(np.sum(o.mask)) * 2 * o.n_objects for o in observations]
    floor = pooled_rms([noise_floor(o) for o in observations], n_used)
    if settings.base_retry and not adequate(current, calm_rmse(current, observations, masks)[0], floor, settings):
        # before any effect is screened, make sure the base model is not merely stuck (step 3)
        say("the base model misfits: fitting it again from more starts")
        again = fit_model(union, (), settings, jax.random.fold_in(key, 1), starts=2 * settings.base_starts,
                          screen=2 * settings.base_screen)
        if again.loglik > current.loglik:
            current = again
            masks = calm_masks(current, observations)
        if not adequate(current, calm_rmse(current, observations, masks)[0], floor, settings):
            # more LM starts end in the same ripples: search from the best point (base_retry)
            say("the base model still misfits: searching from its best fit (CMA-ES)")
            searched = fit_model(union, (), settings, jax.random.fold_in(key, 2), init=np.asarray(current.result.theta),
                                 starts=0)
            if searched.loglik > current.loglik:
                current = searched
                masks = calm_masks(current, observations)
    fits = [current]
    timings["base_fit_s"] = time.perf_counter() - t0
    m = max(len(all_candidates), 1)
    threshold = settings.alpha / m
    rounds, added, final_index = [], [], 0
    for rnd in range(settings.max_effects):
        candidates = [e for e in all_candidates if e.name not in added]
        if not candidates:
            break
        t = time.perf_counter()
        rnd_info = Round(round=rnd + 1, base=current.name, threshold_p=threshold)
        done = adequate_round(rnd_info, current, observations, masks, floor, settings)
        if done is not None:  # nothing left to explain; the screen is reported where it costs no refit
            say("screening the candidate effects")
            own = {e.name for e in current.union.effects}
            done.screen = screen_candidates(current.union, current, [
                e for e in candidates if e.params and e.name in own
                and model_engine(scenes, tuple(added) + (e.name,), settings) == current.union.engine], settings)
            timings[f"round{rnd + 1}_screen_s"] = time.perf_counter() - t
            rounds.append(done)
            break
        home = candidate_unions(ws, scenes, candidates, added, settings)
        rnd_info.engines = {n: u.engine for n, u in home.items()}
        # the current model in every union with parametric candidates (refitted there, from its
        # estimate, when it lives in another: another engine, or without these effects)
        currents = {id(current.union): current}

        def current_in(u: Union) -> ModelFit:
            if id(u) not in currents:
                say(f"refitting the {current.name} model on {ENGINE_NAMES[u.engine]}")
                fit = fit_model(u, tuple(added), settings, jax.random.fold_in(key, 100 * rnd + 50 + len(currents)),
                                init=u.theta_from(current.union, np.asarray(current.result.theta)), starts=0,
                                search=False)
                currents[id(u)] = fit
                rnd_info.transfers.append({"model": current.name, "engine": u.engine, "loglik": fit.loglik,
                                              "rmse": fit.rmse, "from_engine": current.union.engine,
                                              "rmse_before": current.rmse})
            return currents[id(u)]

        params_by_union: dict[int, tuple[Union, list[Effect]]] = {}
        for e in candidates:
            if e.params:
                params_by_union.setdefault(id(home[e.name]), (home[e.name], []))[1].append(e)
        say(f"screening {len(candidates)} candidate effects")
        screen = []
        for u, group in params_by_union.values():
            screen += screen_candidates(u, current_in(u), group, settings)
        screen.sort(key=lambda r: -r["statistic"])
        rnd_info.screen = screen
        order = list(dict.fromkeys(row["effect"] for row in screen))
        chosen = order[:settings.refits] + [e.name for e in candidates if e.structural]
        timings[f"round{rnd + 1}_screen_s"] = time.perf_counter() - t
        if quiet(current, screen, candidates, settings, floor):  # step 4b: nothing points at an effect
            rnd_info.quiet = True
            rounds.append(rnd_info)
            break

        def base_of(effect: Effect) -> ModelFit:  # what an effect is tested against
            return currents[id(home[effect.name])] if effect.params else current

        tests = []
        for i, name in enumerate(chosen):
            effect = available_effects()[name]
            u = home[name]
            say(f"refitting with {name} ({i + 1}/{len(chosen)}, {ENGINE_NAMES[u.engine]})")
            t_refit = time.perf_counter()
            k = jax.random.fold_in(key, 100 * rnd + i)
            init = refit_init(u, base_of(effect), effect, screen) if effect.params else None
            fits.append(fit_model(u, tuple(added) + (name,), settings, k, init=init,
                                  starts=settings.refit_starts if init is not None else settings.base_starts,
                                  screen=settings.refit_screen))
            tests.append(test_effect(base_of(effect), effect, fits, len(fits) - 1, threshold, settings))
            timings[f"round{rnd + 1}_refit_{name}_s"] = time.perf_counter() - t_refit
        timings[f"round{rnd + 1}_refits_s"] = time.perf_counter() - t
        t = time.perf_counter()
        improved = {}  # id(union) -> its null_refit record
        for u, _ in params_by_union.values():  # each union's null at its maximum (refit_null)
            better = refit_null(u, currents[id(u)], tests, fits, added, settings,
                                jax.random.fold_in(key, 100 * rnd + 99 + len(rnd_info.null_refit)))
            if better is None:
                continue
            old = currents[id(u)]
            improved[id(u)] = {"from_effect": better[1], "engine": u.engine, "model": old.name,
                               "loglik_before": old.loglik, "loglik_after": better[0].loglik,
                               "rmse_before": old.rmse, "rmse_after": better[0].rmse, "alternatives_improved": []}
            rnd_info.null_refit.append(improved[id(u)])
            say(f"the {old.name} model ({ENGINE_NAMES[u.engine]}) improved from {better[1]}'s estimate (log L "
                f"{old.loglik:.1f} -> {better[0].loglik:.1f}); re-testing")
            currents[id(u)] = better[0]
            if u is current.union:  # the reported current model itself
                current = fits[final_index] = better[0]
        if improved:  # the tests so far were against a null stuck in a worse optimum: refit from it, redo them
            for j, x in enumerate(tests):
                effect = available_effects()[x.effect]
                u = fits[x.fit_index].union
                if not effect.params or id(u) not in improved:
                    continue
                say(f"refitting with {effect.name} from the improved {current.name} model")
                if refit_from_null(u, currents[id(u)], effect, fits, x.fit_index, screen, added, settings,
                                   jax.random.fold_in(key, 100 * rnd + 60 + j)):
                    improved[id(u)]["alternatives_improved"].append(effect.name)
            tests = [test_effect(base_of(available_effects()[x.effect]), available_effects()[x.effect], fits,
                                 x.fit_index, threshold, settings) for x in tests]
        timings[f"round{rnd + 1}_null_refits_s"] = time.perf_counter() - t
        if improved:
            done = adequate_round(dataclasses.replace(rnd_info, refits=tests), current, observations, masks, floor, settings)
            if done is not None and not clear_gain(tests, current, settings, floor):
                rounds.append(done)
                break
        supported = rank_supported(tests)
        rnd_info.refits = tests
        if not supported:
            rounds.append(rnd_info)
            break
        win = supported[0]
        tied = [x for x in supported[1:] if indistinguishable(win, x, fits, current.union, settings)]
        if tied:
            names = [win.effect] + [x.effect for x in tied]
            how = ", ".join(f"{available_effects()[n].evidence} ({n})" for n in names)
            rmses = " / ".join("%.4f" % x.rmse_after for x in [win] + tied)
            rnd_info.indistinguishable = {
                "effects": names, "vuong_p": [x.vuong_p_vs_winner for x in tied],
                "message": (f"{' and '.join(names)} explain this video about equally well (RMSE {rmses} m/s); "
                            f"to separate them measure {how}")}
        rnd_info.winner = win.effect
        rounds.append(rnd_info)
        added.append(win.effect)
        say(f"polishing the fit with {win.effect}")
        fits[win.fit_index] = polish(fits[win.fit_index], settings, jax.random.fold_in(key, 100 * rnd + 98))
        current = fits[win.fit_index]
        final_index = win.fit_index
    timings["total_s"] = time.perf_counter() - t0
    decision = _decision(fits, rounds, added, final_index, floor, threshold, settings.adequate_ratio,
                         settings.min_rmse_drop)
    if decision["unexplained_misfit"] and any(sc.ramp.thickness == 0 for sc in scenes):
        # the one misfit we know real setups have and no candidate describes: a board's edge
        decision["message"] += (" If the ramp is a board lying on the floor, the step at its foot is such a thing: "
                                "state the board's thickness (ramp.thickness in the scene file) and run again.")
    angle = angle_alternative(fits[final_index], scenes[0], settings.angle_tolerance_deg) if added else None
    decision["calibration_alternatives"] = [angle] if angle else []
    return Diagnosis(scenes, observations, floor, fits, rounds, decision, timings)


def base_loglik_by_engine(diag: "Diagnosis") -> dict[str, float]:
    """{engine: log-likelihood (nats) of the base model on that engine}: the base fit on its own
    engine; on another, the base model refitted there in the first round (after its null refit,
    when that improved it). Log-likelihoods of one model on two engines differ (the engines
    differ at impacts), so a model's gain is read against the base on its own engine."""
    base = diag.fits[0]
    out = {base.union.engine: float(base.loglik)}
    first = diag.rounds[0] if diag.rounds else None
    for tr in first.transfers if first else []:
        if tr["model"] == base.name:
            out.setdefault(tr["engine"], float(tr["loglik"]))
    for nr in first.null_refit if first else []:
        if nr["model"] == base.name and nr["engine"] != base.union.engine:
            out[nr["engine"]] = float(nr["loglik_after"])
    return out


def candidate_unions(ws: Workspace, scenes, candidates, added, settings: DiagnoseSettings) -> dict[str, Union]:
    """{candidate name: the union it is refitted in}: the candidates with parameters grouped by
    the engine of current + candidate (:func:`~galileo_jax.criticism.models.model_engine`), one union per group holding the
    current model's effects and the group; a structural candidate in a union of its own."""
    have = tuple(resolve_effects(added))
    groups: dict[str, list[Effect]] = {}
    home: dict[str, Union] = {}
    for e in candidates:
        engine = model_engine(scenes, have + (e,), settings)
        if e.params:
            groups.setdefault(engine, []).append(e)
        else:
            home[e.name] = ws.union(engine, have + (e,))
    for engine, group in groups.items():
        u = ws.union(engine, have + tuple(group))
        home.update({e.name: u for e in group})
    return home


def _decision(fits, rounds, added, final_index, floor, threshold, adequate_ratio, min_rmse_drop=0.10) -> dict:
    base, final = fits[0], fits[final_index]
    unexplained = False
    if not added and rounds and rounds[-1].adequate:
        r = rounds[-1]
        message = (f"No missing effect: away from contact events the model already fits to within {adequate_ratio:g}x "
                   f"of the noise floor (RMSE {r.calm_rmse:.4f} m/s on {100 * r.calm_fraction:.0f}% of the "
                   f"samples; {base.rmse:.4f} m/s on all, {base.rmse / floor:.1f}x; floor {floor:.4f} m/s); there is "
                   "nothing left for an effect to explain.")
    elif not added and rounds and rounds[-1].quiet:
        screen = rounds[-1].screen
        message = (f"No missing effect: the residuals look like noise ({base.rmse / floor:.1f}x the noise floor, RMSE "
                   f"{base.rmse:.4f} m/s) and no candidate's screen points at an effect (smallest p = "
                   f"{min(r['p_value'] for r in screen):.2g}, largest profile gain "
                   f"{max(r['grid_gain'] for r in screen):.1f} nats); no refit was needed.")
    elif not added:
        best = None
        if rounds and rounds[0].refits:
            # a refit that passed both tests and was turned down for its negligible size is what to explain
            rope = [x for x in rounds[0].refits if x.negligible]
            best = min(rope or rounds[0].refits, key=lambda x: x.p_value)
        passed = best is not None and best.p_value <= threshold
        if passed and best.negligible:  # a gain through a negligible value (negligible implies both tests passed)
            values = ", ".join(f"{n} {v.get('best'):.3g}" for n, v in best.parameters.items()
                               if v.get("best") is not None)
            rope = ", ".join(f"{q.name} within {q.negligible:g} of {q.neutral:g}"
                             for q in available_effects()[best.effect].params)
            why = (f" (best candidate {best.effect}: p = {best.p_value:.2g} passes its test and lowers the RMSE by "
                   f"{100 * best.rmse_drop:.0f}%, but at {values}, inside its region of practical equivalence "
                   f"({rope}), where the effect does not act measurably: the fit improved through something "
                   "else the parameter also changes)")
        elif passed:  # a significant but small gain: chance is not what rules it out
            why = (f" (best candidate {best.effect}: p = {best.p_value:.2g} passes its test (threshold "
                   f"{threshold:.2g}) but lowers the RMSE by only {100 * best.rmse_drop:.0f}%, under the "
                   f"{100 * min_rmse_drop:.0f}% that counts)")
        elif best is not None:
            why = (f" (best candidate {best.effect}: p = {best.p_value:.2g} vs threshold {threshold:.2g}, "
                   f"RMSE drop {100 * best.rmse_drop:.0f}%)")
        else:
            why = ""
        ratio = base.rmse / floor if floor > 0 else float("nan")
        # the model misfits (beyond the adequacy bound, with residuals its criticism finds
        # structured), and no candidate says why: say both. Residuals that look like noise at a
        # ratio above the bound are the simulator's own roughness at contact events, not a misfit.
        unexplained = bool(ratio > adequate_ratio) and not base.criticism.get("looks_like_noise", False)
        if unexplained:
            message = (f"No candidate effect explains the misfit: the model misfits at {ratio:.1f}x the noise floor "
                       f"(RMSE {base.rmse:.4f} m/s, floor {floor:.4f} m/s), and no candidate both passes its test and "
                       f"lowers the RMSE by {100 * min_rmse_drop:.0f}%{why}. Something none of the candidates "
                       "describes is missing (or a calibration error beyond its tolerance): see where the residuals "
                       "sit (residuals_base.png).")
        else:
            noise = (f"; the residuals look like noise at {ratio:.1f}x the noise floor (no structure the residual "
                     "tests find: the simulator's own variability at contact events, or a difference spread over "
                     "the whole video that none of the candidates describes)" if ratio > adequate_ratio else "")
            message = ("No missing effect: no candidate improves the fit "
                       + ("by enough to count" if passed else "beyond chance") + why + noise + ".")
    else:
        message = (f"Missing effect: {' then '.join(added)}. RMSE {base.rmse:.3f} -> {final.rmse:.3f} m/s "
                   f"({base.rmse / max(final.rmse, 1e-12):.1f}x lower; noise floor {floor:.3f} m/s).")
    indist = [r.indistinguishable["message"] for r in rounds if r.indistinguishable]
    return {"missing_effects": added, "final_model": final.name, "final_index": final_index,
            "message": message, "unexplained_misfit": unexplained, "indistinguishable": indist,
            "rmse_base": base.rmse, "rmse_final": final.rmse, "noise_floor": floor,
            "rmse_ratio_to_floor": final.rmse / floor if floor > 0 else None, "adequate_ratio": adequate_ratio,
            "verdict_base": base.criticism.get("verdict"), "verdict_final": final.criticism.get("verdict"),
            "residuals_look_like_noise": bool(final.criticism.get("looks_like_noise", False))}
