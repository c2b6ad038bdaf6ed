"""Parameters of synthetic videos: given (:func:`resolve_params`) or drawn at random
(:func:`draw_random_params`, :func:`draw_informative_params`: object 1 slides and reaches
object 2), with hidden effects' values (:func:`draw_effect_values`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import mujoco
import numpy as np

from galileo_jax.effects import BodyState, Effect, available_effects, check_applicable
from galileo_jax.effects.runtime import (
    apply_c_model,
    effect_param_names,
    frictions,
    make_context,
    neutral_values,
    split_values,
    surface_frictions,
)
from galileo_jax.errors import GalileoError
from galileo_jax.physics.model import build_model, object_start_pose, set_physics
from galileo_jax.physics.simulate import PhysParams, scene_effects
from galileo_jax.scene import Scene
from galileo_jax.synth.motion import (
    MAX_REDRAWS,
    MIN_REST_FRICTION,
    RANDOM_FRICTION,
    RANDOM_MASS,
    REACH_DISTANCE,
    SLIDE_MARGIN,
    Motion,
    simulate_motion,
)


def resolve_params(scene: Scene, params, effects=()) -> PhysParams:
    """Masses, frictions and effect parameters, from a dict or :class:`PhysParams`.

    Args:
        scene: the scene; its known masses/frictions fill values the dict leaves out.
        params: ``{"m1", "k1", "m2", "k2", <effect parameters>}`` (any subset of the masses
            and frictions that, with the scene's known values, gives every object a mass in kg
            and a friction coefficient; every parameter of the simulated effects, by its name,
            e.g. ``"drag_quadratic"``) or a :class:`PhysParams` with (n_objects,) arrays and,
            when the effects have parameters, ``effects`` in the order of their names.
        effects: extra effects (names or :class:`~galileo_jax.effects.Effect`) simulated on
            top of the scene's own ``scene.effects`` (see :func:`simulate.scene_effects`).

    Returns:
        :class:`PhysParams` of numpy float arrays, shapes (n_objects,); ``effects`` is the
        (n_effect_params,) vector of the effects' values (ordered as
        :func:`~galileo_jax.effects.runtime.effect_param_names`), or None when no effect is
        simulated.

    Raises:
        GalileoError: a value is missing, unknown, non-finite, out of range, or contradicts
            a value the scene fixes; an unknown effect.
    """
    n = scene.n_objects
    effs = scene_effects(scene, effects)
    names = effect_param_names(effs)
    values = None
    if isinstance(params, PhysParams):
        mass = np.asarray(params.mass, dtype=float).reshape(-1)
        friction = np.asarray(params.friction, dtype=float).reshape(-1)
        if mass.shape != (n,) or friction.shape != (n,):
            raise GalileoError(f"PhysParams must have {n} masses and {n} frictions for this scene")
        if params.effects is not None:
            values = np.asarray(params.effects, dtype=float).reshape(-1)
            if values.shape != (len(names),):
                raise GalileoError(f"PhysParams.effects has {values.size} values but the effects take "
                                   f"{len(names)} ({', '.join(names) or 'none'})")
        elif names:
            raise GalileoError(f"PhysParams.effects is None but the effects need values for {', '.join(names)}")
    elif isinstance(params, Mapping):
        base = {f"{p}{i + 1}" for i in range(n) for p in "mk"}
        allowed = base | set(names)
        unknown = sorted(set(params) - allowed)
        if unknown:
            owner = _effect_of_param(unknown[0])
            if owner is not None and unknown[0] not in base:
                raise GalileoError(f"{unknown[0]} is a parameter of effect {owner.name!r}, which is not simulated; "
                                   f"add the effect (effects=[{owner.name!r}], CLI --effect {owner.name}=VALUE)")
            raise GalileoError(f"unknown parameter {unknown[0]!r}; this scene takes {', '.join(sorted(base))}"
                               + (f" and the effects' {', '.join(names)}" if names else ""))
        mass, friction = np.zeros(n), np.zeros(n)
        for i, obj in enumerate(scene.objects):
            for key, known, out in ((f"m{i + 1}", obj.mass, mass), (f"k{i + 1}", obj.friction, friction)):
                given = params.get(key)
                if given is None and known is None:
                    flag = "--" + key
                    raise GalileoError(f"{key} is free in the scene; give its value ({flag})")
                if given is not None and known is not None and not math.isclose(float(given), known, rel_tol=1e-9):
                    raise GalileoError(f"{key} = {given} contradicts the scene, which fixes {key} = {known}; "
                                       f"leave it out or edit the scene")
                out[i] = float(given if given is not None else known)
        if effs:
            values = np.zeros(len(names))
            j = 0
            for e in effs:
                for p in e.params:
                    if params.get(p.name) is None:
                        raise GalileoError(f"effect {e.name!r} needs a value of {p.name} ({p.doc or p.unit}); "
                                           f"give it (CLI: --effect {e.name}=VALUE, e.g. {p.synth_range[0]:g})")
                    values[j] = float(params[p.name])
                    j += 1
    else:
        raise GalileoError("params must be a dict {m1, k1, m2, k2, <effect parameters>} or a PhysParams")
    for i in range(n):
        if not (math.isfinite(mass[i]) and 0 < mass[i] <= 1e3):
            raise GalileoError(f"m{i + 1} = {mass[i]} must be a mass in kg in (0, 1000]")
        if not (math.isfinite(friction[i]) and 0 <= friction[i] <= 10):
            raise GalileoError(f"k{i + 1} = {friction[i]} must be a friction coefficient in [0, 10]")
    if not effs:
        return PhysParams(mass, friction)
    if values is None:  # PhysParams with effects=None and parameterless effects only
        values = np.zeros(0)
    p_list = [p for e in effs for p in e.params]
    for p, v in zip(p_list, values):
        if not (math.isfinite(v) and p.lower <= v <= p.upper):
            raise GalileoError(f"{p.name} = {v:g} is outside the effect's range [{p.lower:g}, {p.upper:g}] {p.unit}".rstrip())
    return PhysParams(mass, friction, values)


def _effect_of_param(name: str) -> Effect | None:
    """The registered effect that has a parameter called ``name``, or None."""
    for e in available_effects().values():
        if name in e.param_names:
            return e
    return None


def effect_value_dict(effects, values) -> dict[str, dict[str, float]]:
    """``{effect name: {parameter: value}}`` of a flat effect-parameter vector (empty dicts for
    effects without parameters)."""
    vals = split_values(effects, np.asarray(values if values is not None else neutral_values(effects), float))
    return {e.name: {p.name: float(x) for p, x in zip(e.params, v if v is not None else [])}
            for e, v in zip(effects, vals)}


def param_dict(params: PhysParams) -> dict[str, float]:
    """``{"m1", "k1", ...}`` of :class:`PhysParams` (plus nothing else)."""
    out = {}
    for i, (m, k) in enumerate(zip(np.asarray(params.mass), np.asarray(params.friction)), start=1):
        out[f"m{i}"] = float(m)
        out[f"k{i}"] = float(k)
    return out


def draw_random_params(scene: Scene, rng: np.random.Generator, margin: float = SLIDE_MARGIN,
                       fixed: Mapping[str, float] | None = None) -> dict[str, float]:
    """Draw the scene's free parameters uniformly, with object 1 sure to slide.

    Masses: uniform on ``RANDOM_MASS`` intersected with ``priors.mass``; frictions uniform on
    ``RANDOM_FRICTION`` intersected with ``priors.friction``; k1 also below
    tan(theta) - ``margin``. Values in ``fixed`` are kept.

    Raises:
        GalileoError: no friction range leaves object 1 sliding (ramp too shallow).
    """
    fixed = dict(fixed or {})
    out = {}
    ma, mb = max(RANDOM_MASS[0], scene.priors.mass[0]), min(RANDOM_MASS[1], scene.priors.mass[1])
    fa, fb = max(RANDOM_FRICTION[0], scene.priors.friction[0]), min(RANDOM_FRICTION[1], scene.priors.friction[1])
    for name in scene.free_parameters():
        if name in fixed:
            continue
        if name.startswith("m"):
            out[name] = float(rng.uniform(ma, mb))
            continue
        hi = min(fb, math.tan(scene.ramp.angle) - margin) if name == "k1" else fb
        if hi <= fa:
            raise GalileoError(f"no friction in [{fa}, {hi:.3g}] lets object 1 slide on a "
                               f"{scene.ramp.angle_deg} degree ramp; use a steeper ramp or widen priors.friction")
        out[name] = float(rng.uniform(fa, hi))
    out.update({k: float(v) for k, v in fixed.items() if v is not None})
    return out


def draw_effect_values(effects, rng: np.random.Generator, fixed: Mapping[str, float] | None = None) -> dict[str, float]:
    """Draw each effect parameter not in ``fixed`` uniformly on its ``synth_range``; keep ``fixed``.

    Returns:
        ``{parameter name: value}`` for every parameter of ``effects`` (in their order).
    """
    fixed = dict(fixed or {})
    out = {}
    for e in effects:
        for p in e.params:
            out[p.name] = float(fixed[p.name]) if p.name in fixed else float(rng.uniform(*p.synth_range))
    return out


def ramp_friction_at_rest(scene: Scene, effects, values: Mapping[str, float], friction) -> float:
    """Object 1's friction coefficient on the ramp at rest after the effects' ``friction`` hooks
    (``k1 + dk_ramp`` for ``ramp_friction``; ``k1`` when no hook changes it).

    Args:
        scene: the scene.
        effects: the simulated effects (Effect objects).
        values: their parameter values by name.
        friction: (n_objects,) base friction coefficients.
    """
    return float(frictions_at_rest(scene, effects, values, friction)[0, 0])


def frictions_at_rest(scene: Scene, effects, values: Mapping[str, float], friction) -> np.ndarray:
    """(n_objects, 2) friction coefficients at rest (on the ramp, on the floor) after the
    effects' ``model`` hooks (e.g. ``ramp_friction``) and ``friction`` hooks (arguments as
    :func:`ramp_friction_at_rest`)."""
    effects = tuple(effects)
    friction = np.asarray(friction, dtype=float).reshape(-1)
    if not any(e.friction is not None or e.model is not None for e in effects):
        return np.repeat(friction[:, None], 2, axis=1)
    n = scene.n_objects
    model, index = build_model(scene, effects=effects)
    data = mujoco.MjData(model)
    set_physics(model, data, index, np.asarray(model.body_mass[list(index.body)]), friction)
    ctx = make_context(scene, index, 1.0 / 240.0)
    flat = np.asarray([values[p] for p in effect_param_names(effects)], dtype=float)
    apply_c_model(effects, flat, model, data, index, ctx)
    k = surface_frictions(model.pair_friction, ctx, friction)
    pos = np.stack([object_start_pose(scene, i)[0] for i in range(n)])
    state = BodyState(pos, np.zeros((n, 3)), np.ones(n))
    out = frictions(effects, split_values(effects, flat), k, state, ctx)
    return np.asarray(k if out is None else out, dtype=float)


def degenerate_motion(scene: Scene, motion: Motion) -> str | None:
    """Why ``motion`` would make an uninformative video, or None if it is informative.

    Informative: with two objects, object 1 reaches object 2 and moves it (more than
    :data:`REACH_DISTANCE`); with one object starting on the ramp, its centre passes the ramp's
    foot (it reaches the floor); with one object starting on the floor, it moves more than
    :data:`REACH_DISTANCE`. All within the video.
    """
    pos = motion.positions
    travel = np.linalg.norm(pos - pos[0], axis=-1).max(axis=0)
    if scene.n_objects == 2:
        if travel[1] <= REACH_DISTANCE:
            return "object 1 does not reach object 2 within the video"
        return None
    if scene.placement(0) == "ramp":
        if pos[:, 0, 0].max() <= 0.0:
            return "object 1 does not reach the floor within the video"
        return None
    if travel[0] <= REACH_DISTANCE:
        return "object 1 does not move"
    return None


def draw_informative_params(scene: Scene, rng: np.random.Generator, effects, *, fps: float, rest_frames: int,
                            n_frames: int | None = None, fixed: Mapping[str, float] | None = None,
                            fixed_effects: Mapping[str, float] | None = None,
                            attempts: int = MAX_REDRAWS) -> dict[str, float]:
    """Random free parameters and effect values that give an informative video.

    Rule (documented in the CLI help): the effect parameters not in ``fixed_effects`` are drawn
    uniformly on their ``synth_range``; then the scene's free masses and frictions as
    :func:`draw_random_params` draws them, with object 1's friction on the ramp *after the
    effects* (e.g. ``k1 + dk_ramp`` for ``ramp_friction``, see :func:`ramp_friction_at_rest`)
    below tan(theta) - :data:`SLIDE_MARGIN`, and no friction at rest lowered by the effects
    below :data:`MIN_REST_FRICTION` (:func:`frictions_at_rest`); then the motion is simulated in C MuJoCo for the
    video's length and must pass :func:`degenerate_motion` (object 1 reaches object 2, or the
    floor). A draw that breaks a rule is thrown away and everything is drawn again, at most
    ``attempts`` times.

    Args:
        scene: the scene.
        rng: random generator.
        effects: the simulated effects (names or Effects; the scene's own are added).
        fps, rest_frames, n_frames: the video's timing (``n_frames`` None: automatic length).
        fixed: base parameters to keep (``m1``, ...).
        fixed_effects: effect parameter values to keep, by parameter name.
        attempts: draws before giving up.

    Returns:
        ``{"m1", "k1", ..., <effect parameters>}``, ready for :func:`render_video`.

    Raises:
        GalileoError: no draw in ``attempts`` gave an informative video (the message says why
            the last one failed).
    """
    effs = scene_effects(scene, effects)
    check_applicable(effs, scene)
    fixed = dict(fixed or {})
    limit = math.tan(scene.ramp.angle) - SLIDE_MARGIN
    on_ramp = scene.placement(0) == "ramp"
    reason = "no draw was tried"
    for _ in range(max(1, attempts)):
        values = draw_effect_values(effs, rng, fixed_effects)
        probe = np.full(scene.n_objects, max(limit, 0.0))
        offset = max(0.0, ramp_friction_at_rest(scene, effs, values, probe) - probe[0]) if on_ramp else 0.0
        try:
            base = draw_random_params(scene, rng, margin=SLIDE_MARGIN + offset, fixed=fixed)
        except GalileoError as err:
            reason = str(err).split(";")[0]
            continue
        params = {**base, **values}
        phys = resolve_params(scene, params, effs)
        k_rest = frictions_at_rest(scene, effs, values, phys.friction)  # (n_objects, ramp / floor)
        if on_ramp:
            k_ramp = float(k_rest[0, 0])
            if k_ramp >= limit:
                reason = (f"object 1's friction on the ramp {k_ramp:.3g} is not below "
                          f"tan(theta) - {SLIDE_MARGIN} = {limit:.3g}")
                continue
        floor = np.minimum(MIN_REST_FRICTION, np.asarray(phys.friction, dtype=float))[:, None]
        if np.any(k_rest < floor - 1e-12):
            reason = (f"the effects lower a friction coefficient at rest to {k_rest.min():.3g}, below "
                      f"{MIN_REST_FRICTION}: a resting object would drift")
            continue
        motion = simulate_motion(scene, phys, fps, rest_frames, n_frames, effects=effs)
        reason = degenerate_motion(scene, motion)
        if reason is None:
            return params
    names = ", ".join(e.name for e in effs)
    raise GalileoError(f"no random draw in {attempts} tries gives an informative video with effect(s) {names} "
                       f"(last: {reason}); fix fewer values, lengthen --duration or use a steeper ramp")
