"""Model criticism: compare the fitted simulation with the video and see where the model fails.

A good fit is not the same as a good model. Once the parameters are fitted, the residuals
``observed - simulated`` of the velocity profile should look like the noise the likelihood
assumes (:mod:`galileo_jax.likelihood`); where they do not, the model is missing something.
This module splits the video into *motion phases* of the fitted simulation (on the ramp, on
the floor, around the collision, at rest), tests the residuals of every trace in every phase
for structure, and writes a one-line verdict such as

    The model fails on the floor: object 2 travels 3.1x farther than simulated (0.42 m vs
    0.14 m); residuals are structured (CUSUM p = 1e-9).

Everything here is plain NumPy/SciPy on explicit arrays (no JAX, no MuJoCo), so it runs on any
fit result and is cheap to test.

The noise model (from :mod:`galileo_jax.likelihood`). Tracking measures each position trace i
with independent errors of SD ``sd_p[i]`` (m); differencing over one frame gives velocity
residuals r = D e with covariance sd_p^2 D D^T, to which the likelihood adds a white model-error
floor sd_model^2 I (m/s)^2. So for one trace, at frame rate fps,

    Var(r_k)            = s^2 = 2 sd_p^2 fps^2 + sd_model^2         (s: :func:`~galileo_jax.criticism.noise.residual_sd`)
    Cov(r_k, r_{k+1})   = -sd_p^2 fps^2
    Corr(r_k, r_{k+1})  = rho = -sd_p^2 fps^2 / (2 sd_p^2 fps^2 + sd_model^2)  in [-1/2, 0]
                                                                      (:func:`~galileo_jax.criticism.noise.expected_lag1`)

and zero beyond lag 1: an MA(1) process. The *standardised residual* is z_k = r_k / s, with
unit variance and lag-1 correlation rho under the model (:func:`~galileo_jax.criticism.noise.standardised_residuals`).

Tests for structure (each on the masked samples of one trace in one phase; sources below):

* ``runs`` -- Wald-Wolfowitz runs test on the signs of z, one-sided for TOO FEW runs (long
  stretches of one sign are systematic error). Exact null distribution given the numbers of
  positive and negative signs (Swed & Eisenhart 1943). It assumes exchangeable signs; under
  the noise model neighbouring residuals are anti-correlated (rho <= 0, differencing), which
  makes runs MORE frequent than under independence, so the test is conservative. A row with
  residuals of one sign only has one possible arrangement and gets p = 1: bias is the job of
  the CUSUM and chi-square tests.
* ``lag1`` -- lag-1 sample autocorrelation r1 of z (mean removed, adjacent samples only)
  against its expected value rho, one-sided for POSITIVE excess (smooth residuals), with
  z = (r1 - rho) * sqrt(n / w), w = 1 - 3 rho^2 + 4 rho^4 (Bartlett's formula for an MA(1),
  Brockwell & Davis, *Time Series: Theory and Methods*, 2nd ed. 1991, Example 7.2.2). For
  rho = 0 this is the familiar z = (r1 - rho) * sqrt(n); for rho < 0, w < 1 and the plain
  sqrt(n) form would be conservative.
* ``cusum`` -- cumulative sum of the residuals (not demeaned, so a constant bias or a drift
  both build up), statistic max_k |S_k| / sqrt(n * lrv), where lrv = g0 + 2 g1 = 1 + 2 rho is
  the long-run variance of z under the MA(1) model. It is computed exactly as the partial sums
  of the *whitened* residuals e = L^-1 z (R = L L^T the model correlation of the phase's
  samples, Cholesky), which are i.i.d. N(0, 1) under the model; sum(z) = sqrt(lrv) sum(e) up
  to O(1) end terms, so the two statistics agree for large n, but the whitened form is
  calibrated at small n and stays defined when lrv -> 0 (sd_model -> 0). Under the model the
  statistic tends to sup_{0<=t<=1} |W(t)| of a Brownian motion W, whose tail is
  P(sup|W| >= x) = 4 sum_{j>=0} (-1)^j Phi_bar((2j+1) x)
                 = 1 - (4/pi) sum_{k>=0} (-1)^k / (2k+1) exp(-pi^2 (2k+1)^2 / (8 x^2))
  (reflection principle: Feller, *Ann. Math. Stat.* 22, 1951; Billingsley, *Convergence of
  Probability Measures*, 1968, eq. 11.10). Note: the Kolmogorov distribution
  (``scipy.stats.kstwobign``) is the law of sup|B(t)| of a Brownian *bridge*, i.e. of the CUSUM
  of demeaned residuals (Ploberger & Kraemer, *Econometrica* 60, 1992); demeaning would hide
  a constant bias, the commonest model failure here, so this module keeps the mean and uses
  the Brownian-motion law (using kstwobign with undemeaned sums would be anti-conservative).
* ``chi2`` -- excess size: T = sum z^2 against n. The z are correlated (lag-1 rho), so
  Var(T) = 2 tr(R^2) = 2 (n + 2 n_pairs rho^2) > 2 n and the plain chi2(n) would be
  anti-conservative; T is referred to the Satterthwaite approximation c * chi2(nu) with
  c = tr(R^2) / n, nu = n^2 / tr(R^2) (Satterthwaite, *Biometrics Bull.* 2, 1946; Box,
  *Ann. Math. Stat.* 25, 1954), which matches mean and variance and reduces to
  ``scipy.stats.chi2.sf(T, n)`` when rho = 0.

The tracking noise of the tests. ``sd_p`` comes from the tracker
(:func:`galileo_jax.observe.tracks.estimate_noise_sd`: third differences of the position
track, leaving out those beyond 3.5 robust SDs, because without a model of the motion a
tracking glitch and a change of acceleration look alike). Here the fitted motion is known, so
:func:`~galileo_jax.criticism.noise.tracking_noise` measures the noise again from the third differences of the *residual*
position track (observed - simulated, integrated from the velocity residuals), where the
model's own changes of acceleration cancel and nothing is left out, so glitches count:
sd_r^2 = mean(d3^2) / 20 - 0.3 dt^2 sd_model^2 (the white floor adds 6 dt^2 sd_model^2 to
E d3^2). Where sd_r exceeds sd_p by more than chance (mean(d3^2) against its distribution under
the noise model with sd_p, c chi2(nu) by Satterthwaite from the autocovariance of d3 at lags
0-3, at level :data:`~galileo_jax.criticism.noise.NOISE_LEVEL`), the tests use sd_r: the tracker
underestimated its noise (measured on the real 10.3 degree roll-slip clip: 4 of 41 third
differences left out, sd 1.2 mm from the tracker, 2.7 mm with them), and a size test against
the smaller SD would blame the model for the tracker's glitches. A smooth misfit barely moves
third differences (a constant velocity offset not at all), so this does not hide a wrong
model; a glitch shows in the third differences exactly as much as in the velocity residuals
(20 g^2 against 2 g^2 fps^2 for a single-frame glitch g, the noise model's own ratio).

Multiple testing: a row's smallest p-value is Bonferroni-adjusted over ALL tests of the table
(4 tests x number of rows), p_adj = min(1, p_min * n_tests), and the row is ``structured`` when
p_adj < alpha. Adjusting over the whole table (not only over the 4 tests of a row) keeps the
chance that the verdict calls pure noise "structured" below alpha (default 0.01); the tests
on one set of residuals are positively dependent ("all" rows overlap the phase rows), so
Bonferroni is conservative. The raw p-values are kept in the table.

The fitted parameters were chosen to make these residuals small, so on the "all" rows the
tests are somewhat conservative (a few parameters absorb part of any structure).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from galileo_jax.criticism.noise import (
    SD_MODEL,
    expected_lag1,
    noise_floor,
    residual_sd,
    standardised_residuals,
    tracking_noise,
)
from galileo_jax.criticism.phases import (
    ALL,
    MIN_DISPLACEMENT,
    PHASES,
    REST_SPEED,
    impact_sample,
    motion_phases,
    phase_spans,
)
from galileo_jax.criticism.structure import TEST_LABELS, TESTS, chi2_test, cusum_test, lag1_test, runs_test
from galileo_jax.observation import Observation, trace_names

#: Smallest phase (masked samples) that gets its own table row.
MIN_SAMPLES = 3


_PHASE_WORDS = {"before_release": "before the release", "ramp": "on the ramp", "floor": "on the floor",
                "collision": "after the collision", "rest": "where the simulation is at rest",
                ALL: "over the whole fit window"}


@dataclass(frozen=True)
class ResidualRow:
    """Residual summary and structure tests of one trace in one phase (or "all").

    Attributes:
        trace: trace name, e.g. "object 2 x" (:func:`galileo_jax.observation.trace_names`).
        object: object number, 1-based.
        axis: "x" (horizontal, positive downhill) or "y" (vertical, up).
        phase: one of :data:`~galileo_jax.criticism.phases.PHASES` or :data:`~galileo_jax.criticism.phases.ALL`.
        n: number of masked samples in the phase.
        rms_z: root mean square of the standardised residuals (about 1 under the model).
        mean_z: mean standardised residual (bias; about 0 under the model).
        rmse: RMS of observed - simulated, m/s.
        rmse_expected: RMSE expected under the noise model, s_i in m/s.
        mean_offset: mean of observed - simulated, m/s.
        sim_mean_velocity: mean simulated velocity over the samples, m/s.
        obs_displacement: sum of observed velocity * dt over the samples, m.
        sim_displacement: the same for the simulated velocity, m.
        rho_expected: lag-1 correlation of the residuals under the model.
        rho_hat: measured lag-1 autocorrelation (nan if too few adjacent pairs).
        cusum: CUSUM statistic max|S_k| / sqrt(n) of the whitened residuals.
        chi2: sum of squared standardised residuals.
        p_runs, p_lag1, p_cusum, p_chi2: p-values of the four tests (nan if not computable).
        p_min: smallest of them.
        p_adjusted: Bonferroni-adjusted p_min over all tests in the table.
        structured: p_adjusted < alpha.
        position_sd: tracking-noise SD (m) of the trace that the tests used (:func:`~galileo_jax.criticism.noise.tracking_noise`).
        position_sd_tracker: the tracker's own estimate (m).
        noise_reestimated: True where the tests used the SD measured from the residual track.
    """

    trace: str
    object: int
    axis: str
    phase: str
    n: int
    rms_z: float
    mean_z: float
    rmse: float
    rmse_expected: float
    mean_offset: float
    sim_mean_velocity: float
    obs_displacement: float
    sim_displacement: float
    rho_expected: float
    rho_hat: float
    cusum: float
    chi2: float
    p_runs: float
    p_lag1: float
    p_cusum: float
    p_chi2: float
    p_min: float
    p_adjusted: float = math.nan
    structured: bool = False
    position_sd: float = math.nan
    position_sd_tracker: float = math.nan
    noise_reestimated: bool = False

    @property
    def worst_test(self) -> str:
        """Name (from :data:`~galileo_jax.criticism.structure.TESTS`) of the test with the smallest p-value."""
        ps = [getattr(self, f"p_{t}") for t in TESTS]
        ps = [p if np.isfinite(p) else np.inf for p in ps]
        return TESTS[int(np.argmin(ps))]

    @property
    def chi2_excess(self) -> float:
        """(chi2 - n) / sqrt(2 n): how far the size of the residuals is off, in rough SDs."""
        return (self.chi2 - self.n) / math.sqrt(2.0 * self.n) if self.n else 0.0

    def as_dict(self) -> dict[str, Any]:
        """The row as a plain dict (numbers as Python floats/ints)."""
        out = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            out[f.name] = float(v) if isinstance(v, (float, np.floating)) else v
        return out


def _row(trace: str, obj: int, axis: str, phase: str, idx: np.ndarray, obs: np.ndarray, sim: np.ndarray,
         s: float, rho: float, dt: np.ndarray) -> ResidualRow:
    r = obs[idx] - sim[idx]
    z = r / s
    p_runs = runs_test(z)
    rho_hat, p_lag1 = lag1_test(z, idx, rho)
    cus, p_cusum = cusum_test(z, idx, rho)
    chi, p_chi2 = chi2_test(z, idx, rho)
    ps = np.array([p_runs, p_lag1, p_cusum, p_chi2])
    p_min = float(np.nanmin(ps)) if np.isfinite(ps).any() else math.nan
    return ResidualRow(
        trace=trace, object=obj, axis=axis, phase=phase, n=int(idx.size),
        rms_z=float(np.sqrt(np.mean(z**2))), mean_z=float(np.mean(z)),
        rmse=float(np.sqrt(np.mean(r**2))), rmse_expected=float(s), mean_offset=float(np.mean(r)),
        sim_mean_velocity=float(np.mean(sim[idx])),
        obs_displacement=float(np.sum(obs[idx] * dt[idx])), sim_displacement=float(np.sum(sim[idx] * dt[idx])),
        rho_expected=float(rho), rho_hat=float(rho_hat), cusum=float(cus), chi2=float(chi),
        p_runs=float(p_runs), p_lag1=float(p_lag1), p_cusum=float(p_cusum), p_chi2=float(p_chi2), p_min=p_min)


def residual_table(observation: Observation, simulated: np.ndarray, sd_model: float = SD_MODEL,
                   phases: np.ndarray | None = None, alpha: float = 0.01,
                   reestimate_noise: bool = True) -> list[ResidualRow]:
    """Residual summary and structure tests per trace and motion phase.

    For each trace (rows of the profile: "object 1 x", "object 1 y", ...) one row per phase
    of :data:`~galileo_jax.criticism.phases.PHASES` with at least :data:`MIN_SAMPLES` masked samples (phase of the trace's
    object, from ``phases``), then one row for phase :data:`~galileo_jax.criticism.phases.ALL` (every masked sample).
    Samples whose observed value is not finite are skipped. See the module docstring for the
    tests and the multiple-testing rule that sets ``structured``.

    Args:
        observation: the observation (profile (2n, N-1) in m/s, position_sd (2n,) in m, mask
            (N-1,), frame_times (N,) in s, fps).
        simulated: (2n, N-1) simulated profile at the fitted parameters, m/s.
        sd_model: model-error floor of the likelihood, m/s.
        phases: (n, N-1) phase labels (:func:`~galileo_jax.criticism.phases.motion_phases`); None gives the "all" rows only.
        alpha: family-wise significance level of the whole table.
        reestimate_noise: measure each trace's tracking noise again from the residual track and
            use it where the tracker's estimate is significantly too small (:func:`~galileo_jax.criticism.noise.tracking_noise`);
            False: the tracker's ``position_sd`` as it is.

    Returns:
        List of :class:`ResidualRow`, ordered by trace, then phase in :data:`~galileo_jax.criticism.phases.PHASES` order, then "all".

    Raises:
        ValueError: shape mismatches, sd_model < 0, alpha outside (0, 1), or zero noise.
    """
    if not sd_model >= 0:
        raise ValueError(f"sd_model must be >= 0 m/s, got {sd_model}")
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    obs = np.asarray(observation.profile, np.float64)
    sim = np.asarray(simulated, np.float64)
    n_traces, m = obs.shape
    n_obj = n_traces // 2
    mask = np.asarray(observation.mask, bool)
    if mask.shape != (m,):
        raise ValueError(f"observation.mask has shape {mask.shape}, expected ({m},)")
    if phases is not None:
        phases = np.asarray(phases)
        if phases.shape != (n_obj, m):
            raise ValueError(f"phases has shape {phases.shape}, expected ({n_obj}, {m})")
    standardised_residuals(observation, sim, sd_model)  # validates shapes and noise
    tracker = np.asarray(observation.position_sd, np.float64)
    used, reest = tracker, np.zeros(n_traces, bool)
    if reestimate_noise:
        noise = tracking_noise(observation, sim, sd_model)
        used, reest = noise["used"], noise["reestimated"]
        observation = observation._replace(position_sd=used)
    s = residual_sd(observation, sd_model)
    rho = expected_lag1(observation, sd_model)
    dt = np.diff(np.asarray(observation.frame_times, np.float64))
    names = trace_names(n_obj)
    rows: list[ResidualRow] = []
    for i in range(n_traces):
        obj, axis = i // 2 + 1, "xy"[i % 2]
        ok = mask & np.isfinite(obs[i]) & np.isfinite(sim[i])
        groups = []
        if phases is not None:
            groups = [(p, ok & (phases[obj - 1] == p)) for p in PHASES]
        groups.append((ALL, ok))
        for phase, sel in groups:
            idx = np.flatnonzero(sel)
            if idx.size < (MIN_SAMPLES if phase != ALL else 1):
                continue
            rows.append(_replace(_row(names[i], obj, axis, phase, idx, obs[i], sim[i], float(s[i]), float(rho[i]), dt),
                                 position_sd=float(used[i]), position_sd_tracker=float(tracker[i]),
                                 noise_reestimated=bool(reest[i])))
    n_tests = sum(int(np.isfinite([getattr(r, f"p_{t}") for t in TESTS]).sum()) for r in rows)
    out = []
    for r in rows:
        p_adj = min(1.0, r.p_min * n_tests) if np.isfinite(r.p_min) else math.nan
        out.append(_replace(r, p_adjusted=float(p_adj), structured=bool(p_adj < alpha)))
    return out


def _replace(row: ResidualRow, **changes: Any) -> ResidualRow:
    return dataclasses.replace(row, **changes)


def flagged(table: Iterable[ResidualRow]) -> list[tuple[str, str]]:
    """(trace, phase) of every structured row (input for :func:`galileo_jax.report.figures.residual_figure`)."""
    return [(r.trace, r.phase) for r in table if r.structured]


def worst_row(table: Sequence[ResidualRow]) -> ResidualRow | None:
    """The structured row the verdict names, or None if no row is structured.

    Preference: x (horizontal) traces over y traces, a motion phase over "all", then the
    smallest p-value, ties (e.g. p-values that underflow to 0) broken by the larger
    chi-square excess (how far the size of the residuals is off).
    """
    cands = [r for r in table if r.structured]
    if not cands:
        return None
    return min(cands, key=lambda r: (r.axis != "x", r.phase == ALL, r.p_min, -r.chi2_excess))


def format_p(p: float) -> str:
    """A p-value for a sentence, with its relation: "= 0.2", "= 0.013", "= 1e-9", "< 1e-300"."""
    if not np.isfinite(p):
        return "= n/a"
    if p < 1e-300:
        return "< 1e-300"
    if p < 1e-3:
        mant, exp = f"{p:.0e}".split("e")
        return f"= {mant}e{int(exp)}"
    return f"= {p:.2g}"


def _describe(row: ResidualRow, min_displacement: float) -> str:
    """What the object does differently from the simulation in this row, as a clause."""
    who = f"object {row.object}"
    vert = row.axis == "y"
    do, ds = row.obs_displacement, row.sim_displacement
    if max(abs(do), abs(ds)) > min_displacement and abs(do - ds) > min_displacement:
        along = " vertically" if vert else ""
        if abs(ds) < 1e-3:
            return f"{who} moves {abs(do):.2f} m{along} where the simulation has it still ({ds:.2f} m)"
        if abs(do) > 1e-3 and np.sign(do) != np.sign(ds):
            return f"{who} moves the opposite way{along} to the simulation ({do:+.2f} m vs {ds:+.2f} m)"
        ratio = abs(do) / abs(ds)
        metres = f"({abs(do):.2f} m vs {abs(ds):.2f} m)"
        if ratio >= 2:
            return f"{who} travels {ratio:.1f}x farther{along} than simulated {metres}"
        if ratio >= 1:  # a ratio near 1 in percent: "2.3% farther", not "1.0x farther"
            return f"{who} travels {100 * (ratio - 1):.2g}% farther{along} than simulated {metres}"
        if ratio > 0.5:
            return f"{who} falls {100 * (1 - ratio):.2g}% short of the simulated distance{along} {metres}"
        return f"{who} travels only {ratio:.2f}x as far{along} as simulated {metres}"
    d, v = row.mean_offset, row.sim_mean_velocity
    if abs(v) > REST_SPEED:
        word = "faster" if d * np.sign(v) > 0 else "slower"
        along = " vertically" if vert else ""
        return f"{who} is {word}{along} than simulated by {_speed(d)} on average"
    direction = ("up" if d > 0 else "down") if vert else ("downhill" if d > 0 else "uphill")
    return f"{who} drifts {direction} at {_speed(d)} on average while the simulation has it still"


def _speed(v: float) -> str:
    """|v| in m/s with two significant digits below 0.1 m/s (0.0032 m/s, not 0.00 m/s)."""
    v = abs(float(v))
    return f"{v:.2f} m/s" if v >= 0.1 else f"{v:.2g} m/s"


def verdict(table: Sequence[ResidualRow], min_displacement: float = MIN_DISPLACEMENT) -> str:
    """One line: do the residuals look like noise, and if not, where and how does the model fail?

    Names :func:`worst_row`; describes it by its displacement ratio when the displacement is
    meaningful (larger of observed/simulated and their difference both > ``min_displacement``
    m), else by the mean velocity offset; ends with the test with the smallest p-value.

    Args:
        table: rows from :func:`residual_table`.
        min_displacement: displacement in m below which the velocity offset is described.

    Returns:
        The verdict sentence.
    """
    if not table:
        return "No residuals to judge: the fit window has no samples."
    row = worst_row(table)
    if row is None:
        p = [r.p_adjusted for r in table if np.isfinite(r.p_adjusted)]
        smallest = format_p(min(p)) if p else "= n/a"
        return (f"The residuals look like noise: no phase shows structure (smallest adjusted p {smallest})."
                + noise_note(table))
    test = row.worst_test
    where = _PHASE_WORDS.get(row.phase, f"in phase {row.phase}")
    return (f"The model fails {where}: {_describe(row, min_displacement)}; residuals are structured "
            f"({TEST_LABELS[test]} p {format_p(getattr(row, f'p_{test}'))})." + noise_note(table))


def noise_note(table: Sequence[ResidualRow]) -> str:
    """A sentence naming the traces tested with the tracking noise measured from the residual
    track (:func:`~galileo_jax.criticism.noise.tracking_noise`), with both SDs in mm; "" when there are none."""
    rows = [r for r in table if r.phase == ALL and r.noise_reestimated]
    if not rows:
        return ""
    parts = "; ".join(f"{r.trace} {1e3 * r.position_sd:.1f} mm, the tracker's {1e3 * r.position_sd_tracker:.1f} mm"
                      for r in rows)
    return (" Tested with the tracking noise measured from the residual track, larger than the tracker's"
            f" estimate (tracking glitches): {parts}.")


def tested_position_sd(summary: dict[str, Any], observation: Observation) -> np.ndarray:
    """(2n,) tracking-noise SD (m) each trace's tests used, from a :func:`summarize` dict
    (``tracking_noise_m``); the tracker's ``position_sd`` for a trace without samples."""
    used = summary.get("tracking_noise_m", {})
    names = trace_names(observation.n_objects)
    return np.array([used[n]["used"] if n in used else float(sd) for n, sd in zip(names, observation.position_sd)])


def summarize(observation: Observation, simulated: np.ndarray, poses: np.ndarray, sd_model: float = SD_MODEL,
              alpha: float = 0.01, rest_speed: float = REST_SPEED, collision_halfwidth: int = 2) -> dict[str, Any]:
    """Criticise a fit: phases, residual table and verdict, as JSON-ready values.

    Args:
        observation: the observation.
        simulated: (2n, N-1) simulated profile at the fitted parameters, m/s.
        poses: (N, n, 3) simulated poses (x m, z m, pitch rad) at the frame times.
        sd_model: model-error floor of the likelihood, m/s.
        alpha: family-wise significance level.
        rest_speed: speed (m/s) below which a simulated object is at rest.
        collision_halfwidth: half-width of the collision window in samples.

    Returns:
        {"phases": {"order", "labels" (n lists of N-1 names), "spans" (per object, list of
        {"phase", "start", "end", "first", "last"}, times in s at mid-frame samples),
        "impact_time" (s or None)}, "table": list of row dicts (:meth:`ResidualRow.as_dict`,
        NaN as None), "verdict": str, "looks_like_noise": bool, "tracking_noise_m": {trace:
        {"tracker", "used" (m), "reestimated"}} (:func:`~galileo_jax.criticism.noise.tracking_noise`), "alpha", "sd_model",
        "noise_floor" (m/s)}.
    """
    t = np.asarray(observation.frame_times, np.float64)
    phases = motion_phases(poses, t, observation.release_time, observation.n_objects, rest_speed,
                           collision_halfwidth)
    table = residual_table(observation, simulated, sd_model, phases, alpha)
    mid = 0.5 * (t[1:] + t[:-1])
    kc = impact_sample(poses, t, observation.release_time, rest_speed)

    def clean(v):
        return None if isinstance(v, float) and not math.isfinite(v) else v

    return {
        "phases": {"order": list(PHASES), "labels": phases.tolist(), "spans": phase_spans(phases, mid),
                   "impact_time": None if kc is None else float(mid[kc])},
        "table": [{k: clean(v) for k, v in r.as_dict().items()} for r in table],
        "verdict": verdict(table),
        "looks_like_noise": not any(r.structured for r in table),
        "tracking_noise_m": {r.trace: {"tracker": r.position_sd_tracker, "used": r.position_sd,
                                       "reestimated": r.noise_reestimated} for r in table if r.phase == ALL},
        "alpha": float(alpha),
        "sd_model": float(sd_model),
        "noise_floor": noise_floor(observation),
    }


