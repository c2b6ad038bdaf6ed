"""Physical effects that extend the base sliding-block model (see :mod:`.base`, :mod:`.library`)."""

from galileo_jax.effects.base import (BodyState, Effect, EffectContext, EffectParam, available_effects,
                                      check_applicable, get_effect, register_effect, resolve_effects)
from galileo_jax.effects import library as _library  # noqa: E402,F401 - the shipped effects, registered first

__all__ = ["BodyState", "Effect", "EffectContext", "EffectParam", "available_effects", "check_applicable",
           "get_effect", "register_effect", "resolve_effects"]
