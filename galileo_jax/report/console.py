"""The readable console summary of a fit."""

from __future__ import annotations

import math

from galileo_jax.pipeline import FitReport, identifiability_statement

NOTES = {
    "phi": "(m1-m2)/(m1+m2), what the video shows of the masses",
}


def _fmt(x) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    return f"{x:.3f}" if abs(x) >= 1e-3 or x == 0 else f"{x:.2e}"


def summary_text(fit: FitReport, elapsed: float | None = None) -> str:
    """Multi-line summary: estimates with 90% intervals, diagnostics, fit quality, prediction."""
    obs = fit.observation
    lines = [
        f"galileo_jax fit: {fit.video.name}  (scene {fit.scene.name}, {len(obs.frame_times)} frames at "
        f"{obs.fps:.2f} fps, method {fit.method})",
        "",
        f"  {'parameter':<10}{'estimate':>10}{'90% interval':>22}{'R-hat':>8}{'ESS':>8}   note",
    ]
    for name, p in fit.parameters.items():
        interval = p.get("interval90")
        iv = f"[{_fmt(interval[0])}, {_fmt(interval[1])}]" if interval else "-"
        note = NOTES.get(name, p.get("note", "") if p.get("identifiable", True) else "")
        if not p.get("identifiable", True):
            note = "NOT identifiable from the video (only phi is)"
        if p.get("known"):
            note = "known (scene file)"
        rhat = _fmt(p.get("rhat")) if p.get("rhat") is not None else ""
        ess = f"{p['ess_bulk']:.0f}" if p.get("ess_bulk") is not None else ""
        lines.append(f"  {name:<10}{_fmt(p.get('estimate')):>10}{iv:>22}{rhat:>8}{ess:>8}   {note}")
    lines += ["", "  " + identifiability_statement(fit.scene), ""]
    lines.append("  fit quality (RMSE of observed - simulated velocity, m/s; noise = tracking noise SD):")
    for name, r in fit.rmse.items():
        if name == "all":
            continue
        lines.append(f"    {name:<12} RMSE {r['rmse']:.3f}   noise {r['noise_sd']:.3f}   ratio {r['ratio']:.1f}")
    diag = {k: v for k, v in fit.diagnostics.items() if isinstance(v, (int, float, bool, str))}
    if diag:
        lines.append("  diagnostics: " + ", ".join(f"{k} {_fmt(v) if isinstance(v, float) else v}"
                                                   for k, v in diag.items()))
    lines.append("")
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
    for kind, path in fit.outputs.items():
        lines.append(f"  wrote {kind}: {path}")
    if elapsed is not None:
        lines.append(f"  total time {elapsed:.1f} s")
    return "\n".join(lines)
