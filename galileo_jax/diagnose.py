"""``python -m galileo_jax.diagnose VIDEO``: which physical effect is the model missing?

Tracks the video like ``fit``, fits the base model, criticises it per motion phase, screens
the candidate effects of :mod:`galileo_jax.effects` and refits the promising ones, then says
which effect is missing (or that none is), how much the error falls when it is added, and
whether the residuals then look like noise (:func:`galileo_jax.diagnosis.diagnose` explains
the statistics).

Outputs (in ``--out``, default ``<video>_diagnose/``, each written atomically):
``diagnosis.json`` (every model's estimates with 90% intervals, log-likelihood, RMSE, the
residual table and verdict, the screen and the tests), ``residuals_base.png`` and
``residuals_final.png`` (standardised residuals over time with the motion phases),
``model_comparison.png`` (RMSE and log-likelihood per model against the noise floor) and
``profiles_final.png`` (observed vs simulated profiles of the final model).

``--list`` prints the available effects. Every user mistake ends in one line and a non-zero
exit status.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

from galileo_jax.errors import GalileoError, VideoError, cli_entry  # noqa: E402


class _Parser(argparse.ArgumentParser):
    def error(self, message: str):  # noqa: D401 - argparse API
        raise GalileoError(f"{message} (see python -m galileo_jax.diagnose --help)")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="python -m galileo_jax.diagnose",
                description="Find which physical effect the sliding-block model is missing for a ramp video.")
    p.add_argument("video", nargs="?", help="video file of the ramp scene")
    p.add_argument("--scene", help="scene file (YAML); default: the video's name with .yaml")
    p.add_argument("--effects", help="candidate effects, comma-separated (default: all that apply)")
    p.add_argument("--refits", type=int, default=3, help="candidates refitted after the screen (default 3)")
    p.add_argument("--max-effects", type=int, default=1, help="effects added one after another at most (default 1)")
    p.add_argument("--alpha", type=float, default=0.05, help="false-alarm rate of 'an effect is missing' (default 0.05)")
    p.add_argument("--out", help="output folder (default: <video>_diagnose next to the video)")
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


def summary_text(diag, video: Path, elapsed: float | None = None) -> str:
    """Console report: base verdict, screen, refits with tests, decision, error before/after."""
    d = diag.decision
    lines = [f"galileo_jax diagnose: {video.name} (scene {diag.scene.name})", "",
             f"  base model: RMSE {diag.fits[0].rmse:.3f} m/s (noise floor {diag.noise_floor:.3f} m/s)",
             f"  {diag.fits[0].criticism.get('verdict', '')}", ""]
    for rnd in diag.rounds:
        lines.append(f"  round {rnd['round']} (model: {rnd['base']}); threshold p < {rnd['threshold_p']:.3g}")
        if rnd["screen"]:
            lines.append(f"    {'screen: effect':<26}{'score':>9}{'p':>10}{'grid gain':>11}{'at':>8}")
            for r in rnd["screen"]:
                lines.append(f"    {r['effect']:<26}{r['score']:>9.1f}{r['p_value']:>10.2g}{r['grid_gain']:>11.1f}"
                             f"{r['best_value']:>8.3g}")
        lines.append(f"    {'refit: effect':<26}{'dlogL':>9}{'p':>10}{'RMSE':>8}{'drop':>7}   estimate [90%]")
        for x in rnd["refits"]:
            est = "; ".join(f"{k} {v['mean']:.3g} [{v['interval90'][0]:.3g}, {v['interval90'][1]:.3g}]"
                            for k, v in x["parameters"].items()) or "-"
            mark = "  <- supported" if x["supported"] else ""
            lines.append(f"    {x['effect']:<26}{x['delta_loglik']:>9.1f}{x['p_value']:>10.2g}{x['rmse_after']:>8.3f}"
                         f"{100 * x['rmse_drop']:>6.0f}%   {est}{mark}")
        if rnd.get("indistinguishable"):
            lines.append("    " + rnd["indistinguishable"]["message"])
        lines.append("")
    lines.append("  " + d["message"])
    for msg in d["indistinguishable"]:
        lines.append("  " + msg)
    if d["missing_effects"]:
        lines.append(f"  after adding: {d['verdict_final']}")
    lines.append("")
    return "\n".join(lines)


def write_outputs(diag, out: Path, title: str) -> dict:
    """Write diagnosis.json and the figures into ``out``; return {kind: path}."""
    import numpy as np

    from galileo_jax import criticism
    from galileo_jax.report.figures import model_comparison_figure, profile_figure, residual_figure
    from galileo_jax.report.results import package_versions, write_json

    out.mkdir(parents=True, exist_ok=True)
    obs = diag.observation
    times = 0.5 * (obs.frame_times[:-1] + obs.frame_times[1:])
    mask = np.asarray(obs.mask, bool)
    outputs = {}
    for label, fit in (("base", diag.fits[0]), ("final", diag.final)):
        z = criticism.standardised_residuals(obs, fit.simulated, fit.problem.likelihood.sd_model)
        phases = criticism.motion_phases(fit.poses, obs.frame_times, obs.release_time, obs.n_objects)
        table = criticism.residual_table(obs, fit.simulated, fit.problem.likelihood.sd_model, phases)
        path = out / f"residuals_{label}.png"
        residual_figure(path, times, z, phases, mask, f"{title}: {fit.name}", flagged=criticism.flagged(table))
        outputs[f"residuals_{label}"] = str(path)
    models = [{"name": f.name, "rmse": f.rmse, "loglik": f.loglik, "noise_floor": diag.noise_floor} for f in diag.fits]
    path = out / "model_comparison.png"
    model_comparison_figure(path, models, f"{title}: error per model")
    outputs["model_comparison"] = str(path)
    path = out / "profiles_final.png"
    final = diag.final
    profile_figure(path, times, obs.profile, final.simulated, obs.velocity_sd, mask, None, f"{title}: {final.name}")
    outputs["profiles_final"] = str(path)
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
    if args.video is None:
        raise GalileoError("give a video file (or --list); see python -m galileo_jax.diagnose --help")
    video = Path(args.video)
    if not video.is_file():
        raise VideoError(f"video {video} not found; check the path")
    for name, value, low in (("--refits", args.refits, 0), ("--max-effects", args.max_effects, 1)):
        if value < low:
            raise GalileoError(f"{name} must be >= {low}, got {value}")
    if not 0 < args.alpha < 1:
        raise GalileoError(f"--alpha must be between 0 and 1, got {args.alpha}")
    from galileo_jax.diagnosis import DiagnoseSettings, candidate_effects, diagnose
    from galileo_jax.effects import resolve_effects
    from galileo_jax.fit import _scene_path
    from galileo_jax.scene import load_scene

    scene = load_scene(_scene_path(video, args.scene))
    names = None if args.effects is None else tuple(e.name for e in resolve_effects(args.effects))
    if not candidate_effects(scene, names):
        raise GalileoError(f"none of the candidate effects applies to scene {scene.name!r}; "
                           f"see python -m galileo_jax.diagnose --list")
    out = Path(args.out) if args.out else video.with_name(video.stem + "_diagnose")

    from galileo_jax.jaxcache import enable_compilation_cache
    from galileo_jax.observe import observe, read_video

    enable_compilation_cache()
    t0 = time.perf_counter()
    clip = read_video(video, fps_override=args.fps or scene.video.fps)
    obs = observe(clip, scene, progress=not args.quiet)
    settings = DiagnoseSettings(candidates=names, refits=args.refits, alpha=args.alpha, max_effects=args.max_effects)
    say = None if args.quiet else (lambda msg: print(f"  [{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr))
    diag = diagnose(scene, obs, settings, seed=args.seed, progress=say)
    outputs = write_outputs(diag, out, video.name)
    print(summary_text(diag, video))
    for kind, path in outputs.items():
        print(f"  wrote {kind}: {path}")
    print(f"  total time {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
