"""Calibration errors that mimic a physical effect: a ramp friction ``dk_ramp`` acts on a
sliding object like an error in the ramp's angle (:func:`equivalent_angle_error`), and
:func:`angle_alternative` says in ``diagnose``'s report whether the angle could be off by that
much (``DiagnoseSettings.angle_tolerance_deg``).
"""

from __future__ import annotations

import math

from galileo_jax.criticism.models import ModelFit, base_name
from galileo_jax.scene import Scene


def equivalent_angle_error(angle: float, k: float, dk_ramp: float) -> float:
    """The error in a ramp's angle (rad) that changes an object's slide acceleration as a ramp
    friction ``dk_ramp`` does.

    Sliding down the ramp, a = g (sin(theta) - k cos(theta)) (Coulomb friction). A ramp
    friction k + dk at the stated angle theta gives the same a as friction k at theta + delta when
    sin(theta + delta) - k cos(theta + delta) = sin(theta) - (k + dk) cos(theta), i.e.
    theta + delta = atan(k) + asin((sin(theta) - (k + dk) cos(theta)) / sqrt(1 + k^2)). On the
    floor neither acts, so the velocity profiles of the two differ only through the normal force
    on the ramp (second order in delta). Example: theta = 20 deg, k = 0.2: dk = -0.06 is
    delta = +3.2 deg.

    Args:
        angle: the scene's ramp angle theta (rad).
        k: the object's friction coefficient (on the floor).
        dk_ramp: ramp friction minus floor friction (``ramp_friction``'s parameter).

    Returns:
        delta in rad (> 0: the ramp would be steeper than stated); nan if no angle matches.
    """
    rhs = (math.sin(angle) - (k + dk_ramp) * math.cos(angle)) / math.sqrt(1.0 + k * k)
    if abs(rhs) > 1.0:
        return float("nan")
    return math.atan(k) + math.asin(rhs) - angle


def angle_alternative(fit: ModelFit, scene: Scene, tolerance_deg: float) -> dict | None:
    """For a fitted model with ``ramp_friction``: the ramp-angle error that would mimic its
    ``dk_ramp`` for object 1 (:func:`equivalent_angle_error`), and a sentence saying whether that
    is within ``tolerance_deg``. None when the model has no ramp friction."""
    params = fit.summary["parameters"]
    dk = next((v.get("best") for n, v in params.items() if base_name(n) == "dk_ramp"), None)
    k = next((v.get("best") for n, v in params.items() if base_name(n) == "k1"), None)
    if dk is None or k is None or scene.placement(0) != "ramp":
        return None
    delta = math.degrees(equivalent_angle_error(scene.ramp.angle, float(k), float(dk)))
    if not math.isfinite(delta):
        return None
    within = abs(delta) <= tolerance_deg
    what = "steeper" if delta > 0 else "shallower"
    lead = (f"ramp_friction (dk_ramp {dk:+.3f}) acts on object 1 like the ramp being {abs(delta):.1f} deg {what} than "
            f"the scene's {scene.ramp.angle_deg:g} deg")
    if within:
        message = (f"{lead}: within the +-{tolerance_deg:g} deg an angle is usually measured to, so this may be an error "
                   "in the ramp angle, not the surface; measure the angle to better than "
                   f"{max(abs(delta) / 2, 0.1):.1f} deg to tell them apart.")
    else:
        message = (f"{lead}: more than the +-{tolerance_deg:g} deg an angle is usually off by, so the surface is the "
                   "likelier cause; if the angle may be off by that much, measure it again.")
    return {"effect": "ramp_friction", "angle_error_deg": delta, "tolerance_deg": tolerance_deg,
            "within_tolerance": within, "message": message}
