"""Synthetic ramp videos with exact ground truth, rendered with MuJoCo.

The package: :mod:`.draws` (parameters given or drawn), :mod:`.motion` (the physics, C MuJoCo
step by step), :mod:`.video` (frames, files, :func:`render_video`), :mod:`.cli` (the command
line); their public names are importable from here.

:func:`render_video` simulates a scene in C MuJoCo for given masses and friction coefficients
(and optionally hidden physical effects, see below) and renders it through a front camera
(:mod:`galileo_jax.render`): orthographic by default, so the pixel scale is exact at any
depth, or perspective, exact in the plane of motion; it writes three files next to each other
(each atomically):

* ``<stem>.mp4``: the video (mp4v), ``width`` x ``height``, ``fps`` frames per second, with
  Gaussian pixel noise of SD ``noise_sd`` grey levels (before compression).
* ``<stem>.yaml``: the input scene with its ``camera`` block replaced by the exact
  calibration (``pixels_per_metre`` in the plane of motion, ``foot_pixel`` = pixel of the
  world origin, i.e. the ramp foot in the plane of motion, ``ramp_direction: right`` or
  ``left``, ``roll_deg: 0``), and ``video.fps`` only when the container's frame rate differs
  from ``fps``.
* ``<stem>.truth.json``: the ground truth (see :func:`truth_record`).

Timeline: frame k is shown at t_k = k / fps, k = 0..N-1. The objects rest at their start
poses (optionally held by a hand) for ``rest_frames`` frames and are released at
``release_time = rest_frames / fps``; frame k >= rest_frames shows the state after
(k - rest_frames) * substeps physics steps of dt = 1 / (fps * substeps), the timestep of
:func:`galileo_jax.physics.simulate.physics_timestep`. This is the sampling of
:func:`galileo_jax.physics.simulate.velocity_profile` with the same ``frame_times`` and
``release_time``, so the MJX simulator and the video can be compared sample by sample.

Masses and frictions are set as :func:`galileo_jax.physics.simulate.apply_params` sets them in MJX:
``body_mass``, ``body_inertia`` scaled with the mass, ``pair_friction[:, 0:2]`` of each
object's pairs with the ramp and floor, then ``mj_setConst`` recomputes ``invweight0``.

Rendering needs an OpenGL context: ``MUJOCO_GL=egl`` (set by default on importing galileo_jax) with Mesa's
software EGL works without a GPU; on Debian/Ubuntu install
``libegl1 libegl-mesa0 libopengl0 libgl1-mesa-dri``.

CLI::

    python -m galileo_jax.synth --scene scenes/ramp_20.yaml --m1 0.6 --k1 0.15 --m2 0.3 \\
        --k2 0.25 --out out/ [--fps 30] [--duration S] [--noise 2] [--hand] [--seed 0] \\
        [--random N] [--effect NAME[=VALUE] ...] [--width 640] [--height 360] [--rest 0.3] \\
        [--look checker|plain] [--colour R,G,B ...] [--camera orthographic|perspective] \\
        [--distance 2.2] [--left | --direction right|left] [--blur N] [--shutter 0.5] \\
        [--backdrop plain|clutter]

``--out`` is a ``.mp4`` path or a folder (``<scene name>.mp4``, or ``<scene name>_NNN.mp4``
with ``--random N``).

How the video looks (:func:`render_video`; the defaults give the original look):

* ``--look plain``: each object one flat colour instead of the checker texture;
  ``--colour R,G,B`` (0..1, once per object) sets the base colours of either look.
* ``--camera perspective [--distance D]``: a pinhole D m (default 2.2) from the plane of
  motion, looking straight at it, with fovy = 2 atan((H/2) / (scale D)): the written
  ``pixels_per_metre`` and ``foot_pixel`` are exact in the plane of the objects' centres,
  nearer surfaces (an object's front face) look slightly larger.
* ``--left``: object 1 moves to the left of the image (the scene seen from its other side;
  the scene file says ``ramp_direction: left``).
* ``--blur N [--shutter S]``: motion blur, the average of N sub-frames spread over the
  fraction S (default 0.5) of the frame interval around each frame time, each showing the
  state interpolated between the physics steps around it (dt = 1 / (fps substeps)). A camera's
  blur is a continuous streak: give enough sub-frames that they lie about 1 px apart at the
  fastest object (a 40 px/frame object with S = 0.5 needs about 20).
* ``--backdrop clutter``: a backdrop wall with posters, shelves, cables and blobs (seeded by
  ``--seed``) instead of the plain grey one.
* Low resolutions (e.g. ``--width 320 --height 240``) work with all of these.

The truth JSON then also records ``pixels_front`` (the projected centre of each object's face
toward the camera) and with blur ``pixels_exposure`` (the mean projected centre over each
frame's exposure); see :func:`truth_record`::

    python -m galileo_jax.synth --scene scenes/ramp_20.yaml --m1 0.6 --k1 0.2 --m2 0.3 --k2 0.25 \\
        --camera perspective --look plain --left --blur 20 --backdrop clutter --out out/world.mp4

Hidden effects: ``--effect NAME=VALUE`` (repeatable) simulates a physical effect of
:mod:`galileo_jax.effects` that the base model lacks, e.g. ``--effect quadratic_drag=0.9``
(``NAME=V1,V2`` for an effect with several parameters; ``NAME`` alone for one without, such as
``rolling``, or with ``--random`` to draw the value uniformly from the parameter's
``synth_range``; ``--effect none``: no effect). The effect acts in the C MuJoCo simulation
through the same hooks as in the MJX fit (:func:`simulate_motion`), its values go into the
truth JSON (``effects``, ``hidden_effects`` and each parameter by name at top level), and the
written scene YAML does not mention it (the scene's own ``effects`` are kept)::

    python -m galileo_jax.synth --scene scenes/ramp_20.yaml --random 5 --effect quadratic_drag --out out/

With ``--random`` and effects, each draw must give an informative video
(:func:`draw_informative_params`): object 1's friction on the ramp after the effects (k1 +
dk_ramp for ``ramp_friction``) below tan(theta) - 0.05, and in the simulated motion object 1
reaches object 2 and moves it (one object: reaches the floor) within the video; otherwise
everything is drawn again, at most 20 times. Without effects the draws are unchanged.

The shipped example was made with::

    python -m galileo_jax.synth --scene scenes/ramp_20.yaml --m1 0.6 --k1 0.2 --m2 0.3 \
        --k2 0.25 --hand --noise 2 --rest 0.5 --duration 3.0 --seed 0 \
        --out examples/ramp20_example.mp4
"""

from __future__ import annotations

from galileo_jax.synth.cli import main, parse_effect_options
from galileo_jax.synth.draws import (
    degenerate_motion,
    draw_effect_values,
    draw_informative_params,
    draw_random_params,
    effect_value_dict,
    frictions_at_rest,
    param_dict,
    ramp_friction_at_rest,
    resolve_params,
)
from galileo_jax.synth.motion import (
    MAX_BLUR,
    MAX_REDRAWS,
    MAX_SECONDS,
    MIN_REST_FRICTION,
    RANDOM_FRICTION,
    RANDOM_MASS,
    REACH_DISTANCE,
    REST_SECONDS,
    REST_SPEED,
    SETTLE_SECONDS,
    SLIDE_MARGIN,
    Motion,
    exposure_times,
    simulate_motion,
)
from galileo_jax.synth.video import (
    calibrated_scene,
    check_options,
    check_style,
    render_frames,
    render_video,
    truth_record,
    write_video,
)

__all__ = [
    "MAX_BLUR",
    "MAX_REDRAWS",
    "MAX_SECONDS",
    "MIN_REST_FRICTION",
    "Motion",
    "RANDOM_FRICTION",
    "RANDOM_MASS",
    "REACH_DISTANCE",
    "REST_SECONDS",
    "REST_SPEED",
    "SETTLE_SECONDS",
    "SLIDE_MARGIN",
    "calibrated_scene",
    "check_options",
    "check_style",
    "degenerate_motion",
    "draw_effect_values",
    "draw_informative_params",
    "draw_random_params",
    "effect_value_dict",
    "exposure_times",
    "frictions_at_rest",
    "main",
    "param_dict",
    "parse_effect_options",
    "ramp_friction_at_rest",
    "render_frames",
    "render_video",
    "resolve_params",
    "simulate_motion",
    "truth_record",
    "write_video",
]
