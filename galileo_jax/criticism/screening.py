"""Step 4 of :func:`~galileo_jax.criticism.diagnosis.diagnose`: rank the candidate effects at the
current fit in one batched set of rollouts (:func:`screen_candidates`), and start each refit
where the screen points (:func:`refit_init`).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from galileo_jax.criticism.models import ModelFit, Union, base_name
from galileo_jax.criticism.settings import DiagnoseSettings
from galileo_jax.effects import Effect
from galileo_jax.inference.screen import score_test

#: Fractions of a parameter's range at which the screen also evaluates each effect (a one-sided
#: parameter from its neutral bound; a two-sided one on both sides of its neutral value).
SCREEN_GRID = (0.05, 0.15, 0.4)



def finite_difference(res: np.ndarray, plus: int, minus: int | None, h: float) -> np.ndarray:
    """Derivative (n,) of the residual rows ``res`` (P, n) in one coordinate, from row 0 (the
    current fit) and the rows ``plus`` (coordinate + h) and ``minus`` (- h, or None).

    Central where both are finite, one-sided where only one is (a rollout can blow up at a
    screen point, e.g. a stiff contact), zero (no information) where neither is."""
    ok = np.all(np.isfinite(res[[plus] + ([] if minus is None else [minus])]), axis=1)
    if minus is not None and ok.all():
        return (res[plus] - res[minus]) / (2 * h)
    if ok[0]:
        return (res[plus] - res[0]) / h
    if minus is not None and ok[1]:
        return (res[0] - res[minus]) / h
    return np.zeros_like(res[0])



def screen_candidates(union: Union, current: ModelFit, candidates, settings: DiagnoseSettings) -> list[dict]:
    """Rank the candidates with parameters at the current fit, in one batched set of rollouts.

    Two statistics per candidate coordinate, both predicted gains in 2 log L after re-adjusting
    the current model's parameters to first order (projecting the residual change on the
    orthogonal complement of their Jacobian J):

    * ``score``: the local score test at the neutral value (:func:`score_test`), calibrated
      chi-square(1) but blind to effects that only show when large;
    * ``grid``: |r0|^2 - min_b |r(eta) - J b|^2 at the values of :data:`SCREEN_GRID` across the
      parameter's range (a coarse profile likelihood; large effects are not linear); for a
      parameter with a ``ridge`` (:class:`~galileo_jax.effects.EffectParam`) also at the same
      values with the ridge's base parameters moved along (a re-adjustment too large for the
      first-order one: e.g. a slicker ramp keeps the ramp's friction k1 + dk_ramp and changes
      the floor's), the move included in ``adjust_grid``.

    Candidates are ranked by the larger of the two (``statistic``); ``best_value`` is the grid
    value with the largest gain, used to start the refit. Screen points whose rollout is not
    finite are left out (:func:`finite_difference`; grid values skipped).

    Returns one dict per candidate coordinate, sorted by statistic, largest first.
    """
    problem = union.problem
    names = problem.names
    lo, hi = np.asarray(problem.space.lower), np.asarray(problem.space.upper)
    theta0 = np.asarray(current.result.theta, np.float64)
    held = set(current.result.fixed)
    free_now = [j for j, n in enumerate(names) if n not in held]
    points, plan = [theta0], []

    def add(point_values: dict) -> int:
        p = theta0.copy()
        for j, v in point_values.items():
            p[j] = v
        points.append(p)
        return len(points) - 1

    for j in free_now:  # central differences in the current model's parameters
        h = 0.01 * (hi[j] - lo[j])
        plan.append(("current", j, h, add({j: theta0[j] + h}), add({j: theta0[j] - h}), None))
    by_name = {p.name: p for e in candidates for p in e.params}
    for e in candidates:
        for j in union.coords.get(e.name, []):
            prm = by_name[base_name(names[j])]
            plus = add({j: prm.neutral + prm.screen_step})
            minus = None if prm.one_sided else add({j: prm.neutral - prm.screen_step})
            # (index, position among the current model's free parameters, coefficient) of each
            # free base parameter on the ridge
            ridge = [(names.index(n), free_now.index(names.index(n)), c) for n, c in prm.ridge
                     if n in names and names.index(n) in free_now]
            grid = []
            for f in SCREEN_GRID:
                if prm.one_sided:
                    vals = [prm.lower + f * (prm.upper - prm.lower)]
                else:
                    vals = [prm.neutral + f * (prm.upper - prm.neutral), prm.neutral - f * (prm.neutral - prm.lower)]
                grid += [(v, add({j: v}), np.zeros(len(free_now))) for v in vals]
                if not ridge:
                    continue
                for v in vals:  # the same values along the ridge (EffectParam.ridge)
                    moved = {i: float(np.clip(theta0[i] + c * (v - prm.neutral), lo[i], hi[i])) for i, _, c in ridge}
                    shift = np.zeros(len(free_now))
                    for i, k, _ in ridge:
                        shift[k] = moved[i] - theta0[i]
                    grid.append((v, add({j: v, **moved}), shift))
            plan.append((e.name, prm, names[j], plus, minus, grid))
    if not any(x[0] != "current" for x in plan):
        return []
    res = np.asarray(problem.residuals(np.stack(points)), np.float64)
    finite = np.all(np.isfinite(res), axis=1)  # a rollout can blow up at a screen point (a stiff contact)
    r0 = res[0]
    if not finite[0]:
        return []
    jac = np.stack([finite_difference(res, ip, im, h) for kind, _, h, ip, im, *_ in plan if kind == "current"],
                   axis=1)
    cands = [x for x in plan if x[0] != "current"]
    sens = np.stack([finite_difference(res, plus, minus, prm.screen_step) for _, prm, _, plus, minus, _ in cands],
                    axis=1)
    one_sided = [prm.one_sided for _, prm, *_ in cands]
    score = score_test(r0, jac, sens, np.asarray(one_sided))
    base_ss = float(np.sum(r0**2))
    free_names = [names[j] for j in free_now]

    def readjust(dr: np.ndarray) -> np.ndarray:
        # first-order re-adjustment b of the current parameters: min_b |r0 + dr - J b|
        return np.linalg.lstsq(jac, dr, rcond=None)[0] if jac.size else np.zeros(0)

    rows = []
    for c, (name, prm, coord, plus, minus, grid) in enumerate(cands):
        gains = [(-math.inf, prm.neutral + prm.screen_step, np.zeros(len(free_now)))]  # if no grid point is finite
        for v, ip, shift in grid:
            if not finite[ip]:
                continue
            dr = res[ip] - r0
            b = readjust(dr)
            gains.append((base_ss - float(np.sum((r0 + dr - (jac @ b if b.size else 0.0)) ** 2)), v, shift - b))
        g_best, v_best, adj_grid = max(gains, key=lambda x: (x[0], x[1]))
        t = float(score.statistic[c])
        adj_step = -readjust(sens[:, c] * score.step[c])
        rows.append({"effect": name, "parameter": coord, "statistic": max(t, g_best), "score": t,
                     "p_value": float(score.p_value[c]), "step": float(score.step[c]), "grid_gain": g_best,
                     "best_value": float(v_best), "identifiable": bool(score.identifiable[c]),
                     "adjust_grid": dict(zip(free_names, map(float, adj_grid))),
                     "adjust_step": dict(zip(free_names, map(float, adj_step)))})
    return sorted(rows, key=lambda r: -r["statistic"])



def refit_init(union: Union, current: ModelFit, effect: Effect, screen_rows: list[dict]) -> np.ndarray:
    """Start of a refit: the effect's coordinates at the screen's best guess, and the current
    model's parameters either where they are or moved along the screen's first-order
    re-adjustment (``adjust_grid`` / ``adjust_step``: the base parameters that best absorb the
    effect, e.g. a lower friction under added drag), whichever start has the higher likelihood
    (one batched call). The re-adjustment is first order, so it helps for small effects; for
    large ones the refit relies on its screened starts (``DiagnoseSettings.refit_starts``).

    A third start is the current estimate with the effect at its neutral value (1% of its range
    inside a bound, where the neutral value is one): there the nested model's likelihood is the
    current model's, so the start chosen, and LM, which only accepts steps that raise the
    likelihood, never end below the null (exactly, for an effect whose neutral value is inside
    its range).

    The current estimate's free coordinates may sit at a bound (a misfitting model often pushes
    the release time to the edge of its window); ``fit_grad`` moves such an ``init`` 1% of the
    range inward, where LM can move it again."""
    theta = np.asarray(current.result.theta, np.float64).copy()
    problem = union.problem
    names = problem.names
    lo, hi = np.asarray(problem.space.lower), np.asarray(problem.space.upper)
    by_name = {p.name: p for p in effect.params}
    shift = np.zeros_like(theta)
    neutral = theta.copy()
    for j in union.coords.get(effect.name, []):
        prm = by_name[base_name(names[j])]
        span = prm.upper - prm.lower
        v = prm.neutral + prm.screen_step
        adjust = {}
        row = next((r for r in screen_rows if r["parameter"] == names[j]), None)
        if row is not None:
            use_grid = row["grid_gain"] > row["score"]  # the coarse profile beats the local linear step
            v = row["best_value"] if use_grid else prm.neutral + row["step"]
            adjust = row.get("adjust_grid" if use_grid else "adjust_step", {})
        if prm.one_sided and v <= prm.neutral:
            v, adjust = prm.neutral + prm.screen_step, {}
        theta[j] = float(np.clip(v, prm.lower + 0.01 * span, prm.upper - 0.01 * span))
        neutral[j] = float(np.clip(prm.neutral, prm.lower + 0.01 * span, prm.upper - 0.01 * span))
        for n, dv in adjust.items():
            shift[names.index(n)] += dv
    margin = 0.01 * (hi - lo)
    moved = np.clip(theta + shift, lo + margin, hi - margin)
    held = [names.index(n) for n in current.result.fixed]
    moved[held] = theta[held]
    starts = np.stack([theta, moved, neutral])
    ll = np.asarray(problem.log_likelihood(problem.space.to_unconstrained(jnp.asarray(starts))))
    return starts[int(np.nanargmax(np.where(np.isfinite(ll), ll, -np.inf)))] if np.any(np.isfinite(ll)) else theta
