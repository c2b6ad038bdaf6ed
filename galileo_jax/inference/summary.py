"""Posterior and estimate summaries as plain dicts (JSON-ready), one shape for every method.

:func:`summarize_mh` reduces MH draws with ArviZ (``az.from_dict``, ``az.rhat`` rank-normalised
split R-hat, ``az.ess`` bulk ESS; Vehtari et al. 2021); :func:`summarize_grad` gives the same
fields from the Gauss-Newton normal approximation of :func:`~galileo_jax.inference.grad.fit_grad`.

Shape::

    {"method": "mh" | "grad",
     "parameters": {
        name: {"mean", "median", "sd", "interval90": [lo, hi], "best",
               "rhat", "ess_bulk",              # MH only (None for grad)
               "identifiable": bool, "known": bool, "note": str},
        ...},                                   # k1, k2, phi, m1, m2 as they apply
     "diagnostics": {...}}

Reported parameters: every free friction; phi = (m1 - m2) / (m1 + m2) for two-object scenes
(sampled, derived from a free mass and a known one, or known); m1, m2; the release-time
correction ``dt_release`` (when fitted) and the effects' parameters. Masses are flagged
``identifiable: False`` unless a mass is known: with both masses free, MH reports draws from
the posterior under the uniform mass prior given phi (``ParamSpace.masses_for_report``), whose
spread is the prior's, and grad reports no mass value. One-object scenes: the mass does not
affect the motion and is flagged the same way. Known values are reported with
``known: True`` and zero width.
"""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np

from galileo_jax.inference.grad import PROFILE_REFIT_GAIN
from galileo_jax.observation import trace_names
from galileo_jax.params import ParamSpace, nuisances_at_edge

NOT_IDENTIFIABLE = ("not identifiable: velocities determine only phi = (m1 - m2) / (m1 + m2); "
                    "values are draws from the uniform mass prior given phi")
NOT_IDENTIFIABLE_ONE = "not identifiable: a lone sliding object's motion does not depend on its mass"


def phi_of(space: ParamSpace, theta) -> jax.Array | None:
    """phi = (m1 - m2) / (m1 + m2) for theta (..., d); None for one-object scenes."""
    if space.n_objects != 2:
        return None
    m = space.physical(jnp.asarray(theta, jnp.float64)).mass
    return (m[..., 0] - m[..., 1]) / (m[..., 0] + m[..., 1])


def _entry(**kw) -> dict:
    base = {"mean": None, "median": None, "sd": None, "interval90": None, "best": None, "rhat": None,
            "ess_bulk": None, "identifiable": True, "known": False, "note": ""}
    base.update(kw)
    return base


def _f(x):
    return None if x is None else float(x)


def _draw_stats(x: np.ndarray, best: float | None, rhat: float, ess: float, **kw) -> dict:
    return _entry(mean=float(np.mean(x)), median=float(np.median(x)), sd=float(np.std(x, ddof=1)),
                  interval90=[float(np.quantile(x, 0.05)), float(np.quantile(x, 0.95))], best=_f(best),
                  rhat=float(rhat), ess_bulk=float(ess), **kw)


def _effect_names(space: ParamSpace) -> list[str]:
    """The coordinates reported as they are: the release-time correction, the scale error and the effect parameters."""
    return [n for n, k in zip(space.names, space.kinds) if k in ("release", "scale", "effect")]


#: Report note of the release-time correction.
RELEASE_NOTE = ("release time minus the tracker's estimate (s), fitted with the physics (with initial_push: "
                "when a push-free slide would have started; the pushed object leaves v0 / a later)")
#: Report note of the camera's scale error.
SCALE_NOTE = ("relative error of the camera's scale (observed / true displacement - 1), a calibration nuisance within "
              "+-camera.scale_tolerance (fit's --scale-tolerance where the scene states none, 3% by default)")


def _effect_note(name: str) -> str:
    """"effect: meaning (unit)" for an effect parameter name."""
    from galileo_jax.effects import available_effects

    if name == "dt_release":
        return RELEASE_NOTE
    if name == "scale_error":
        return SCALE_NOTE
    for e in available_effects().values():
        for p in e.params:
            if p.name == name:
                return f"{e.name}: {p.doc}" + (f" ({p.unit})" if p.unit else "")
    return ""


#: R-hat above which a sampled parameter's chains count as not mixed (Gelman et al., Bayesian
#: Data Analysis, 3rd ed., 11.4: "below 1.1"; Vehtari et al. 2021 ask for 1.01 with 4 chains).
#: 1.05: what mh at its defaults reaches on 9 of the samplers benchmark's 10 videos (the tenth
#: 1.053; ``benchmarks/results/samplers.md``), so that a warning marks an unusual run.
RHAT_LIMIT = 1.05


def mixing_warning(parameters: dict) -> str | None:
    """One line naming the identifiable sampled parameters whose R-hat exceeds :data:`RHAT_LIMIT`,
    with what it means and what to do; None when every R-hat is below it (or none was computed)."""
    bad = {n: p["rhat"] for n, p in parameters.items()
           if p.get("identifiable", True) and not p.get("known") and p.get("rhat") is not None
           and np.isfinite(p["rhat"]) and p["rhat"] > RHAT_LIMIT}
    if not bad:
        return None
    names = ", ".join(f"{n} {r:.2f}" for n, r in bad.items())
    return (f"warning: R-hat above {RHAT_LIMIT} ({names}): the chains have not mixed, so the intervals may be too "
            "narrow. The log-likelihood is rough around contact events (the simulated impact responds "
            "pseudo-randomly to small parameter changes); raise mh.samples or mh.chains, smooth it further with "
            "--ensemble 8 (each simulated profile the mean of 8 rollouts; mh's default is 2), or set "
            "simulation.substeps: 16 in the scene file (a finer physics step halves that roughness, at twice the "
            "time), or compare with --method grad")


def _mark_edges(params: dict, space: ParamSpace) -> dict:
    """Mark in place each calibration nuisance whose estimate (its ``median``) lies at its
    window's end (:func:`~galileo_jax.params.nuisances_at_edge`): ``at_edge`` "lower" or "upper",
    and ``window`` [lower, upper] (s for dt_release, relative for scale_error). Returns ``params``."""
    names = [n for n in space.names if n in params and not params[n].get("known")
             and params[n].get("median") is not None]
    theta = np.array([params[n]["median"] if n in names else 0.5 * (lo + hi)
                      for n, lo, hi in zip(space.names, space.lower, space.upper)])
    for j, side in nuisances_at_edge(space, theta).items():
        if space.names[j] in names:
            params[space.names[j]].update(at_edge=side, window=[float(space.lower[j]), float(space.upper[j])])
    return params


def edge_warning(parameters: dict) -> str | None:
    """One line per calibration nuisance at the end of its window (:func:`_mark_edges`): what it
    means and what to do; None when none is. Measured on the coverage benchmark's world_62 (a
    hand over the object at its release): with the tracker's release estimate 0.23 s late,
    dt_release stopped at -0.2 s, the end of its window, and k1 came out 0.078 for 0.091."""
    lines = []
    for name, p in parameters.items():
        if not p.get("at_edge"):
            continue
        v, (lo, hi) = p["median"], p["window"]
        if name.startswith("dt_release"):
            lines.append(f"warning: {name} {v:+.3f} s is at the end of its window [{lo:+.2f}, {hi:+.2f}] s: the "
                         "release is further from the tracker's estimate than the fit may move it (was the object "
                         "hidden at its release?), and the other estimates are biased with it; widen "
                         "simulation.release_window in the scene file")
        else:
            lines.append(f"warning: {name} {v:+.1%} is at the end of its tolerance [{lo:+.0%}, {hi:+.0%}]: either "
                         "the camera's scale is off by more (check camera.pixels_per_metre, measured in the plane "
                         "of the objects' centres, or widen camera.scale_tolerance / fit --scale-tolerance), or the "
                         "fit slid along the ridge of friction, release time and scale (compare with --method mh); "
                         "read the other estimates with care")
    return "\n  ".join(lines) or None


#: Log-likelihood difference (nats) within which another Levenberg-Marquardt end point counts as
#: a competing optimum: a likelihood-ratio statistic 2 * delta up to 4, about the 95% quantile of
#: chi^2 with one degree of freedom (3.84), so a test at the 5% level could not tell it from the
#: best (Wilks 1938).
COMPETING_DELTA = 2.0


def competing_optima(result, space: ParamSpace | None, parameters: dict,
                     max_delta: float = COMPETING_DELTA) -> list[dict]:
    """Other optima that fit about as well as the best but lie outside its 90% intervals.

    A Gauss-Newton interval describes the curvature at the best optimum only. Where another
    start of the multi-start fit ended at a different optimum whose log-likelihood is within
    ``max_delta`` nats of the best, the local intervals do not describe what the video
    determines (e.g. a friction coefficient traded against the camera's scale along a ridge).

    Args:
        result: a :class:`~galileo_jax.inference.grad.GradResult` (its ``starts_theta`` (S, d)
            end points and ``starts_cost`` (S,), cost = -log-likelihood + const, nats).
        space: the parameter space (for phi in two-object scenes with free masses); may be
            None where no phi is reported.
        parameters: the summary's parameters (``interval90``, ``sd``, ``identifiable``,
            ``known``), as :func:`point_parameters` returns them.
        max_delta: log-likelihood difference (nats), default :data:`COMPETING_DELTA`.

    Returns:
        One dict per distinct competing optimum, best first: ``delta_loglik`` (nats below the
        best, >= 0), ``theta`` {name: value} of the identifiable fitted parameters, and
        ``outside_interval90`` (the names whose value lies outside the best's 90% interval).
        End points within 1.645 SD (the best's) of an optimum already listed are the same one.
    """
    theta = np.asarray(result.starts_theta, np.float64)
    cost = np.asarray(result.starts_cost, np.float64)
    values = {n: theta[:, j] for j, n in enumerate(result.names)}
    if "phi" in parameters and "phi" not in values and space is not None:
        phi = phi_of(space, jnp.asarray(theta))
        if phi is not None:
            values["phi"] = np.asarray(phi, np.float64)
    checked = [n for n, p in parameters.items() if n in values and p.get("identifiable", True)
               and not p.get("known") and p.get("interval90") is not None]
    out: list[dict] = []
    for s in np.argsort(cost):
        delta = float(cost[s] - result.cost)
        if not np.isfinite(delta) or delta > max_delta:
            continue
        outside = [n for n in checked
                   if not parameters[n]["interval90"][0] <= values[n][s] <= parameters[n]["interval90"][1]]
        if not outside:
            continue
        here = {n: float(values[n][s]) for n in checked}
        if any(all(abs(here[n] - o["theta"][n]) <= 1.645 * max(parameters[n]["sd"], 1e-12) for n in checked)
               for o in out):
            continue
        out.append({"delta_loglik": max(delta, 0.0), "theta": here, "outside_interval90": outside})
    return out


def optima_warning(diagnostics: dict) -> str | None:
    """One line naming the competing optima of a grad fit (:func:`competing_optima`), what they
    mean and what to do; None when there are none."""
    optima = diagnostics.get("competing_optima") or []
    if not optima:
        return None
    shown = "; ".join(", ".join(f"{n} {o['theta'][n]:.3f}" for n in o["outside_interval90"])
                      + f" (log-likelihood {o['delta_loglik']:.1f} lower)" for o in optima[:3])
    return (f"warning: {len(optima)} other optimum{'s' if len(optima) > 1 else ''} fit almost as well ({shown}): "
            "the 90% intervals above are local to the best optimum and do not cover "
            f"{'them' if len(optima) > 1 else 'it'}. The video may not determine these parameters (read them "
            "together), or the search missed a better optimum: compare with more --starts or --method mh")


#: Widening factors at or below this are not mentioned in the console summary.
WIDENING_NOTE_MIN = 1.2


def widening_note(diagnostics: dict) -> str | None:
    """One line naming the parameters whose grad intervals were widened for correlated
    residuals (``interval_widening`` of :func:`summarize_grad`, by more than
    :data:`WIDENING_NOTE_MIN`); None when none was."""
    wide = {n: f for n, f in (diagnostics.get("interval_widening") or {}).items() if f > WIDENING_NOTE_MIN}
    if not wide:
        return None
    shown = ", ".join(f"{n} x{f:.1f}" for n, f in sorted(wide.items(), key=lambda nf: -nf[1])[:5])
    return (f"note: intervals widened for residuals correlated over many frames ({shown}; sandwich covariance): "
            "the model misses something the video shows (tracking errors, a missing effect); see the profiles")


def profile_note(diagnostics: dict) -> str | None:
    """One line naming the parameters whose grad interval was taken from the profile likelihood
    (``profile_check`` of :func:`summarize_grad`) and the Gauss-Newton interval it replaced, and
    saying where the held fits found a higher likelihood than the fit's optimum (and grad was
    fitted again from there, or still stopped short); None when
    neither happened."""
    check = diagnostics.get("profile_check") or {}
    parts = []
    for name, e in (check.get("parameters") or {}).items():
        if e["method"] != "profile":
            continue
        lo, hi = e["interval90_profile"]
        open_ = " (not bounded by the data on one side)" if not all(e.get("bounded", [True, True])) else ""
        g_lo, g_hi = e["interval90_gauss_newton"]
        parts.append(f"{name} [{_fmt_num(lo)}, {_fmt_num(hi)}]{open_} instead of [{_fmt_num(g_lo)}, {_fmt_num(g_hi)}]")
    lines = []
    if parts:
        lines.append("note: the log-likelihood is not quadratic out to the Gauss-Newton interval's ends; 90% intervals "
                     "from the profile likelihood: " + "; ".join(parts))
    for gain in check.get("refitted_from_gain", []):
        lines.append(f"note: a fit with one parameter held found a log-likelihood {gain:.1f} nats higher than the "
                     "first estimate's: grad had stopped short of the maximum and was fitted again from there")
    if check.get("loglik_gain", 0.0) > PROFILE_REFIT_GAIN:
        lines.append(f"note: a fit with one parameter held found a log-likelihood {check['loglik_gain']:.1f} nats "
                     "higher than the estimate's: the fit stopped short of the maximum; refit with more starts "
                     "(grad.starts) or try --method mh")
    return "\n  ".join(lines) or None


def _fmt_num(x: float) -> str:
    return f"{x:.3g}" if abs(x) < 1e-3 or abs(x) >= 1e3 else f"{x:.4f}".rstrip("0").rstrip(".")


def _known(value: float, **kw) -> dict:
    return _entry(mean=value, median=value, sd=0.0, interval90=[value, value], best=value, known=True, **kw)


def summarize_mh(result, space: ParamSpace, key: jax.Array | None = None) -> dict:
    """Summarise an :class:`~galileo_jax.inference.mh.MHResult`.

    Arguments:
        result: MH output with ``theta`` (chains, draws, d) and ``loglik`` (chains, draws).
        space: the problem's :class:`ParamSpace`.
        key: PRNG key for the mass draws (default ``jax.random.key(0)``).

    Returns:
        The dict described in the module docstring. ``best`` is the draw with the highest
        log-likelihood. ``diagnostics``: n_chains, n_draws, acceptance (mean), max_rhat,
        min_ess_bulk (over identifiable sampled parameters), seconds_per_step, best_loglik.

    Raises:
        ValueError: ``result.theta`` does not have shape (chains, draws, d) with d = space.dim.
    """
    import arviz as az

    theta = np.asarray(result.theta, np.float64)
    if theta.ndim != 3 or theta.shape[-1] != space.dim:
        raise ValueError(f"result.theta must have shape (chains, draws, {space.dim}), got {theta.shape}")
    key = jax.random.key(0) if key is None else key
    loglik = np.asarray(result.loglik, np.float64)
    ibest = np.unravel_index(np.argmax(loglik), loglik.shape)

    draws = posterior_draws(theta, space, key)
    phi = phi_of(space, theta)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        idata = az.from_dict(posterior=draws)
        rhat = az.rhat(idata)
        ess = az.ess(idata, method="bulk")

    params: dict[str, dict] = {}
    for i in range(space.n_objects):
        name = f"k{i + 1}"
        if name in draws:
            params[name] = _draw_stats(draws[name], draws[name][ibest], rhat[name], ess[name])
        else:
            params[name] = _known(float(space.known_friction[i]))
    if space.n_objects == 2:
        if "phi" in draws:
            params["phi"] = _draw_stats(draws["phi"], draws["phi"][ibest], rhat["phi"], ess["phi"])
        else:
            params["phi"] = _known(float(np.asarray(phi).ravel()[0]))
    for i in range(space.n_objects):
        name = f"m{i + 1}"
        if space.known_mass[i] is not None:
            params[name] = _known(float(space.known_mass[i]))
        elif space.mass_identifiable:
            params[name] = _draw_stats(draws[name], draws[name][ibest], rhat[name], ess[name])
        else:
            note = NOT_IDENTIFIABLE_ONE if space.n_objects == 1 else NOT_IDENTIFIABLE
            params[name] = _draw_stats(draws[name], None, rhat[name], ess[name], identifiable=False, note=note)
    for name in _effect_names(space):
        params[name] = _draw_stats(draws[name], draws[name][ibest], rhat[name], ess[name], note=_effect_note(name))

    _mark_edges(params, space)
    sampled = [n for n, p in params.items() if p["identifiable"] and not p["known"]]
    diagnostics = {
        "n_chains": int(theta.shape[0]), "n_draws": int(theta.shape[1]),
        "acceptance": float(np.mean(result.acceptance)),
        "max_rhat": float(max(params[n]["rhat"] for n in sampled)) if sampled else None,
        "min_ess_bulk": float(min(params[n]["ess_bulk"] for n in sampled)) if sampled else None,
        "seconds_per_step": float(result.seconds_per_step), "best_loglik": float(loglik[ibest]),
        "rhat_ok": mixing_warning(params) is None,
    }
    return {"method": "mh", "parameters": params, "diagnostics": diagnostics}


def posterior_draws(theta: np.ndarray, space: ParamSpace, key=None) -> dict[str, np.ndarray]:
    """Named draws of the reported quantities: every coordinate of ``space`` and, where the
    fit does not sample them directly, phi and the masses as reported (prior-conditioned where
    not identifiable: :meth:`~galileo_jax.params.ParamSpace.masses_for_report`, from ``key``).

    Args:
        theta: (..., d) draws in physical coordinates, e.g. (chains, draws, d).
        space: the fit's parameter space (d = ``space.dim``).
        key: JAX key for the masses' prior-conditioned draws (default key 0).

    Returns:
        {name: (...) array}, in the units of the parameters (kg, 1, s, ...).
    """
    theta = np.asarray(theta, np.float64)
    key = jax.random.key(0) if key is None else key
    draws: dict[str, np.ndarray] = {n: theta[..., j] for j, n in enumerate(space.names)}
    phi = phi_of(space, theta)
    if phi is not None and "phi" not in draws and space.mass_mode == "free":
        draws["phi"] = np.asarray(phi, np.float64)
    masses = np.asarray(space.masses_for_report(jnp.asarray(theta, jnp.float64), key), np.float64)
    for i in range(space.n_objects):
        if space.known_mass[i] is None and f"m{i + 1}" not in draws:
            draws[f"m{i + 1}"] = masses[..., i]
    return draws


def inference_data(draws: dict[str, np.ndarray], observation, *, sample_stats: dict | None = None,
                   attrs: dict | None = None):
    """The posterior of a fit as ArviZ ``InferenceData`` (``az.from_dict``), the form the
    field's tools read (``az.summary``, ``az.plot_forest``, ``az.from_netcdf``).

    Args:
        draws: {name: (chains, draws) array} (:func:`posterior_draws`; an approximation's
            draws as one chain).
        observation: the fit's :class:`~galileo_jax.observation.Observation`: its velocity
            profile (trace, sample) in m/s, the sample times (s, mid-frame) and the fit
            window go into ``observed_data``.
        sample_stats: optional {name: (chains, draws) array}, e.g. ``lp`` (log posterior
            density, nats) and ``log_likelihood_total`` (nats).
        attrs: optional attributes of the posterior group (method, video, approximation ...);
            strings and numbers.

    Returns:
        ``arviz.InferenceData`` with groups posterior, observed_data (and sample_stats).
    """
    import arviz as az

    t = np.asarray(observation.frame_times, np.float64)
    coords = {"trace": trace_names(observation.n_objects), "time": 0.5 * (t[1:] + t[:-1])}
    observed = {"velocity_profile": np.asarray(observation.profile, np.float64),
                "fit_window": np.asarray(observation.mask, bool)}
    dims = {"velocity_profile": ["trace", "time"], "fit_window": ["time"]}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        idata = az.from_dict(posterior={k: np.asarray(v, np.float64) for k, v in draws.items()},
                             sample_stats=None if sample_stats is None else
                             {k: np.asarray(v, np.float64) for k, v in sample_stats.items()},
                             observed_data=observed, coords=coords, dims=dims)
    idata.posterior.attrs.update({k: v for k, v in (attrs or {}).items() if v is not None})
    idata.observed_data["velocity_profile"].attrs["units"] = "m/s"
    return idata


def summarize_grad(result, space: ParamSpace) -> dict:
    """Summarise a :class:`~galileo_jax.inference.grad.GradResult` in the MH dict shape.

    mean = median = best = the estimate; sd from the delta method; interval90 from the
    Gauss-Newton normal approximation in z mapped through the transform. A derived phi (one
    mass known) gets its SD by the delta method and interval estimate +- 1.645 sd. R-hat and
    ESS are None. ``diagnostics``: cost, loglik, iterations, converged, result, jacobian, time_s,
    ``competing_optima`` (:func:`competing_optima`) and ``interval_widening``: {name: factor}
    by which each fitted parameter's Gauss-Newton SD (in z) was widened to the sandwich
    estimate's (:func:`~galileo_jax.inference.covariance.robust_covariance`; 1.0: not widened). Where
    the intervals were checked against the profile likelihood (:attr:`GradResult.profile`),
    ``profile_check`` holds the check and each checked parameter its ``interval_method``
    ("profile likelihood" where the profile's ends were reported, else "gauss-newton"). Where
    a CMA-ES search followed LM (:attr:`GradResult.search`), ``search`` holds its record; where
    a nuisance at its window's end was fitted again from inside it (:attr:`GradResult.inside`),
    ``inside`` holds that record.
    """
    params = point_parameters(space, result.theta, result.sd, result.interval90, result.cov_theta,
                              getattr(result, "fixed", ()))
    diagnostics = {"cost": float(result.cost), "loglik": float(result.loglik), "iterations": int(result.iterations),
                   "converged": bool(result.converged), "result": result.result, "jacobian": result.jacobian,
                   "n_starts": int(len(result.starts_cost)), "time_s": float(result.time_s),
                   "competing_optima": competing_optima(result, space, params)}
    inflation = getattr(result, "inflation", None)
    if inflation is not None:
        held = set(getattr(result, "fixed", ()))
        diagnostics["interval_widening"] = {n: round(float(f), 3) for n, f in zip(space.names, inflation)
                                            if n not in held and np.isfinite(f)}
    if getattr(result, "search", None) is not None:
        diagnostics["search"] = result.search
    if getattr(result, "inside", None) is not None:
        diagnostics["inside"] = result.inside
    profile = getattr(result, "profile", None)
    if profile is not None:
        diagnostics["profile_check"] = profile
        for name, entry in profile["parameters"].items():
            if name in params:
                params[name]["interval_method"] = ("profile likelihood" if entry["method"] == "profile"
                                                   else "gauss-newton")
    return {"method": "grad", "parameters": params, "diagnostics": diagnostics}


def summarize_cnn(est, space: ParamSpace, loglik: float) -> dict:
    """Summarise a :class:`~galileo_jax.inference.cnn.CNNEstimate` in the MH dict shape:
    estimate = the network's median, sd and interval90 from its Gaussian head (delta-method
    phi as for grad). ``diagnostics``: the model, its architecture and training, the forward
    pass time and the log-likelihood at the estimate (nats)."""
    params = point_parameters(space, est.theta, est.sd, est.interval90, np.diag(np.asarray(est.sd) ** 2), ())
    m = est.model
    diagnostics = {"model": str(m.path), "architecture": m.spec.architecture, "scene": m.spec.scene,
                   "trained_steps": m.info.get("trained_steps"), "examples_seen": m.info.get("examples_seen"),
                   "loglik": float(loglik), "time_s": float(est.time_s),
                   "note": "amortised estimate of a network trained on simulations of this scene; its intervals are "
                           "calibrated on simulations (benchmarks/results/cnn_accuracy.md), not on this video"}
    if m.spec.family is not None:
        diagnostics["note"] = ("amortised estimate of a scene-conditioned network, trained on simulations of scenes "
                               "drawn from its family (ramp angle, sizes, starts, frame rate), read with this scene's "
                               "features; its intervals are calibrated on simulations (benchmarks/results/"
                               "cnn_family.md), not on this video")
        diagnostics["family"] = m.spec.family
    return {"method": "cnn", "parameters": params, "diagnostics": diagnostics}


def point_parameters(space: ParamSpace, theta, sd, interval90, cov_theta, fixed=()) -> dict:
    """The parameters part of a summary from a point estimate with an uncertainty.

    Arguments:
        theta: (d,) estimate; sd: (d,) SDs; interval90: (d, 2) 90% intervals; cov_theta: (d, d)
        covariance (for a derived phi's delta-method SD); fixed: names held at given values.

    Raises:
        ValueError: ``theta`` is not of shape (d,).
    """
    theta = np.asarray(theta, np.float64)
    if theta.shape != (space.dim,):
        raise ValueError(f"result.theta must have shape ({space.dim},), got {theta.shape}")
    idx = {n: j for j, n in enumerate(space.names)}

    def est(name):
        j = idx[name]
        return _entry(mean=float(theta[j]), median=float(theta[j]), sd=float(sd[j]),
                      interval90=[float(v) for v in interval90[j]], best=float(theta[j]))

    params: dict[str, dict] = {}
    for i in range(space.n_objects):
        name = f"k{i + 1}"
        params[name] = est(name) if name in idx else _known(float(space.known_friction[i]))
    if space.n_objects == 2:
        if "phi" in idx:
            params["phi"] = est("phi")
        else:
            phi_fn = lambda t: phi_of(space, t)  # noqa: E731
            value = float(phi_fn(theta))
            if space.mass_mode == "known":
                params["phi"] = _known(value)
            else:
                g = np.asarray(jax.grad(phi_fn)(jnp.asarray(theta, jnp.float64)), np.float64)
                sd_phi = float(np.sqrt(max(g @ np.asarray(cov_theta) @ g, 0.0)))
                params["phi"] = _entry(mean=value, median=value, sd=sd_phi, best=value,
                                       interval90=[max(value - 1.6448536 * sd_phi, -1.0),
                                                   min(value + 1.6448536 * sd_phi, 1.0)])
    for i in range(space.n_objects):
        name = f"m{i + 1}"
        if space.known_mass[i] is not None:
            params[name] = _known(float(space.known_mass[i]))
        elif name in idx:
            params[name] = est(name)
        else:
            note = NOT_IDENTIFIABLE_ONE if space.n_objects == 1 else NOT_IDENTIFIABLE.split(";")[0]
            params[name] = _entry(identifiable=False, note=note)
    held = set(fixed)
    for name in _effect_names(space):
        if name not in held:  # an effect held at a value is not part of this model's report
            params[name] = {**est(name), "note": _effect_note(name)}
    for name in held & set(params):
        params[name] = _known(float(theta[idx[name]]), note="held fixed, not fitted")
    return _mark_edges(params, space)


def summarize_coordinates(result, method: str) -> dict:
    """Per-coordinate summary of a fit of any problem (e.g. a joint fit of several videos), in
    the dict shape of the module docstring: one entry per fitted coordinate name.

    Arguments:
        result: a :class:`~galileo_jax.inference.grad.GradResult` (``method="grad"``) or an
            :class:`~galileo_jax.inference.mh.MHResult` (``method="mh"``: ArviZ R-hat and bulk ESS).
        method: "grad" or "mh".

    Raises:
        ValueError: an unknown method.
    """
    params: dict[str, dict] = {}
    names = list(result.names)
    held = set(getattr(result, "fixed", ()))
    if method == "grad":
        for j, name in enumerate(names):
            if name in held:
                params[name] = _known(float(result.theta[j]), note="held fixed, not fitted")
                continue
            v = float(result.theta[j])
            params[name] = _entry(mean=v, median=v, sd=float(result.sd[j]), best=v,
                                  interval90=[float(x) for x in result.interval90[j]], note=_coord_note(name))
        diagnostics = {"cost": float(result.cost), "loglik": float(result.loglik), "iterations": int(result.iterations),
                       "converged": bool(result.converged), "result": result.result, "time_s": float(result.time_s)}
    elif method == "mh":
        import arviz as az

        theta = np.asarray(result.theta, np.float64)
        draws = {n: theta[..., j] for j, n in enumerate(names)}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            idata = az.from_dict(posterior=draws)
            rhat, ess = az.rhat(idata), az.ess(idata, method="bulk")
        ibest = np.unravel_index(np.argmax(result.loglik), np.shape(result.loglik))
        for name in names:
            params[name] = _draw_stats(draws[name], draws[name][ibest], rhat[name], ess[name], note=_coord_note(name))
        diagnostics = {"n_chains": int(theta.shape[0]), "n_draws": int(theta.shape[1]),
                       "acceptance": float(np.mean(result.acceptance)),
                       "max_rhat": float(max(p["rhat"] for p in params.values())),
                       "min_ess_bulk": float(min(p["ess_bulk"] for p in params.values())),
                       "seconds_per_step": float(result.seconds_per_step), "best_loglik": float(np.max(result.loglik))}
    else:
        raise ValueError(f"unknown method {method!r}; choose grad or mh")
    return {"method": method, "parameters": params, "diagnostics": diagnostics}


def _coord_note(name: str) -> str:
    """Report note of a (possibly per-video, ``name@j``) coordinate."""
    base, _, video = name.partition("@")
    note = "(m1-m2)/(m1+m2), what the videos show of the masses" if base == "phi" else _effect_note(base)
    return (note + f" (video {int(video) + 1})").strip() if video else note
