"""``python -m galileo_jax.synth``: the command line of the synthetic-video renderer (package
docstring: options and examples).
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from galileo_jax import render
from galileo_jax.cli import OneLineParser
from galileo_jax.effects import available_effects, check_applicable, get_effect
from galileo_jax.effects.runtime import effect_param_names
from galileo_jax.errors import GalileoError, SceneError, cli_entry
from galileo_jax.physics.model import WorldPhysics
from galileo_jax.physics.simulate import scene_effects
from galileo_jax.scene import load_scene
from galileo_jax.synth.draws import draw_informative_params, draw_random_params
from galileo_jax.synth.motion import REST_SECONDS
from galileo_jax.synth.video import check_options, check_style, render_video


def _parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="python -m galileo_jax.synth",
                description="Render a synthetic ramp video (mp4) with its calibrated scene (.yaml) and "
                            "ground truth (.truth.json).")
    p.add_argument("--scene", required=True, help="scene YAML file (e.g. scenes/ramp_20.yaml)")
    for name, what in (("m1", "mass of object 1 (kg)"), ("k1", "friction coefficient of object 1"),
                       ("m2", "mass of object 2 (kg)"), ("k2", "friction coefficient of object 2")):
        p.add_argument(f"--{name}", type=float, help=what)
    p.add_argument("--out", required=True, help="output .mp4 file, or a folder (created if missing)")
    p.add_argument("--fps", type=float, default=30.0, help="frames per second (default 30)")
    p.add_argument("--duration", type=float, help="video length in s (default: until at rest, at most 4 s)")
    p.add_argument("--noise", type=float, default=2.0, help="pixel noise SD in grey levels (default 2)")
    p.add_argument("--hand", action="store_true", help="show a hand holding object 1 until the release")
    p.add_argument("--seed", type=int, default=0, help="seed of the noise and of --random draws")
    p.add_argument("--random", type=int, metavar="N", help="render N videos with random free parameters "
                   "(k1 < tan(theta) - 0.05 so object 1 slides); given --m1 etc. are kept fixed")
    p.add_argument("--effect", action="append", metavar="NAME[=VALUE]",
                   help="simulate a hidden physical effect (repeatable): NAME=VALUE sets its parameter "
                        "(NAME=V1,V2 for several, in order), NAME alone with --random draws it uniformly from the "
                        "parameter's synth range, 'none' means no effect. The effect goes into the truth, not the "
                        "written scene file. With --random and effects, draws are redone (at most 20 times) "
                        "until object 1's friction on the ramp after the effects (k1 + dk_ramp) is below "
                        "tan(theta) - 0.05 and the simulated object 1 reaches object 2 (one object: the floor) "
                        f"within the video. Effects: {', '.join(sorted(available_effects()))}")
    p.add_argument("--width", type=int, default=640, help="image width in px (default 640)")
    p.add_argument("--height", type=int, default=360, help="image height in px (default 360)")
    p.add_argument("--rest", type=float, default=REST_SECONDS, help="seconds held at rest before release (default 0.3)")
    p.add_argument("--look", choices=render.LOOKS, default="checker",
                   help="objects: checker texture (default) or one plain colour")
    p.add_argument("--colour", action="append", type=_colour, metavar="R,G,B",
                   help="base colour of an object, components in [0, 1] (repeatable: once per object, in order; "
                        "default: the scene's rgba, else red and blue)")
    p.add_argument("--camera", choices=render.PROJECTIONS, default="orthographic",
                   help="orthographic (default: exact scale at any depth) or perspective (a pinhole --distance m "
                        "from the plane of motion, exact scale in that plane)")
    p.add_argument("--distance", type=float, default=render.CAMERA_DISTANCE,
                   help=f"perspective camera's distance from the plane of motion in m "
                        f"(default {render.CAMERA_DISTANCE})")
    p.add_argument("--direction", choices=render.DIRECTIONS,
                   help="image direction object 1 moves in: right (default) or left (the scene seen from behind)")
    p.add_argument("--left", action="store_true", help="same as --direction left")
    p.add_argument("--blur", type=int, default=0, metavar="N",
                   help="motion blur: average N >= 2 sub-frames per frame over the --shutter (default 0: none)")
    p.add_argument("--shutter", type=float, default=0.5,
                   help="exposure as a fraction of the frame interval, in (0, 1] (default 0.5; with --blur)")
    p.add_argument("--backdrop", choices=render.BACKDROPS, default="plain",
                   help="backdrop wall: plain grey (default) or clutter (posters, shelves, cables, blobs)")
    p.add_argument("--cone", choices=("pyramidal", "elliptic"), default="pyramidal",
                   help="friction cone of the simulated contacts: pyramidal (default, the fitted model's) or "
                        "elliptic (physics the model does not have, for testing on videos it cannot reproduce)")
    p.add_argument("--ramp-thickness", type=float, default=0.0, metavar="M",
                   help="simulate the ramp as a board this thick (m) whose foot edge rests on the floor, so objects "
                        "drop over an edge onto the floor; the written scene file does not know of it (default 0: "
                        "the fitted model's ramp plane)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def _colour(text: str) -> tuple[float, ...]:
    """argparse type of ``--colour R,G,B``: three numbers (their range is checked by render_video)."""
    try:
        rgb = tuple(float(t) for t in text.split(","))
    except ValueError:
        rgb = ()
    if len(rgb) != 3:
        raise argparse.ArgumentTypeError(f"{text!r} is not R,G,B (three numbers in [0, 1], e.g. 0.2,0.5,0.9)")
    return rgb


def _direction(args: argparse.Namespace) -> str:
    """The image direction from ``--direction`` and ``--left``.

    Raises:
        GalileoError: ``--left`` with ``--direction right``.
    """
    if args.left and args.direction == "right":
        raise GalileoError("--left contradicts --direction right; give one of them")
    return "left" if args.left else args.direction or "right"


def _outputs(out: str, stem: str, count: int, random: bool) -> list[Path]:
    path = Path(out)
    if path.suffix.lower() == ".mp4":
        if random:
            raise GalileoError(f"--random needs --out to be a folder, not {out}")
        if path.parent.exists() and not path.parent.is_dir():
            raise GalileoError(f"--out {out}: {path.parent} is a file, not a folder")
        path.parent.mkdir(parents=True, exist_ok=True)
        return [path]
    if path.exists() and not path.is_dir():
        raise GalileoError(f"--out {out} is a file; give a folder or a .mp4 path")
    path.mkdir(parents=True, exist_ok=True)
    if not random:
        return [path / f"{stem}.mp4"]
    return [path / f"{stem}_{i:03d}.mp4" for i in range(count)]


def parse_effect_options(items, random: bool) -> tuple[list[str], dict[str, float]]:
    """Parse ``--effect`` options into (effect names in order, {parameter: value}).

    ``NAME=VALUE`` (``NAME=V1,V2`` for an effect with several parameters, in their order) fixes
    the values; ``NAME`` alone is allowed for an effect without parameters, or with ``random``
    (its values are drawn); ``none`` means no effect.

    Raises:
        GalileoError: an unknown effect, a missing or malformed value, a repeated effect, or
            ``none`` given with other effects.
    """
    names: list[str] = []
    values: dict[str, float] = {}
    items = list(items or [])
    if any(i.strip().lower() == "none" for i in items):
        if len(items) > 1:
            raise GalileoError("--effect none means no effect; do not combine it with other --effect options")
        return [], {}
    for item in items:
        name, sep, text = item.partition("=")
        name = name.strip()
        effect = get_effect(name)
        if effect.name in names:
            raise GalileoError(f"--effect {effect.name} is given twice; give each effect once")
        names.append(effect.name)
        if not sep:
            if effect.params and not random:
                p = effect.params[0]
                raise GalileoError(f"--effect {name} needs a value: --effect {name}=VALUE ({p.name}, {p.doc or p.unit}; "
                                   f"e.g. {p.synth_range[0]:g} to {p.synth_range[1]:g}), or use --random to draw it")
            continue
        if not effect.params:
            raise GalileoError(f"--effect {item}: effect {name} has no parameter; give --effect {name} alone")
        parts = [t.strip() for t in text.split(",")]
        if len(parts) != len(effect.params):
            raise GalileoError(f"--effect {item}: {name} takes {len(effect.params)} value(s) "
                               f"({', '.join(effect.param_names)}), got {len(parts)}")
        for p, t in zip(effect.params, parts):
            try:
                values[p.name] = float(t)
            except ValueError:
                raise GalileoError(f"--effect {item}: {t!r} is not a number") from None
    return names, values


@cli_entry
def main(argv: list[str] | None = None) -> int:
    """Command-line entry point (``python -m galileo_jax.synth``); returns the exit code."""
    args = _parser().parse_args(argv)
    scene = load_scene(args.scene)
    given = {k: getattr(args, k) for k in ("m1", "k1", "m2", "k2") if getattr(args, k) is not None}
    extra = [k for k in given if int(k[1]) > scene.n_objects]
    if extra:
        raise SceneError(f"--{extra[0]} given but scene {args.scene} has {scene.n_objects} object(s)")
    if args.random is not None and not 1 <= args.random <= 10000:
        raise GalileoError(f"--random {args.random}: give a count in [1, 10000]")
    if not math.isfinite(args.rest) or args.rest <= 0:
        raise GalileoError(f"--rest {args.rest}: give a positive time in s")
    effect_names, effect_values = parse_effect_options(args.effect, args.random is not None)
    effs = scene_effects(scene, effect_names)
    check_applicable(effs, scene)
    if args.random is None:  # every effect parameter needs a value (also those of the scene's own effects)
        missing = [(e, p) for e in effs for p in e.params if p.name not in effect_values]
        if missing:
            e, p = missing[0]
            raise GalileoError(f"effect {e.name!r} needs a value of {p.name}: give --effect {e.name}=VALUE "
                               f"(e.g. {p.synth_range[0]:g} to {p.synth_range[1]:g}) or use --random")
    count = args.random or 1
    paths = _outputs(args.out, scene.name.replace(" ", "_"), count, args.random is not None)
    rng = np.random.default_rng(args.seed)
    rest_frames = max(1, int(round(args.rest * args.fps)))
    n_frames = None if args.duration is None else int(round(args.duration * args.fps))
    names = ["m1", "k1", "m2", "k2"] + list(effect_param_names(effs))
    style = dict(look=args.look, colours=args.colour, camera=args.camera, camera_distance=args.distance,
                 direction=_direction(args), blur=args.blur, shutter=args.shutter, backdrop=args.backdrop)
    check_style(scene, **style)
    try:
        world = WorldPhysics(cone=args.cone, ramp_thickness=args.ramp_thickness)
    except ValueError as err:
        raise GalileoError(f"{err} (--cone, --ramp-thickness)") from None
    if args.random and effs:  # the draws simulate the video: check its options first
        check_options(args.fps, args.duration, args.width, args.height, args.noise, rest_frames)
    for i, path in enumerate(paths):
        if args.random and effs:
            params = draw_informative_params(scene, rng, effect_names, fps=args.fps, rest_frames=rest_frames,
                                             n_frames=n_frames, fixed=given, fixed_effects=effect_values)
        elif args.random:
            params = draw_random_params(scene, rng, fixed=given)
        else:
            params = {**given, **effect_values}
        truth = render_video(scene, params, path, fps=args.fps, duration=args.duration, width=args.width,
                             height=args.height, noise_sd=args.noise, hand=args.hand,
                             rest_frames=rest_frames, seed=args.seed + i,
                             progress=not args.quiet, effects=effect_names, world=world, **style)
        values = ", ".join(f"{k}={truth[k]:.4g}" for k in names if k in truth)
        hidden = f" (hidden: {', '.join(truth['hidden_effects'])})" if truth["hidden_effects"] else ""
        print(f"{path}: {truth['n_frames']} frames at {truth['fps']:g} fps, {values}{hidden}")
    return 0
