"""The readable console summary of a fit."""

from __future__ import annotations

import math
from pathlib import Path

from galileo_jax.inference.summary import edge_warning, mixing_warning, optima_warning, profile_note, widening_note
from galileo_jax.fit_report import FitReport, JointFitReport, identifiability_statement

NOTES = {
    "phi": "(m1-m2)/(m1+m2), what the video shows of the masses",
}


def _fmt(x) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    return f"{x:.3f}" if abs(x) >= 1e-3 or x == 0 else f"{x:.2e}"


def _parameter_lines(parameters: dict) -> list[str]:
    """The table of estimates with 90% intervals, R-hat and ESS (where sampled)."""
    lines = [f"  {'parameter':<14}{'estimate':>10}{'90% interval':>22}{'R-hat':>8}{'ESS':>8}   note"]
    for name, p in parameters.items():
        interval = p.get("interval90")
        iv = f"[{_fmt(interval[0])}, {_fmt(interval[1])}]" if interval else "-"
        note = NOTES.get(name, p.get("note", "") if p.get("identifiable", True) else "")
        if not p.get("identifiable", True):
            note = "NOT identifiable from the video (only phi is)"
        if p.get("known"):
            note = p.get("note") or "known (scene file)"
        rhat = _fmt(p.get("rhat")) if p.get("rhat") is not None else ""
        ess = f"{p['ess_bulk']:.0f}" if p.get("ess_bulk") is not None else ""
        lines.append(f"  {name:<14}{_fmt(p.get('estimate', p.get('mean'))):>10}{iv:>22}{rhat:>8}{ess:>8}   {note}")
    return lines + [f"  {w}" for w in (mixing_warning(parameters), edge_warning(parameters)) if w]


def _interval_warning_lines(diagnostics: dict) -> list[str]:
    return [f"  {line}" for line in (optima_warning(diagnostics), widening_note(diagnostics),
                                      profile_note(diagnostics)) if line]


def _rmse_lines(rmse: dict, indent: str = "    ") -> list[str]:
    return [f"{indent}{name:<12} RMSE {r['rmse']:.3f}   noise {r['noise_sd']:.3f}   ratio {r['ratio']:.1f}"
            for name, r in rmse.items() if name != "all"]


def joint_summary_text(fit: JointFitReport, elapsed: float | None = None) -> str:
    """Multi-line summary of a joint fit: shared and per-video estimates, fit quality per video."""
    lines = [f"galileo_jax fit: {len(fit.videos)} videos fitted jointly (method {fit.method}); per video: "
             f"{', '.join(fit.per_video) or 'nothing'}", ""]
    for j, (v, s, o) in enumerate(zip(fit.videos, fit.scenes, fit.observations)):
        lines.append(f"  video {j + 1}: {v.name} (scene {s.name}, {len(o.frame_times)} frames at {o.fps:.2f} fps)")
    lines.append("")
    lines += _parameter_lines(fit.parameters) + _interval_warning_lines(fit.diagnostics)
    lines += ["", "  " + identifiability_statement(fit.scenes[0]), ""]
    lines.append("  fit quality per video (RMSE of observed - simulated velocity, m/s; log-likelihood):")
    for j, (r, ll) in enumerate(zip(fit.rmse, fit.video_loglik)):
        lines.append(f"    video {j + 1}: RMSE {r['all']['rmse']:.3f}, log L {ll:.1f}")
        lines += _rmse_lines(r, "      ")
        if j < len(fit.adequacy):
            lines += ["    " + x for x in _adequacy_lines(fit.adequacy[j], fit.videos[j], fit.scenes[j])]
    lines += _diagnostic_lines(fit.diagnostics) + [""]
    return "\n".join(lines + _footer_lines(fit.outputs, elapsed))


#: Diagnostics said in their own line (:func:`_start_line`), not in the diagnostics list.
_START_KEYS = ("init", "init_note", "cnn_model", "cnn_time_s")


def _start_line(diagnostics: dict) -> list[str]:
    """Where grad or mh started: the CNN's estimate (which network) or the prior (and why, where
    ``--init auto`` found no network for the video)."""
    if diagnostics.get("init") == "cnn":
        model = Path(str(diagnostics.get("cnn_model", ""))).name
        return [f"  start: the trained CNN's estimate ({model}, {_fmt(diagnostics.get('cnn_time_s', 0.0))} s)"]
    if "init_note" in diagnostics:
        return [f"  start: {diagnostics['init_note']}"]
    return []


def _diagnostic_lines(diagnostics: dict) -> list[str]:
    diag = {k: v for k, v in diagnostics.items()
            if isinstance(v, (int, float, bool, str)) and v != "" and k not in _START_KEYS}
    lines = _start_line(diagnostics)
    if diag:
        lines.append("  diagnostics: " + ", ".join(f"{k} {_fmt(v) if isinstance(v, float) else v}"
                                                   for k, v in diag.items()))
    return lines


def _footer_lines(outputs: dict, elapsed: float | None) -> list[str]:
    lines = [f"  wrote {kind}: {path}" for kind, path in outputs.items()]
    if elapsed is not None:
        lines.append(f"  total time {elapsed:.1f} s")
    return lines


def _adequacy_lines(adequacy: dict, video, scene) -> list[str]:
    """The fit-adequacy verdict (:func:`galileo_jax.criticism.adequacy.adequacy`) and, where the residuals
    are structured, where to look next."""
    if not adequacy:
        return []
    lines = [f"  fit adequacy: {adequacy['verdict']}"]
    if not adequacy["adequate"] and not adequacy["looks_like_noise"]:
        scale = (" a calibration error (this fit took the camera's scale as exact, and a scale measured by hand is "
                 "rarely better than a few percent: --scale-tolerance 0.03 or camera.scale_tolerance fits it) or"
                 if not scene.camera.scale_tolerance else "")
        lines.append("  The model misses something here (the estimates and intervals above assume it does not;"
                     " on rendered test videos the 90% intervals of fits judged inadequate held the truth in only"
                     " 52-80% of the cases, benchmarks/results/coverage.md):"
                     f"{scale} a physical effect; python -m galileo_jax.diagnose {video} looks for both.")
    return lines


def summary_text(fit: FitReport, elapsed: float | None = None) -> str:
    """Multi-line summary: estimates with 90% intervals, diagnostics, fit quality, prediction."""
    obs = fit.observation
    lines = [
        f"galileo_jax fit: {fit.video.name}  (scene {fit.scene.name}, {len(obs.frame_times)} frames at "
        f"{obs.fps:.2f} fps, method {fit.method})",
        "",
    ]
    lines += _parameter_lines(fit.parameters) + _interval_warning_lines(fit.diagnostics)
    lines += ["", "  " + identifiability_statement(fit.scene), ""]
    lines.append("  fit quality (RMSE of observed - simulated velocity, m/s; noise = tracking noise SD):")
    lines += _rmse_lines(fit.rmse)
    lines += _adequacy_lines(fit.adequacy, fit.video, fit.scene)
    lines += _diagnostic_lines(fit.diagnostics) + [""]
    pred = fit.prediction
    lines.append(f"  prediction ({pred['simulated_seconds_after_release']:.1f} s after release):")
    for o in pred["objects"]:
        where = ("on the floor, " if o["rest_x_m"] >= 0 else "on the ramp, ") + f"x = {o['rest_x_m']:.3f} m from the foot"
        iv = o.get("rest_x_interval90_m")
        iv = f" (90%: {iv[0]:.3f} to {iv[1]:.3f} m)" if iv else ""
        when = ("still moving at the end" if o["still_moving_at_end"]
                else f"stops {o['stop_time_after_release_s']:.2f} s after release")
        lines.append(f"    object {o['object']}: comes to rest {where}{iv}; {when}")
    slide = pred["will_object1_slide"]
    prob = f", probability {slide['probability']:.2f}" if slide.get("probability") is not None else ""
    lines.append(f"    will object 1 slide? {'yes' if slide['answer'] else 'no'} ({slide['rule']}{prob})")
    lines.append("")
    return "\n".join(lines + _footer_lines(fit.outputs, elapsed))
