"""Physical effects: small, documented additions to the base sliding-block model.

The base model (issue 2) is Galileo's: rigid blocks that slide with Coulomb friction on a
ramp and a floor, and collide with MuJoCo's default (nearly inelastic) contact. Real
videos show more: air drag, bouncy impacts, a ramp rougher than the floor, a hand that pushes
instead of letting go, a pipe that rolls. An :class:`Effect` adds one such piece of physics
with a few parameters (:class:`EffectParam`) whose *neutral* value gives back the base model
exactly, a uniform prior on bounds, and hooks that act inside the simulator.

Hooks (all optional; each is a pure function written with ``jax.numpy`` so that the same
code runs inside the jitted MJX rollout and, on NumPy inputs, in the C MuJoCo renderer of
:mod:`galileo_jax.synth`):

* ``build(spec, scene)``: change the model's structure before compiling (``mujoco.MjSpec``),
  e.g. the true shape and rotational inertia of a rolling object. Effects with a ``build``
  and no parameters are *structural*: they have no continuous path back to the base model,
  so the score screen of :mod:`galileo_jax.diagnose` cannot rank them and they are always
  refitted.
* ``model(fields, values, ctx)``: once per rollout, return updated model fields (a dict of
  arrays named as in ``mujoco.MjModel``/``mjx.Model``, e.g. ``pair_solref``); ``fields`` already
  hold the rollout's masses and friction coefficients. Effects with only ``model``,
  ``initial_velocity``, ``build`` and ``release_delay`` hooks also run on the C MuJoCo engine,
  which evaluates the hooks in JAX before the host rollout (:mod:`galileo_jax.physics.simulate_c`).
* ``initial_velocity(values, ctx)``: (n_objects, 3) world linear velocity added at release, m/s.
* ``force(state, values, ctx)``: (n_objects, 3) world force on each object's centre of mass
  in N, applied every physics step through ``xfrc_applied``.
* ``friction(k, state, values, ctx)``: every step, map the (n_objects, 2) sliding friction
  coefficients on (ramp, floor) to new ones (velocity-dependent friction, a ramp rougher
  than the floor).
* ``release_delay(values, k, ctx)``: scalar, seconds by which the effect's motion starts
  later than the fitted release time; ``k`` is the (n_objects,) base friction. It only acts
  in the fit (:class:`~galileo_jax.inference.problem.Problem`), not in the simulator: it keeps
  the fitted release time meaning what it means in the base model, so that an effect that
  changes the start of the motion does not trade off against the release time (the base
  fit then starts the refit near its optimum). ``initial_push`` uses it: a pushed object
  leaves when a push-free one released at the fitted time would have reached v0.
* ``c_build(spec, scene)`` and ``c_model(fields, values, ctx)``: the C MuJoCo engine's form of
  an effect whose ``force`` or ``friction`` acts every step (which the open-loop
  ``mujoco.rollout`` cannot call): a structure added only to models built for that engine and a
  once-per-rollout field update, with which MuJoCo's own physics applies the same force. An
  effect with them runs on both engines (MJX through ``force``/``friction``, C MuJoCo through
  these); ``quadratic_drag`` uses MuJoCo's ellipsoid fluid model.

``values`` is the (n_params,) array of the effect's parameters in the order of ``params``;
``state`` a :class:`BodyState`; ``ctx`` the scene's :class:`EffectContext`.

Registry: :func:`register_effect` adds an effect under its name (a user's own effect takes a
few lines, see ``tests/test_effects.py``); third-party packages can expose effects through the
``galileo_jax.effects`` entry-point group (an ``Effect`` object or a zero-argument function
returning one). :func:`get_effect` looks a name up; :func:`available_effects` lists them.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field
from importlib import metadata
from typing import Any, Callable, NamedTuple

from galileo_jax.errors import GalileoError

#: Entry-point group through which other packages register effects.
ENTRY_POINT_GROUP = "galileo_jax.effects"


class BodyState(NamedTuple):
    """Kinematic state of the free objects at one physics step (arrays, jnp or np).

    Attributes:
        pos: (n_objects, 3) world position of each object's centre, m.
        vel: (n_objects, 3) world linear velocity of each centre, m/s.
        mass: (n_objects,) masses in the simulator, kg.
    """

    pos: Any
    vel: Any
    mass: Any


@dataclass(frozen=True)
class EffectContext:
    """Facts about the scene an effect may use.

    ``ramp_angle``, ``gravity`` and ``downhill`` are numbers of the scene: inside a compiled
    program they are traced arrays (:meth:`~galileo_jax.physics.simulate.Simulator.with_arrays`), so
    hooks use ``jnp`` on them, never ``math``. The other fields are static Python values.

    Attributes:
        n_objects: number of free objects.
        on_ramp: per object, True if it starts on the ramp.
        ramp_angle: ramp angle theta in rad.
        gravity: g in m/s^2.
        downhill: (3,) unit vector down the slope, world frame.
        dt: physics timestep in s.
        object_pair: id of the object-object contact pair, or -1.
        bodies, dofs: per object its body id and the address of its first free-joint dof
            (the three translational dofs, world frame, come first).
        ramp_pairs, floor_pairs: per object the id of its contact pair with the ramp (-1 if it
            starts on the floor) and with the floor; ``pair_friction[id, 0]`` is its sliding friction there.
    """

    n_objects: int
    on_ramp: tuple[bool, ...]
    ramp_angle: float
    gravity: float
    downhill: tuple[float, float, float]
    dt: float
    object_pair: int
    bodies: tuple[int, ...] = ()
    dofs: tuple[int, ...] = ()
    ramp_pairs: tuple[int, ...] = ()
    floor_pairs: tuple[int, ...] = ()


@dataclass(frozen=True)
class EffectParam:
    """One parameter of an effect.

    Attributes:
        name: coordinate name, unique across effects (shown in reports), e.g. ``"drag_quadratic"``.
        unit: SI unit as text (``"1/m"``, ``"m/s"``, ``""`` for dimensionless).
        neutral: value that gives back the base model.
        lower, upper: bounds of the uniform prior (the neutral value may sit on a bound).
        screen_step: step from the neutral value used by the score screen's finite difference
            (a small but clearly non-zero value of the effect).
        synth_range: range of values drawn for synthetic videos with this hidden effect
            (large enough to be visible in a 1-2 s video).
        doc: one-line meaning.
        ridge: base-model parameters that move with this one along the likelihood's ridge, as
            ``(name, coefficient)`` pairs: a change d of this parameter is screened and started
            from with ``name`` changed by ``coefficient * d`` as well. E.g. ``dk_ramp`` with
            ``(("k1", -1.0),)``: the ramp's friction k1 + dk_ramp, which the slide down the ramp
            measures sharply, stays where the base fit put it, and only the floor's changes
            (:func:`galileo_jax.criticism.screening.screen_candidates`).
        negligible: half-width of the effect's region of practical equivalence about ``neutral``
            (a ROPE: Kruschke 2018, "Rejecting or accepting parameter values in Bayesian
            estimation", Adv. Methods Pract. Psychol. Sci. 1, 270): a fitted value within it does
            not change the physics beyond what the base model itself varies by, so ``diagnose``
            does not name the effect for it, however much the fit improves
            (:func:`galileo_jax.criticism.nested.negligible`). 0 (the default): no such region.
    """

    name: str
    unit: str
    neutral: float
    lower: float
    upper: float
    screen_step: float
    synth_range: tuple[float, float]
    doc: str = ""
    ridge: tuple[tuple[str, float], ...] = ()
    negligible: float = 0.0

    @property
    def one_sided(self) -> bool:
        """True when the neutral value is on a bound (likelihood-ratio tests need the boundary correction)."""
        return math.isclose(self.neutral, self.lower) or math.isclose(self.neutral, self.upper)


@dataclass(frozen=True)
class Effect:
    """A physical effect (see the module docstring for the hooks).

    Attributes:
        name: registry name, e.g. ``"quadratic_drag"``.
        summary: one line: the physics and its formula.
        params: the effect's parameters.
        evidence: which measurement shows the effect best (used to say how to separate
            effects the data cannot tell apart).
        source: where the formula comes from.
        search_restarts: independent CMA-ES searches of a ``diagnose`` refit that frees this
            effect (:func:`galileo_jax.criticism.diagnosis.search_then_lm`; 1 for a likelihood with one
            basin to find, more where it is multimodal, e.g. at impacts).
        applies: ``scene -> None`` if the effect can act in the scene, else a reason (str).
        build, model, initial_velocity, force, friction, release_delay, c_build, c_model: hooks
            (module docstring).
    """

    name: str
    summary: str
    params: tuple[EffectParam, ...] = ()
    evidence: str = ""
    source: str = ""
    search_restarts: int = 1
    applies: Callable[[Any], str | None] = field(default=lambda scene: None, repr=False)
    build: Callable | None = field(default=None, repr=False)
    model: Callable | None = field(default=None, repr=False)
    initial_velocity: Callable | None = field(default=None, repr=False)
    force: Callable | None = field(default=None, repr=False)
    friction: Callable | None = field(default=None, repr=False)
    release_delay: Callable | None = field(default=None, repr=False)
    c_build: Callable | None = field(default=None, repr=False)
    c_model: Callable | None = field(default=None, repr=False)

    @property
    def structural(self) -> bool:
        """True for effects with no continuous parameter (always refitted, never screened)."""
        return not self.params

    @property
    def param_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.params)


_REGISTRY: dict[str, Effect] = {}
_ENTRY_POINTS_LOADED = False


def register_effect(effect: Effect, *, replace: bool = False) -> Effect:
    """Add ``effect`` to the registry under ``effect.name`` and return it.

    The shipped effects (:mod:`galileo_jax.effects.library`) are registered when the package
    :mod:`galileo_jax.effects` is imported, before any user code can register one: a user's
    effect of a shipped name needs ``replace=True``, and is not overwritten later.

    Raises:
        ValueError: the name is taken (pass ``replace=True`` to overwrite), or one of its
            parameter names is already used by another effect, or a parameter's neutral
            value lies outside its bounds.
    """
    if not isinstance(effect, Effect):
        raise ValueError(f"register_effect needs an Effect, got {type(effect).__name__}")
    if effect.name in _REGISTRY and not replace:
        raise ValueError(f"an effect named {effect.name!r} is already registered; pass replace=True to overwrite it")
    for p in effect.params:
        if not p.lower <= p.neutral <= p.upper or not p.lower < p.upper:
            raise ValueError(f"effect {effect.name}: parameter {p.name} needs lower <= neutral <= upper, lower < upper")
        for other in _REGISTRY.values():
            if other.name != effect.name and p.name in other.param_names:
                raise ValueError(f"parameter name {p.name!r} is already used by effect {other.name!r}")
    _REGISTRY[effect.name] = effect
    return effect


def _load_entry_points() -> None:
    global _ENTRY_POINTS_LOADED
    if _ENTRY_POINTS_LOADED:
        return
    _ENTRY_POINTS_LOADED = True
    for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
        obj = ep.load()
        effect = obj() if callable(obj) and not isinstance(obj, Effect) else obj
        register_effect(effect, replace=True)


def available_effects() -> dict[str, Effect]:
    """All registered effects by name (the shipped library, user registrations, entry points)."""
    _load_entry_points()
    return dict(_REGISTRY)


def get_effect(name: str) -> Effect:
    """The registered effect called ``name``.

    Raises:
        GalileoError: unknown name (the message lists the known ones and a close match).
    """
    effects = available_effects()
    if name not in effects:
        close = difflib.get_close_matches(name, list(effects), n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        raise GalileoError(f"unknown effect {name!r}; {hint}known effects: {', '.join(sorted(effects))}")
    return effects[name]


def resolve_effects(names) -> tuple[Effect, ...]:
    """Effects from names (a comma-separated string, a list of names/Effects, or None), de-duplicated in order.

    Raises:
        GalileoError: an unknown name.
    """
    if names is None:
        return ()
    if isinstance(names, str):
        names = [n.strip() for n in names.split(",") if n.strip()]
    out: list[Effect] = []
    for n in names:
        e = n if isinstance(n, Effect) else get_effect(str(n))
        if e.name not in [x.name for x in out]:
            out.append(e)
    return tuple(out)


def check_applicable(effects, scene) -> None:
    """Raise GalileoError naming the first effect that cannot act in ``scene`` and why."""
    for e in effects:
        why = e.applies(scene)
        if why:
            raise GalileoError(f"effect {e.name!r} does not apply to scene {scene.name!r}: {why}")
