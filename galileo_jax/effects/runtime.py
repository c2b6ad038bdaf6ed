"""Applying effects inside a simulator: shared by the MJX rollout and the C MuJoCo renderer.

The hooks of :class:`~galileo_jax.effects.Effect` are pure array functions; these helpers
split a flat parameter vector between the active effects, build the static
:class:`EffectContext` of a compiled model, and evaluate the per-step hooks. With NumPy
inputs the results can be written into a ``mujoco.MjModel``/``MjData``
(:func:`apply_c_model`, :func:`c_step`), so synthetic videos with a hidden effect use exactly
the physics that the fit adds.
"""

from __future__ import annotations

import math
from typing import Sequence

import jax.numpy as jnp
import mujoco
import numpy as np

from galileo_jax.effects.base import BodyState, Effect, EffectContext


def n_effect_params(effects: Sequence[Effect]) -> int:
    """Total number of parameters of ``effects``."""
    return sum(len(e.params) for e in effects)


def effect_param_names(effects: Sequence[Effect]) -> tuple[str, ...]:
    """Parameter names of ``effects`` in order (the layout of the flat ``values`` vector)."""
    return tuple(p.name for e in effects for p in e.params)


def neutral_values(effects: Sequence[Effect]) -> np.ndarray:
    """(n_params,) neutral values of ``effects`` (the base model)."""
    return np.asarray([p.neutral for e in effects for p in e.params], np.float64)


def split_values(effects: Sequence[Effect], values) -> list:
    """Split a flat (n_params,) vector into one (len(effect.params),) slice per effect."""
    out, j = [], 0
    for e in effects:
        k = len(e.params)
        out.append(values[j:j + k] if k else None)
        j += k
    return out


def make_context(scene, index, dt: float) -> EffectContext:
    """The static :class:`EffectContext` of a compiled scene model."""
    th = scene.ramp.angle
    return EffectContext(
        n_objects=scene.n_objects,
        on_ramp=tuple(scene.placement(i) == "ramp" for i in range(scene.n_objects)),
        ramp_angle=th, gravity=float(scene.gravity),
        downhill=(math.cos(th), 0.0, -math.sin(th)), dt=float(dt), object_pair=int(index.object_pair),
        bodies=tuple(int(b) for b in index.body), dofs=tuple(int(d) for d in index.dof),
        ramp_pairs=tuple(int(q) for q in index.ramp_pair), floor_pairs=tuple(int(q) for q in index.floor_pair))


def surface_frictions(pair_friction, ctx: EffectContext, k_base):
    """(n_objects, 2) sliding friction coefficients on (ramp, floor) of a model's contact pairs
    (``pair_friction`` (n_pairs, 5), after the masses, frictions and the effects' model updates are
    set), jnp; an object with no ramp pair gets its base coefficient ``k_base`` (n_objects,) there.
    The starting point of the per-step ``friction`` hooks."""
    pf = jnp.asarray(pair_friction)
    k_base = jnp.asarray(k_base)
    cols = []
    for pairs in (ctx.ramp_pairs, ctx.floor_pairs):
        cols.append(jnp.stack([pf[q, 0] if q >= 0 else k_base[i] for i, q in enumerate(pairs)]))
    return jnp.stack(cols, axis=-1)


class _Fields:
    """Read-only mapping view of a model's fields by name (``MjModel`` or ``mjx.Model``)."""

    def __init__(self, model):
        self._model = model

    def __getitem__(self, name: str):
        return getattr(self._model, name)


def model_updates(effects, values_list, model, ctx, engine: str = "mjx") -> dict:
    """Merged field updates of the effects' ``model`` hooks for ``model`` (later effects see earlier
    updates); for ``engine`` "mujoco" also their ``c_model`` hooks (the C engine's form of a
    per-step effect, :class:`~galileo_jax.effects.base.Effect`)."""
    updates: dict = {}

    class _View(_Fields):
        def __getitem__(self, name):
            return updates[name] if name in updates else getattr(model, name)

    for e, v in zip(effects, values_list):
        if e.model is not None:
            updates.update(e.model(_View(model), v, ctx))
        if engine == "mujoco" and e.c_model is not None:
            updates.update(e.c_model(_View(model), v, ctx))
    return updates


def initial_velocity(effects, values_list, ctx):
    """(n_objects, 3) summed release velocities of the effects (zeros if none), jnp."""
    v = jnp.zeros((ctx.n_objects, 3))
    for e, vals in zip(effects, values_list):
        if e.initial_velocity is not None:
            v = v + e.initial_velocity(vals, ctx)
    return v


def release_delay(effects, values_list, k, ctx):
    """Summed ``release_delay`` hooks (s, jnp scalar; 0 if none): how much later than the fitted
    release time the motion with these effects starts. ``k``: (n_objects,) base friction."""
    delay = jnp.zeros(())
    for e, vals in zip(effects, values_list):
        if e.release_delay is not None:
            delay = delay + e.release_delay(vals, k, ctx)
    return delay


def forces(effects, values_list, state: BodyState, ctx):
    """(n_objects, 3) summed world forces of the effects, or None if no effect has a force."""
    total = None
    for e, vals in zip(effects, values_list):
        if e.force is not None:
            f = e.force(state, vals, ctx)
            total = f if total is None else total + f
    return total


def frictions(effects, values_list, k_surface, state: BodyState, ctx):
    """(n_objects, 2) friction coefficients on (ramp, floor) after the effects' ``friction``
    hooks, or None if no effect has one. ``k_surface``: (n_objects, 2) the coefficients before
    the hooks (:func:`surface_frictions`: the objects' own, after the effects' model updates)."""
    hooks = [(e, v) for e, v in zip(effects, values_list) if e.friction is not None]
    if not hooks:
        return None
    k = jnp.asarray(k_surface)
    for e, v in hooks:
        k = e.friction(k, state, v, ctx)
    return k


def has_step_hooks(effects) -> bool:
    """True when some effect acts every step (force or friction)."""
    return any(e.force is not None or e.friction is not None for e in effects)


def needs_mjx(effects) -> bool:
    """True when some effect acts every step and has no C MuJoCo form (``c_model``): only MJX
    can simulate it."""
    return any(has_step_hooks((e,)) and e.c_model is None for e in effects)


# ----------------------------------------------------------------------------- C MuJoCo
def c_state(model: mujoco.MjModel, data: mujoco.MjData, index) -> BodyState:
    """:class:`BodyState` of a C simulation (NumPy)."""
    pos = np.stack([data.qpos[a:a + 3] for a in index.qpos])
    vel = np.stack([data.qvel[d:d + 3] for d in index.dof])
    return BodyState(pos, vel, np.asarray(model.body_mass[list(index.body)]))


def apply_c_model(effects, values, model: mujoco.MjModel, data: mujoco.MjData, index, ctx) -> None:
    """Once before release (masses and frictions already set): write the effects' model updates
    and release velocities into C MuJoCo (NumPy in, the hooks evaluated eagerly; the renderer's
    path, outside ``jit``)."""
    vals = split_values(effects, np.asarray(values, np.float64))
    for name, value in model_updates(effects, vals, model, ctx).items():
        getattr(model, name)[...] = np.asarray(value)
    v0 = np.asarray(initial_velocity(effects, vals, ctx))
    for i, d in enumerate(index.dof):
        data.qvel[d:d + 3] += v0[i]


def c_step(effects, values, model: mujoco.MjModel, data: mujoco.MjData, index, ctx, k_surface: np.ndarray) -> None:
    """One C MuJoCo physics step with the effects' per-step forces and frictions; ``k_surface``
    (n_objects, 2): :func:`surface_frictions` of the model after :func:`apply_c_model`."""
    vals = split_values(effects, np.asarray(values, np.float64))
    state = c_state(model, data, index)
    k = frictions(effects, vals, k_surface, state, ctx)
    if k is not None:
        k = np.asarray(k)
        for i in range(ctx.n_objects):
            for col, pid in enumerate((index.ramp_pair[i], index.floor_pair[i])):
                if pid >= 0:
                    model.pair_friction[pid, 0:2] = k[i, col]
    f = forces(effects, vals, state, ctx)
    if f is not None:
        f = np.asarray(f)
        for i, b in enumerate(index.body):
            data.xfrc_applied[b, 0:3] = f[i]
    mujoco.mj_step(model, data)
