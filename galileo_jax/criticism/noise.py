"""The noise model of the residuals: each velocity sample's SD from the tracking noise and the
model-error floor (:func:`sample_sd`, :func:`standardised_residuals`), the noise floor a perfect
model would reach (:func:`noise_floor`), and the tracking noise measured again from the
residual track (:func:`tracking_noise`).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import special

from galileo_jax.likelihood import DEFAULT_SD_MODEL, event_jumps
from galileo_jax.observation import Observation

#: Default model-error floor in m/s (:data:`galileo_jax.likelihood.DEFAULT_SD_MODEL`).
SD_MODEL = DEFAULT_SD_MODEL


def residual_sd(observation: Observation, sd_model: float = SD_MODEL) -> np.ndarray:
    """(2n,) SD s_i = sqrt(2 sd_p_i^2 fps^2 + sd_model^2) of a velocity residual, m/s."""
    vsd = np.asarray(observation.velocity_sd, np.float64)
    return np.sqrt(vsd**2 + float(sd_model) ** 2)


def expected_lag1(observation: Observation, sd_model: float = SD_MODEL) -> np.ndarray:
    """(2n,) lag-1 correlation rho_i = -sd_p_i^2 fps^2 / s_i^2 of the residuals under the model."""
    vsd = np.asarray(observation.velocity_sd, np.float64)
    s2 = vsd**2 + float(sd_model) ** 2
    return -0.5 * vsd**2 / s2


def sample_sd(observation: Observation, sd_model: float = SD_MODEL, sd_events: np.ndarray | None = None) -> np.ndarray:
    """(2n, N-1) SD of every velocity residual, m/s: sqrt(s_i^2 + sd_events^2), s_i from
    :func:`residual_sd` and ``sd_events`` the extra model error around contact events
    (:func:`galileo_jax.likelihood.event_sd`; None: 0)."""
    s = residual_sd(observation, sd_model)[:, None] * np.ones(np.shape(observation.profile))
    if sd_events is not None:
        ev = np.asarray(sd_events, np.float64)
        if ev.shape != s.shape:
            raise ValueError(f"sd_events has shape {ev.shape}, expected {s.shape} like the profile")
        s = np.sqrt(s**2 + ev**2)
    return s


def standardised_residuals(observation: Observation, simulated: np.ndarray, sd_model: float = SD_MODEL,
                           sd_events: np.ndarray | None = None) -> np.ndarray:
    """(2n, N-1) standardised residuals z = (observed - simulated) / s (unitless), s from :func:`sample_sd`.

    Raises:
        ValueError: shape mismatch, or a trace with zero noise and zero model floor.
    """
    obs = np.asarray(observation.profile, np.float64)
    sim = np.asarray(simulated, np.float64)
    if sim.shape != obs.shape:
        raise ValueError(f"simulated profile has shape {sim.shape}, expected {obs.shape} like the observation")
    s = sample_sd(observation, sd_model, sd_events)
    if not np.all(s > 0):
        raise ValueError("a trace has zero position noise and zero model floor: give sd_model > 0")
    return (obs - sim) / s


def noise_floor(observation: Observation) -> float:
    """RMSE (m/s) a perfect model would reach: root mean square of the tracking-noise velocity SDs."""
    return float(np.sqrt(np.mean(np.asarray(observation.velocity_sd, np.float64) ** 2)))


#: Level of the test that the tracker underestimated a trace's noise (:func:`tracking_noise`).
NOISE_LEVEL = 0.01


#: Velocity jump (m/s, second difference of an object's simulated velocity) that marks a change
#: of acceleration in the simulation: :func:`tracking_noise` leaves out third differences near
#: one, where a mistimed impact or ramp's foot would pass for tracking noise.
SIM_EVENT_JUMP = 0.05


def tracking_noise(observation: Observation, simulated: np.ndarray, sd_model: float = SD_MODEL,
                   level: float = NOISE_LEVEL) -> dict[str, np.ndarray]:
    """The tracking noise of each trace measured again from the residual track (module docstring).

    The velocity residuals r of each trace's masked, finite samples are integrated into the
    residual position track (per run of consecutive samples), whose third differences d3 (those
    not within one sample of a change of the simulated motion, :data:`SIM_EVENT_JUMP`) give
    sd_r^2 = mean(d3^2) / 20 - 0.3 dt^2 sd_model^2 (floored at 0), with dt the mean frame
    interval. sd_r replaces the tracker's ``position_sd`` when mean(d3^2) exceeds the upper
    ``level`` quantile of its distribution under the noise model with sd_p (Satterthwaite:
    gamma_0 chi2(nu) / nu, gamma_h the autocovariance of d3 at lag h, nu = m gamma_0^2 /
    (gamma_0^2 + 2 sum_{h=1..3} gamma_h^2) for m third differences).

    Args:
        observation: the observation (profile (2n, N-1) m/s, position_sd (2n,) m, mask, frame_times).
        simulated: (2n, N-1) simulated profile, m/s.
        sd_model: white model-error floor of the noise model, m/s.
        level: false-alarm rate of the replacement per trace under the noise model.

    Returns:
        {"tracker": (2n,) the tracker's SD (m), "residual": (2n,) sd_r (m; nan with fewer than
        4 third differences), "p": (2n,) p-value of sd_r^2 / sd_p^2 (nan: not computable),
        "reestimated": (2n,) bool, "used": (2n,) the SD the tests use (m)}.
    """
    obs = np.asarray(observation.profile, np.float64)
    sim = np.asarray(simulated, np.float64)
    t = np.asarray(observation.frame_times, np.float64)
    dt_all = np.diff(t)
    tracker = np.asarray(observation.position_sd, np.float64)
    mask = np.asarray(observation.mask, bool)
    n_traces = obs.shape[0]
    events = event_jumps(sim, SIM_EVENT_JUMP) > 0  # (n, N-1)
    near = events.copy()
    near[:, 1:] |= events[:, :-1]
    near[:, :-1] |= events[:, 1:]
    residual, p = np.full(n_traces, np.nan), np.full(n_traces, np.nan)
    for i in range(n_traces):
        ok = mask & np.isfinite(obs[i]) & np.isfinite(sim[i])
        d3, dts = [], []
        # runs of consecutive samples: [start, stop) of each
        edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(np.int8), [0]])))
        for a, b in zip(edges[::2], edges[1::2]):
            pos = np.concatenate([[0.0], np.cumsum((obs[i, a:b] - sim[i, a:b]) * dt_all[a:b])])
            if pos.size >= 4:
                # d3[k] uses positions k..k+3, i.e. velocity samples a+k .. a+k+2
                clear = ~(near[i // 2, a:b - 2] | near[i // 2, a + 1:b - 1] | near[i // 2, a + 2:b])
                d3.append(np.diff(pos, 3)[clear])
                dts.append(dt_all[a:b])
        if not d3:
            continue
        d3 = np.concatenate(d3)
        if d3.size < 4:
            continue
        dt = float(np.mean(np.concatenate(dts)))
        ms, floor2 = float(np.mean(d3**2)), dt**2 * float(sd_model) ** 2
        residual[i] = math.sqrt(max(ms / 20.0 - 0.3 * floor2, 0.0))
        if tracker[i] > 0:
            # autocovariance of d3 under the noise model, lags 0..3: white position noise
            # (20, -15, 6, -1) sd_p^2 plus the integrated white floor (6, -4, 1, 0) dt^2 sd_model^2
            gamma = np.array([20.0, -15.0, 6.0, -1.0]) * tracker[i] ** 2 + np.array([6.0, -4.0, 1.0, 0.0]) * floor2
            nu = d3.size * gamma[0] ** 2 / (gamma[0] ** 2 + 2.0 * float(np.sum(gamma[1:] ** 2)))
            p[i] = float(special.chdtrc(nu, nu * ms / gamma[0]))
    reest = np.isfinite(p) & (p < level) & (residual > tracker)
    return {"tracker": tracker, "residual": residual, "p": p, "reestimated": reest,
            "used": np.where(reest, residual, tracker)}


def residual_correlation(idx: np.ndarray, rho: float) -> np.ndarray:
    """(m, m) model correlation of the standardised residuals at sample indices ``idx`` (sorted)."""
    idx = np.asarray(idx)
    r = np.eye(idx.size)
    adj = np.abs(idx[:, None] - idx[None, :]) == 1
    r[adj] = rho
    return r
