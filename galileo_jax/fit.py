"""``python -m galileo_jax.fit VIDEO --method grad|mh|cnn|seed [--init ...]``: physical properties from a ramp video.

Pipeline: read the video and scene -> track the objects -> velocity profiles -> fit
(m1, k1, m2, k2) against vmapped MJX rollouts -> report (console, ``result.json``,
``profiles.png``, ``overlay.mp4``) and predict beyond the video (where the objects stop,
will object 1 slide?).

Several videos of one setup (``fit a.mp4 b.mp4 ...``) are fitted jointly
(:func:`~galileo_jax.pipeline.run_joint_fit`): shared parameters, and the release-time
correction, ``v0`` and ``--per-video`` names per video; the output folder then holds
``result.json`` and ``profiles_<j>.png`` per video.

The CLI is thin: it parses, calls :func:`run_fit` (or :func:`run_joint_fit`) and prints. Every
user mistake ends in one line on stderr and a non-zero exit status (see :mod:`galileo_jax.errors`).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from galileo_jax.cli import OneLineParser, videos_and_scenes  # noqa: E402
from galileo_jax.errors import GalileoError, cli_entry  # noqa: E402

METHODS = ("grad", "mh", "cnn", "seed")


def build_parser() -> argparse.ArgumentParser:
    from galileo_jax.config import INITS

    p = OneLineParser(prog="python -m galileo_jax.fit",
                      description="Estimate masses and friction coefficients from a video of objects on a ramp "
                                  "(several videos of one setup: one joint fit with shared parameters).")
    p.add_argument("videos", nargs="+", metavar="VIDEO", help="video file(s) (mp4, avi, ...) of the ramp scene")
    p.add_argument("--scene", action="append", help="scene file (YAML); default: each video's name with .yaml; "
                                                    "give it once for all videos or once per video")
    p.add_argument("--method", default="grad", choices=METHODS,
                   help="grad: Levenberg-Marquardt (fast); mh: Metropolis-Hastings posterior; "
                        "cnn: the trained network's amortised estimate (one forward pass); "
                        "seed: the seed's coin-toss sampler (baseline, one video)")
    p.add_argument("--init", default="auto", choices=INITS,
                   help="auto (default): grad starts from the trained CNN's estimate where a network reads "
                        "the scene (else from the prior), mh from the prior; prior; cnn: grad/mh from the CNN, "
                        "an error where no network reads the scene")
    p.add_argument("--cnn-model", help="trained CNN folder (default: the model matching the scene in galileo_jax/models/, $GALILEO_JAX_MODELS or ./models)")
    p.add_argument("--per-video", help="several videos: parameters fitted per video, comma-separated "
                                       "(default: all shared except dt_release and v0)")
    p.add_argument("--out", help="output folder (default: <first video>_fit next to it)")
    p.add_argument("--config", help="settings file (YAML, see configs/fit.yaml)")
    p.add_argument("--fps", type=float, help="frame rate override (frames per second)")
    p.add_argument("--chains", type=int, help="mh/seed: number of chains")
    p.add_argument("--warmup", type=int, help="mh: warm-up steps")
    p.add_argument("--samples", type=int, help="mh: kept steps per chain")
    p.add_argument("--starts", type=int, help="grad: number of Levenberg-Marquardt starts")
    p.add_argument("--effects", help="physical effects to add to the base model, comma-separated "
                                     "(e.g. quadratic_drag,restitution; see python -m galileo_jax.diagnose --list)")
    p.add_argument("--engine", choices=("auto", "mjx", "mujoco"),
                   help="simulator of the rollouts: mjx (JAX, differentiable), mujoco (C MuJoCo's batched rollouts) "
                        "or auto (default: mujoco unless the fit needs MJX, on a GPU too)")
    p.add_argument("--scale-tolerance", type=float, metavar="TOL",
                   help="relative tolerance of the camera's scale where the scene file states none (default 0.03: "
                        "grad and mh fit a nuisance scale_error within +-TOL; 0 takes the scale as exact)")
    p.add_argument("--likelihood", help="likelihood kind: gaussian_iid (default), gaussian_ma1, seed_gaussian, emd, rms")
    p.add_argument("--ensemble", type=int, metavar="K",
                   help="each simulated profile the mean of K rollouts from starts shifted within one physics "
                        "step (smooths the likelihood at collisions; K times the rollouts; default: 4 for mh, "
                        "1 (off) for the other methods)")
    p.add_argument("--seed", type=int, default=0, help="random seed")
    p.add_argument("--no-video", action="store_true", help="do not write the overlay video")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    return p


def _settings(args) -> "FitConfig":  # noqa: F821
    from galileo_jax.config import load_config

    cfg = load_config(args.config)
    if args.chains is not None:
        cfg.mh.chains = cfg.seed_mh.chains = args.chains
    if args.warmup is not None:
        cfg.mh.warmup = cfg.mh.warmup_cnn = args.warmup
    if args.samples is not None:
        cfg.mh.samples = args.samples
    if args.starts is not None:
        cfg.grad.starts = args.starts
    if args.likelihood is not None:
        cfg.likelihood.kind = args.likelihood
    if args.ensemble is not None:
        cfg.likelihood.ensemble = args.ensemble
    if args.engine is not None:
        cfg.engine = args.engine
    if args.cnn_model is not None:
        cfg.cnn.model = args.cnn_model
    if args.scale_tolerance is not None:
        from galileo_jax.scene import MAX_SCALE_TOLERANCE

        if not 0.0 <= args.scale_tolerance <= MAX_SCALE_TOLERANCE:
            raise GalileoError(f"--scale-tolerance must be between 0 and {MAX_SCALE_TOLERANCE:g} (a relative error), "
                               f"got {args.scale_tolerance:g}")
        cfg.scale_tolerance = args.scale_tolerance
    if args.effects is not None:
        from galileo_jax.effects import resolve_effects

        cfg.effects = [e.name for e in resolve_effects(args.effects)]  # unknown name: one-line error
    for name, value in (("--chains", args.chains), ("--starts", args.starts), ("--samples", args.samples),
                        ("--ensemble", args.ensemble)):
        if value is not None and value < 1:
            raise GalileoError(f"{name} must be a positive integer, got {value}")
    if args.ensemble is not None:
        from galileo_jax.config import MAX_ENSEMBLE

        if args.ensemble > MAX_ENSEMBLE:
            raise GalileoError(f"--ensemble must be at most {MAX_ENSEMBLE} (each rollout becomes that many), "
                               f"got {args.ensemble}")
    if args.warmup is not None and args.warmup < 0:
        raise GalileoError(f"--warmup must be >= 0, got {args.warmup}")
    return cfg


@cli_entry
def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    inputs = videos_and_scenes(args.videos, args.scene)
    cfg = _settings(args)
    per_video = tuple(s.strip() for s in (args.per_video or "").split(",") if s.strip())
    if len(inputs) > 1 and args.method in ("seed", "cnn"):
        raise GalileoError(f"--method {args.method} fits one video; use --method grad or mh for several")
    if args.init == "cnn" and args.method in ("seed", "cnn"):
        raise GalileoError(f"--init cnn starts grad or mh; --method {args.method} has no starting point")
    if len(inputs) > 1 and args.init == "cnn":
        raise GalileoError("--init cnn fits one video; a joint fit of several videos starts from the prior")
    if per_video and len(inputs) == 1:
        raise GalileoError("--per-video needs several videos")
    first = inputs[0][0]
    out = Path(args.out) if args.out else first.with_name(first.stem + "_fit")

    from galileo_jax.jaxcache import enable_compilation_cache
    from galileo_jax.report.console import joint_summary_text, summary_text

    enable_compilation_cache()
    t0 = time.perf_counter()
    if len(inputs) > 1:
        from galileo_jax.pipeline import run_joint_fit

        joint = run_joint_fit(inputs, cfg, method=args.method, out=out, fps=args.fps, seed=args.seed,
                              per_video=per_video, progress=not args.quiet)
        print(joint_summary_text(joint, elapsed=time.perf_counter() - t0))
        return 0
    from galileo_jax.pipeline import run_fit

    video, scene = inputs[0]
    fit = run_fit(video, scene, cfg, method=args.method, out=out, fps=args.fps, seed=args.seed,
                  overlay=not args.no_video, progress=not args.quiet, init=args.init)
    print(summary_text(fit, elapsed=time.perf_counter() - t0))
    return 0


if __name__ == "__main__":
    sys.exit(main())
