"""Is the fitted model good enough? The fit-adequacy rule of every report and of ``diagnose``'s
step 3 (:mod:`galileo_jax.criticism.diagnosis`): the RMSE away from contact events within
:data:`ADEQUATE_RATIO` of the noise floor, and over all samples within
:data:`ADEQUATE_RATIO_ALL` (:func:`within_floor`, :func:`adequacy`); where it fails, the residual
tests (:func:`galileo_jax.criticism.residuals.summarize`) say where.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from galileo_jax.criticism.noise import SD_MODEL
from galileo_jax.criticism.residuals import summarize
from galileo_jax.likelihood import event_sd
from galileo_jax.observation import Observation

#: Velocity jump (m/s) that marks a contact event for the adequacy check (:func:`calm_mask`).
#: Lower than the test likelihood's EVENT_JUMP: a gentle second collision (a 0.09 m/s jump,
#: rendered video without a hidden effect) that MJX resolves one frame off the renderer leaves
#: a residual as large as the jump itself (0.11 m/s measured).
GATE_JUMP = 0.05


#: A fit is adequate when its RMSE away from contact events is within this factor of the noise
#: floor (:func:`~galileo_jax.criticism.noise.noise_floor`) ...
ADEQUATE_RATIO = 1.3


#: ... and its RMSE over all fitted samples within this one (measured on rendered videos without
#: a hidden effect: 0.4-1.3x, 2.3x where MJX and the renderer part at a second collision; see
#: :mod:`galileo_jax.criticism.diagnosis`, step 3).
ADEQUATE_RATIO_ALL = 1.6


def profile_rmse(observation: Observation, simulated: np.ndarray) -> float:
    """RMSE (m/s) of observed - simulated (2n, N-1) velocity over the fit window, all traces together."""
    m = np.asarray(observation.mask, bool)
    d = (np.asarray(observation.profile) - np.asarray(simulated))[:, m]
    return float(np.sqrt(np.mean(d**2)))


def within_floor(rmse_calm: float, rmse: float, floor: float, ratio: float = ADEQUATE_RATIO,
                 ratio_all: float = ADEQUATE_RATIO_ALL) -> bool:
    """The adequacy rule (``diagnose``'s step 3, every fit's verdict): RMSE away from contact
    events ``rmse_calm`` <= ``ratio`` x the noise ``floor`` and RMSE over all samples ``rmse`` <=
    ``ratio_all`` x the floor (all m/s)."""
    return rmse_calm <= ratio * floor and rmse <= ratio_all * floor


def calm_mask(observation: Observation, simulated: np.ndarray) -> np.ndarray:
    """(2n, N-1) bool: the fitted samples away from contact events, i.e. not within one sample of
    a velocity jump of at least :data:`GATE_JUMP` in the ``simulated`` (2n, N-1, m/s) or the
    observed profile (:func:`galileo_jax.likelihood.event_sd`)."""
    sd = event_sd(np.asarray(simulated), np.asarray(observation.profile), np.asarray(observation.velocity_sd),
                  jump=GATE_JUMP)
    return (sd == 0) & np.asarray(observation.mask, bool)[None]


def adequacy(observation: Observation, simulated: np.ndarray, poses: np.ndarray, sd_model: float = SD_MODEL,
             alpha: float = 0.01) -> dict[str, Any]:
    """A fit-adequacy verdict for a fit's report: does the fitted model describe the video, and
    if not, where does it fail?

    The rule is ``diagnose``'s step 3 (:mod:`galileo_jax.criticism.diagnosis`): the model is adequate when
    its RMSE away from contact events is within :data:`ADEQUATE_RATIO` of the noise floor and
    its RMSE over all samples within :data:`ADEQUATE_RATIO_ALL` (at an impact the simulator
    itself is exact only to a physics step, so structure there alone is not a missing effect).
    Otherwise the residual tests of :func:`summarize` say where it fails.

    Args:
        observation: the observation (fit window: ``observation.mask``).
        simulated: (2n, N-1) simulated profile at the estimate, m/s.
        poses: (N, n, 3) simulated poses at the frame times (x m, z m, pitch rad).
        sd_model: model-error floor of the likelihood, m/s.
        alpha: family-wise significance level of the residual tests.

    Returns:
        {"adequate": bool, "verdict": one sentence, "residual_tests": the tests' verdict
        (:func:`verdict`), "looks_like_noise": bool, "flagged": list of {"trace", "phase"} whose
        residuals are structured, "rmse_m_per_s" (all fitted samples), "calm_rmse_m_per_s"
        (away from contact events), "calm_fraction", "noise_floor_m_per_s", "rmse_over_floor",
        "calm_rmse_over_floor", "alpha"}.
    """
    s = summarize(observation, simulated, poses, sd_model, alpha)
    diff = np.asarray(observation.profile) - np.asarray(simulated)
    rmse = profile_rmse(observation, simulated)
    calm = calm_mask(observation, simulated)
    rmse_calm = float(np.sqrt(np.mean(diff[calm] ** 2))) if calm.any() else rmse
    fraction = float(calm.sum() / max(diff.shape[0] * int(np.sum(observation.mask)), 1))
    floor = float(s["noise_floor"])
    ratio = rmse / floor if floor > 0 else float("inf")
    ratio_calm = rmse_calm / floor if floor > 0 else float("inf")
    ok = within_floor(rmse_calm, rmse, floor)
    if ok:
        text = (f"The model describes the video: away from contact events its RMSE is {ratio_calm:.1f}x the noise "
                f"floor ({rmse_calm:.4f} m/s on {100 * fraction:.0f}% of the samples; {rmse:.4f} m/s, {ratio:.1f}x, on all; "
                f"floor {floor:.4f} m/s).")
    else:
        text = s["verdict"] + f" RMSE {rmse:.4f} m/s, {ratio:.1f}x the noise floor ({floor:.4f} m/s)."
    return {"adequate": bool(ok), "verdict": text, "residual_tests": s["verdict"],
            "looks_like_noise": bool(s["looks_like_noise"]),
            "flagged": [{"trace": r["trace"], "phase": r["phase"]} for r in s["table"] if r["structured"]],
            "rmse_m_per_s": rmse, "calm_rmse_m_per_s": rmse_calm, "calm_fraction": fraction,
            "noise_floor_m_per_s": floor, "rmse_over_floor": ratio, "calm_rmse_over_floor": ratio_calm,
            "alpha": float(alpha)}
