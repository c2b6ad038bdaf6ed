"""``python -m galileo_jax.diagnose VIDEO``: which physical effect is the model missing?

Tracks the video like ``fit``, fits the base model, criticises it per motion phase, screens
the candidate effects of :mod:`galileo_jax.effects` and refits the promising ones, then says
which effect is missing (or that none is), how much the error falls when it is added, and
whether the residuals then look like noise (:func:`galileo_jax.criticism.diagnosis.diagnose` explains
the statistics).

Several videos of one setup (``diagnose a.mp4 b.mp4 ...``) are diagnosed together: one set of
parameters fits all of them (``dt_release``, ``v0`` and ``--per-video`` names per video), and an effect must
explain them jointly.

Outputs (in ``--out``, default ``<first video>_diagnose/``, each written atomically):
``diagnosis.json`` (every model's estimates with 90% intervals, log-likelihood, RMSE, the
residual table and verdict, the screen and the tests), ``residuals_base.png`` and
``residuals_final.png`` (standardised residuals over time with the motion phases),
``model_comparison.png`` (RMSE and log-likelihood per model against the noise floor) and
``profiles_final.png`` (observed vs simulated profiles of the final model with a 90% band
from its parameter uncertainty). With several videos the per-video figures end in ``_1``,
``_2``, ...

``--list`` prints the available effects. Every user mistake ends in one line and a non-zero
exit status.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from galileo_jax.cli import OneLineParser, videos_and_scenes  # noqa: E402
from galileo_jax.errors import GalileoError, cli_entry  # noqa: E402


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="python -m galileo_jax.diagnose",
                      description="Find which physical effect the sliding-block model is missing for a ramp video "
                                  "(or for several videos of one setup, fitted jointly).")
    p.add_argument("videos", nargs="*", metavar="VIDEO", help="video file(s) of the ramp scene; several videos of one "
                                                              "setup share their parameters")
    p.add_argument("--scene", action="append", help="scene file (YAML); default: each video's name with .yaml; "
                                                    "give it once for all videos or once per video")
    p.add_argument("--effects", help="candidate effects, comma-separated (default: all that apply)")
    p.add_argument("--per-video", help="with several videos: parameters fitted per video, comma-separated "
                                       "(default: all shared except v0)")
    p.add_argument("--refits", type=int, default=6, help="candidates with a parameter refitted after the screen "
                                                     "(default 6: all shipped ones)")
    p.add_argument("--max-effects", type=int, default=1, help="effects added one after another at most (default 1)")
    p.add_argument("--alpha", type=float, default=0.05, help="false-alarm rate of 'an effect is missing' (default 0.05)")
    p.add_argument("--engine", choices=("auto", "mjx", "mujoco"), default="auto",
                   help="simulation engine: auto (default: C MuJoCo except for effects that act every "
                        "physics step, which run on MJX), mjx, or mujoco (quadratic_drag through MuJoCo's "
                        "fluid model; no velocity_friction)")
    p.add_argument("--search-patience", type=int, default=None, metavar="N",
                   help="stop each refit's CMA-ES search after N generations without a 0.5-nat gain: faster "
                        "(12 took a third off one video's refits), not yet calibrated (default: every generation)")
    p.add_argument("--out", help="output folder (default: <first video>_diagnose next to it)")
    p.add_argument("--fps", type=float, help="frame rate override (frames per second)")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--list", action="store_true", help="list the available effects and exit")
    p.add_argument("--quiet", action="store_true", help="no progress messages")
    return p


def effects_table() -> str:
    """The registered effects, their parameters and what each one explains."""
    from galileo_jax.effects import available_effects

    lines = ["available effects (python -m galileo_jax.fit VIDEO --effects NAME[,NAME]):"]
    for e in available_effects().values():
        params = ", ".join(f"{p.name} [{p.lower:g}, {p.upper:g}] {p.unit}".rstrip() for p in e.params) or "no parameter"
        lines.append(f"  {e.name:<18} {e.summary}")
        lines.append(f"  {'':<18} parameters: {params}; shows in {e.evidence}")
    return "\n".join(lines)


def summary_text(diag, videos: list[Path]) -> str:
    """Console report: base verdict, screen, refits with tests, decision, error before/after."""
    from galileo_jax.criticism.models import ENGINE_NAMES

    d = diag.decision
    what = ", ".join(f"{v.name} (scene {s.name})" for v, s in zip(videos, diag.scenes))
    lines = [f"galileo_jax diagnose: {what}", "",
             f"  base model ({ENGINE_NAMES[diag.fits[0].union.engine]}): RMSE {diag.fits[0].rmse:.3f} m/s "
             f"(noise floor {diag.noise_floor:.3f} m/s)",
             f"  {diag.fits[0].criticism.get('verdict', '')}"]
    lines += calibration_lines(diag) + [""]
    for rnd in diag.rounds:
        lines.append(f"  round {rnd.round} (model: {rnd.base}); threshold p < {rnd.threshold_p:.3g}")
        if rnd.screen:
            lines.append(f"    {'screen: effect':<26}{'score':>9}{'p':>10}{'grid gain':>11}{'at':>8}")
            for r in rnd.screen:
                lines.append(f"    {r['effect']:<26}{r['score']:>9.1f}{r['p_value']:>10.2g}{r['grid_gain']:>11.1f}"
                             f"{r['best_value']:>8.3g}")
        for tr in rnd.transfers:
            lines.append(f"    the {tr['model']} model refitted on {ENGINE_NAMES[tr['engine']]} for the effects that act "
                         f"every step: RMSE {tr['rmse']:.4f} m/s ({tr['rmse_before']:.4f} on "
                         f"{ENGINE_NAMES[tr['from_engine']]})")
        for nr in rnd.null_refit:
            lines.append(f"    the {nr['model']} model ({ENGINE_NAMES[nr['engine']]}), refitted from {nr['from_effect']}'s "
                         f"estimate, found a better optimum (log L {nr['loglik_before']:.1f} -> {nr['loglik_after']:.1f}, "
                         f"RMSE {nr['rmse_before']:.4f} -> {nr['rmse_after']:.4f} m/s): the tests below are against it"
                         + (f"; refitted from it, better: {', '.join(nr['alternatives_improved'])}"
                            if nr.get("alternatives_improved") else ""))
        if rnd.quiet:
            lines += ["    the residuals look like noise and no candidate's screen points at an effect: no refit", ""]
            continue
        if rnd.adequate:
            lines.append(f"    away from contact events the model fits to within "
                         f"{diag.decision.get('adequate_ratio', 1.3):g}x of the noise floor (RMSE "
                         f"{rnd.calm_rmse:.4f} m/s on {100 * rnd.calm_fraction:.0f}% of the samples): "
                         + ("no refit" if not rnd.refits else "no effect is needed"))
            if not rnd.refits:
                lines.append("")
                continue
        lines.append(f"    {'refit: effect':<26}{'LR':>9}{'p':>10}{'RMSE':>8}{'drop':>7}   estimate [90%]")
        for x in rnd.refits:
            est = "; ".join(f"{k} {v['mean']:.3g} [{v['interval90'][0]:.3g}, {v['interval90'][1]:.3g}]"
                            if v.get("interval90") else f"{k} {v['mean']:.3g} (no gain)"
                            for k, v in x.parameters.items()) or "-"
            mark = "  <- supported" if x.supported else ("  (negligible size)" if x.negligible else "")
            mark += f"  ({ENGINE_NAMES[x.engine]})" if x.engine else ""
            lines.append(f"    {x.effect:<26}{x.lr_scaled:>9.1f}{x.p_value:>10.2g}{x.rmse_after:>8.3f}"
                         f"{100 * x.rmse_drop:>6.0f}%   {est}{mark}")
        if rnd.indistinguishable:
            lines.append("    " + rnd.indistinguishable["message"])
        lines.append("")
    lines.append("  " + d["message"])
    for msg in d["indistinguishable"]:
        lines.append("  " + msg)
    for alt in d.get("calibration_alternatives", []):
        lines.append("  " + alt["message"])
    if d["missing_effects"]:
        lines.append(f"  after adding: {d['verdict_final']}")
    lines.append("")
    return "\n".join(lines)


def calibration_lines(diag) -> list[str]:
    """One line per fitted model saying how large the calibration nuisances came out, e.g.
    "calibration (base model): scale error +2.4% [+1.9, +3.0]% (allowed +-3%)"."""
    cal = diag.calibration()
    lines = []
    for label in ("base", "final"):
        if not cal[label] or (label == "final" and diag.final is diag.fits[0]):
            continue
        parts = []
        for name, v in cal[label].items():
            what = name.replace("scale_error", "scale error")
            ci = v["interval90"]
            ci = f" [{100 * ci[0]:+.1f}, {100 * ci[1]:+.1f}]%" if ci else ""
            allowed = f" (allowed +-{100 * v['tolerance']:g}%)" if v.get("tolerance") else ""
            parts.append(f"{what} {100 * v['best']:+.1f}%{ci}{allowed}")
        lines.append(f"  calibration ({label} model): " + "; ".join(parts))
    return lines


def predictive_band(fit, key, n_draws: int = 32) -> list[np.ndarray]:
    """Per video the (2, 2n, N-1) 5% and 95% quantiles of the profiles simulated at ``n_draws``
    draws from the fit's Gauss-Newton approximation (a 90% band of the parameter uncertainty)."""
    from galileo_jax.inference.covariance import gauss_newton_draws

    draws = gauss_newton_draws(fit.result, fit.problem.space, key, n_draws)
    bands = []
    for j, p in enumerate(fit.union.problems):
        sims = np.asarray(p.simulate(fit.union.theta_for(j, draws)))
        bands.append(np.quantile(sims, [0.05, 0.95], axis=0))
    return bands


def write_outputs(diag, out: Path, titles: list[str]) -> dict:
    """Write diagnosis.json and the figures into ``out``; return {kind: path}.

    With several videos every per-video figure gets the suffix ``_<j>`` (j = 1, 2, ...).
    """
    import jax

    from galileo_jax.criticism import noise
    from galileo_jax.criticism import residuals as criticism
    from galileo_jax.criticism.diagnosis import base_loglik_by_engine
    from galileo_jax.criticism.models import ENGINE_NAMES
    from galileo_jax.report.figures import model_comparison_figure, profile_figure, residual_figure
    from galileo_jax.report.results import package_versions, write_json

    out.mkdir(parents=True, exist_ok=True)
    outputs = {}
    final = diag.final
    bands = predictive_band(final, jax.random.PRNGKey(1))
    several = len(diag.observations) > 1
    for j, (obs, title) in enumerate(zip(diag.observations, titles)):
        suffix = f"_{j + 1}" if several else ""
        times = 0.5 * (obs.frame_times[:-1] + obs.frame_times[1:])
        mask = np.asarray(obs.mask, bool)
        for label, fit in (("base", diag.fits[0]), ("final", final)):
            vf = fit.videos[j]
            crit = vf.criticism  # the fit's criticism (criticism.summarize): phases, table, noise
            # standardised with the tracking noise the tests used (the tracker's, or the one
            # measured from the residual track where the tracker's is too small)
            z = noise.standardised_residuals(obs._replace(position_sd=criticism.tested_position_sd(crit, obs)),
                                                 vf.simulated, crit["sd_model"])
            phases = np.asarray(crit["phases"]["labels"])
            flagged = [(r["trace"], r["phase"]) for r in crit["table"] if r["structured"]]
            path = out / f"residuals_{label}{suffix}.png"
            residual_figure(path, times, z, phases, mask, f"{title}: {fit.name}", flagged=flagged)
            outputs[f"residuals_{label}{suffix}"] = str(path)
        path = out / f"profiles_final{suffix}.png"
        profile_figure(path, times, obs.profile, final.videos[j].simulated, obs.velocity_sd, mask, bands[j],
                       f"{title}: {final.name}")
        outputs[f"profiles_final{suffix}"] = str(path)
    base_loglik = base_loglik_by_engine(diag)
    engines = {f.union.engine for f in diag.fits}
    models = [{"name": f.name + (f" ({ENGINE_NAMES[f.union.engine]})" if len(engines) > 1 else ""), "rmse": f.rmse,
               "loglik": f.loglik, "noise_floor": diag.noise_floor,
               "loglik_reference": base_loglik.get(f.union.engine)} for f in diag.fits]
    path = out / "model_comparison.png"
    model_comparison_figure(path, models, f"{titles[0] if not several else 'joint'}: error per model")
    outputs["model_comparison"] = str(path)
    path = out / "diagnosis.json"
    write_json(path, {**diag.as_dict(), "outputs": outputs, "versions": package_versions()})
    outputs["result"] = str(path)
    return outputs


@cli_entry
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.list:
        print(effects_table())
        return 0
    if not args.videos:
        raise GalileoError("give a video file (or --list); see python -m galileo_jax.diagnose --help")
    for name, value, low in (("--refits", args.refits, 0), ("--max-effects", args.max_effects, 1),
                             ("--search-patience", 1 if args.search_patience is None else args.search_patience, 1)):
        if value < low:
            raise GalileoError(f"{name} must be >= {low}, got {value}")
    if not 0 < args.alpha < 1:
        raise GalileoError(f"--alpha must be between 0 and 1, got {args.alpha}")
    inputs = videos_and_scenes(args.videos, args.scene)
    from galileo_jax.criticism.diagnosis import DiagnoseSettings, diagnose
    from galileo_jax.criticism.models import candidate_effects
    from galileo_jax.effects import resolve_effects

    names = None if args.effects is None else tuple(e.name for e in resolve_effects(args.effects))
    for video, scene in inputs:
        if not candidate_effects(scene, names):
            raise GalileoError(f"none of the candidate effects applies to scene {scene.name!r} of {video.name}; "
                               f"see python -m galileo_jax.diagnose --list")
    per_video = tuple(s.strip() for s in (args.per_video or "").split(",") if s.strip())
    if per_video and len(inputs) == 1:
        raise GalileoError("--per-video needs several videos")
    first = inputs[0][0]
    out = Path(args.out) if args.out else first.with_name(first.stem + "_diagnose")

    from galileo_jax.jaxcache import enable_compilation_cache
    from galileo_jax.observe import observe, read_video

    enable_compilation_cache()
    t0 = time.perf_counter()
    observations = [observe(read_video(video, fps_override=args.fps or scene.video.fps), scene, progress=not args.quiet)
                    for video, scene in inputs]
    settings = DiagnoseSettings(candidates=names, refits=args.refits, alpha=args.alpha, max_effects=args.max_effects,
                                per_video=per_video, engine=args.engine, search_patience=args.search_patience)
    say = None if args.quiet else (lambda msg: print(f"  [{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr))
    try:
        diag = diagnose([s for _, s in inputs], observations, settings, seed=args.seed, progress=say)
    except ValueError as err:  # e.g. per-video names that are no parameter, bounds that do not overlap
        raise GalileoError(str(err)) from None
    outputs = write_outputs(diag, out, [v.name for v, _ in inputs])
    print(summary_text(diag, [v for v, _ in inputs]))
    for kind, path in outputs.items():
        print(f"  wrote {kind}: {path}")
    print(f"  total time {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
