"""Profile-likelihood check of grad's Gauss-Newton intervals.

grad's 90% interval of a coordinate is z_hat +- 1.645 sd_z (:mod:`.grad`): it assumes the
log-likelihood is quadratic in z out to the interval's ends. Where it is not (a skewed
posterior, a parameter near where the data stop telling it apart, the rough cost surface of
contact events) the interval is wrong on one side or both. The profile likelihood does not
assume that: l_p(v) = max over the other coordinates of l(z) with z_j = v, and the 90%
interval is {v : 2 (l_hat - l_p(v)) <= chi^2_1(0.90) = 1.645^2} (Wilks 1938; Venzon & Moolgavkar
1988, Appl. Stat. 37:87-94, for finding its ends by root search; Pawitan 2001, "In All
Likelihood", ch. 3.4).

:func:`profile_check` evaluates the profile at both ends of each checked coordinate's
Gauss-Newton interval, all ends in ONE batched Levenberg-Marquardt solve with that coordinate
held (:func:`held_lm_solver`; each start is the Gauss-Newton conditional mean of the other
coordinates there). Its signed root deviance there, sqrt(2 (l_hat - l_p)) / inflation (the
inflation being the sandwich widening that the interval already carries,
:func:`~galileo_jax.inference.covariance.robust_covariance`), is 1.645 for an exactly quadratic
log-likelihood. Where it is below 1.645 / :data:`PROFILE_TOLERANCE` the profile is flatter than
the quadratic and the interval too narrow on that side: its end is searched outwards by the
secant method on the root deviance (a few more batched solves) and the profile's end replaces
the Gauss-Newton one.

The check only ever widens. A held fit that stops short of its optimum (the cost surface is
rough at contact events: the simulated impact responds pseudo-randomly to small parameter
changes, :mod:`.grad`) overstates the deviance, never understates it, so a root deviance
below 1.645 proves that point inside the profile's 90% region, while one above it may be the
optimiser's failure. Hence a side where the profile looks steeper than the quadratic keeps its
Gauss-Newton end, and a searched side ends beyond its FARTHEST point found inside (not at the
first point found outside: measured on the shipped example, phi's profile read 0.89, 2.00,
0.68, 2.19 at phi 0.338, 0.358, 0.379, 0.414).

Costs: the first check is one batched solve of 2 m held fits for m coordinates (each LM step
2 (d - 1) + 1 rollouts per fit); each further round only the sides still open. Measured on the
shipped example (README command 1, C MuJoCo engine on 2 CPU cores): 6 held fits 3.8 s, a round
of one 0.7 s, plus 1.8 s to compile each batch shape (programs with the C engine's host
callbacks are not kept in JAX's persistent cache): 8 s in all, 16.5 -> 24.5 s for the command.
"""

from __future__ import annotations

import math
import time
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from galileo_jax.inference.covariance import Z90
from galileo_jax.inference.grad import lm_no_worse
from galileo_jax.inference.problem import pad_rows

#: A side of an interval is searched where the profile's root deviance at its Gauss-Newton end
#: is below 1.645 / this factor (the interval is then more than ~1.5x too narrow there); a
#: larger tolerance runs fewer searches.
PROFILE_TOLERANCE = 1.5
#: Secant rounds after the first check (each one batched solve of the sides still open).
PROFILE_ROUNDS = 2
#: A side's end is found when its root deviance is within this fraction of 1.645.
ROOT_RTOL = 0.05
#: Farthest a profile end is searched from z_hat (in z): theta is then within 0.03% of its
#: range from the bound, where the logistic transform leaves nothing more to find.
MAX_Z_DISTANCE = 8.0
#: Kinds of coordinates checked by default: the physical parameters a user reads (not the
#: release-time and scale nuisances).
CHECKED_KINDS = ("friction", "phi", "mass", "effect")


class ProfileCheck(NamedTuple):
    """Result of :func:`profile_check` for m checked coordinates.

    Attributes:
        coords: (m,) indices of the checked coordinates.
        root_deviance_gn: (m, 2) signed root deviance (lower end, upper end) at the
            Gauss-Newton interval's ends, scaled by the coordinate's inflation; 1.645 where the
            log-likelihood is quadratic.
        disagrees: (m, 2) bool, sides where it is below 1.645 / :data:`PROFILE_TOLERANCE` (the
            profile is flatter than the Gauss-Newton quadratic: the interval is too narrow).
        interval_z: (m, 2) the 90% interval in z: the profile's end on the disagreeing sides,
            the Gauss-Newton end elsewhere.
        bounded: (m, 2) bool, False where the profile stayed below 1.645 out to
            :data:`MAX_Z_DISTANCE` (the data do not bound that side: the end is the prior's bound).
        loglik_gain: how far (nats) the best held fit rose above the fit's own optimum
            (> 0: the fit had stopped short of the maximum).
        best_z: (d,) the best point met (the fit's own unless ``loglik_gain`` > 0).
        searched: {(row, side 0 lower / 1 upper): [(z, root deviance), ...]}: the profile's
            points evaluated on each searched side, the optimum (z_hat, 0) first.
        solves: held Levenberg-Marquardt fits run.
        time_s: wall time (s), compilation included.
    """

    coords: np.ndarray
    root_deviance_gn: np.ndarray
    disagrees: np.ndarray
    interval_z: np.ndarray
    bounded: np.ndarray
    loglik_gain: float
    best_z: np.ndarray
    searched: dict
    solves: int
    time_s: float

    def report(self, names, to_theta: Callable[[int, np.ndarray], np.ndarray], gn_interval: np.ndarray) -> dict:
        """The check as a result's ``profile`` entry: {name: {"method": "profile" or
        "gauss_newton", "root_deviance_at_gauss_newton_ends": [lo, hi], "interval90_gauss_newton":
        [a, b], "interval90_profile": [a, b] (where searched), "bounded": [lo, hi]}, ...,
        "loglik_gain", "solves", "time_s"}; ``to_theta(j, z (k,))`` maps coordinate j's z values
        to theta, ``gn_interval`` (d, 2) is the Gauss-Newton interval in theta."""
        out: dict = {}
        for row, j in enumerate(self.coords):
            entry = {"method": "profile" if self.disagrees[row].any() else "gauss_newton",
                     "root_deviance_at_gauss_newton_ends": [round(float(x), 3) for x in self.root_deviance_gn[row]],
                     "interval90_gauss_newton": [float(x) for x in gn_interval[j]]}
            if self.disagrees[row].any():
                entry["interval90_profile"] = [float(x) for x in to_theta(int(j), self.interval_z[row])]
                entry["bounded"] = [bool(b) for b in self.bounded[row]]
                pts = sorted(p for side in (0, 1) for p in self.searched.get((row, side), [])[1:])
                if pts:  # [theta, root deviance] of each point of the profile evaluated
                    th = to_theta(int(j), np.array([p[0] for p in pts]))
                    entry["profile_points"] = [[float(t), round(float(p[1]), 3)] for t, p in zip(th, pts)]
            out[names[int(j)]] = entry
        return {"parameters": out, "loglik_gain": float(self.loglik_gain), "solves": int(self.solves),
                "time_s": float(self.time_s), "tolerance": PROFILE_TOLERANCE}


def held_lm_solver(res_fn: Callable, rtol: float, atol: float, max_steps: int) -> Callable:
    """Pure ``solve(z0 (S, d), j (S,), v (S,), data) -> (z (S, d), cost (S,))``: vmapped
    Levenberg-Marquardt over the coordinates other than ``j``, with z_j held at ``v``, from
    ``z0`` (its j-th entry ignored); never ends above its start's cost. ``res_fn(z, data)``:
    standardised residuals."""
    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)

    def solve_one(z_init, j, v, data):
        d = z_init.shape[0]
        k = jnp.arange(d - 1)
        src = k + (k >= j)  # free coordinate k -> full coordinate

        def full(zf):
            return jnp.zeros(d, zf.dtype).at[src].set(zf).at[j].set(v)

        zf, cost, _ = lm_no_worse(lambda zf_, args: res_fn(full(zf_), args), solver, z_init[src], data, max_steps)
        return full(zf), cost

    def solve_none(z_init, j, v, data):  # one coordinate: nothing left to optimise
        z = z_init.at[j].set(v)
        return z, 0.5 * jnp.sum(res_fn(z, data) ** 2)

    def solve(z0, j, v, data):
        one = solve_one if z0.shape[-1] > 1 else solve_none
        return jax.vmap(one, in_axes=(0, 0, 0, None))(z0, j, v, data)

    return solve


def profile_check(solve: Callable, data, z_hat: np.ndarray, cost_hat: float, cov_gn: np.ndarray,
                  inflation: np.ndarray | None, coords, *, tolerance: float = PROFILE_TOLERANCE,
                  rounds: int = PROFILE_ROUNDS, pad_batches: bool = False) -> ProfileCheck:
    """Check each coordinate of ``coords`` of a least-squares fit against its profile
    likelihood (module docstring), searching the profile's 90% end where they disagree.

    Args:
        solve: :func:`held_lm_solver`'s function, jitted.
        data: the problem's data pytree (passed to ``solve``).
        z_hat: (d,) the fit's optimum in z; cost_hat: its cost |r|^2 / 2.
        cov_gn: (d, d) the Gauss-Newton covariance (J^T J)^-1 at z_hat, not widened.
        inflation: (d,) the sandwich widening of each coordinate's SD (None: 1).
        coords: indices of the coordinates to check (finite, positive variance).
        tolerance: :data:`PROFILE_TOLERANCE`.
        rounds: secant rounds after the first check.
        pad_batches: pad every batch of held fits to the first one's size (copies of its last
            fit), so that ``solve`` runs one compiled program: for the C engine, whose programs
            JAX compiles in every process (about 2 s for each batch size; its rollout cache
            simulates the copies once).

    Returns:
        :class:`ProfileCheck`.

    Raises:
        ValueError: a coordinate in ``coords`` has no finite positive variance, or tolerance < 1.
    """
    t0 = time.perf_counter()
    z_hat = np.asarray(z_hat, np.float64)
    cov_gn = np.asarray(cov_gn, np.float64)
    d = len(z_hat)
    coords = np.asarray(list(coords), int)
    infl = np.ones(d) if inflation is None else np.asarray(inflation, np.float64)
    var = np.diag(cov_gn)[coords] if len(coords) else np.zeros(0)
    if tolerance < 1.0:
        raise ValueError(f"tolerance must be >= 1, got {tolerance}")
    if not np.all(np.isfinite(var) & (var > 0)):
        raise ValueError(f"coordinates {coords.tolist()} need finite positive Gauss-Newton variances, got {var}")
    m = len(coords)
    sd_z = np.sqrt(var) * infl[coords]  # the reported (widened) SD
    reg = np.where(np.isfinite(cov_gn), cov_gn, 0.0)
    best = {"cost": float(cost_hat), "z": z_hat.copy()}
    n_solves = 0

    def run(rows, sides, dists):
        """Held fits at z_j = z_hat_j + side * dist; their root deviances (scaled)."""
        nonlocal n_solves
        j = coords[rows]
        v = z_hat[j] + sides * dists
        start = z_hat[None] + reg[:, j].T / reg[j, j][:, None] * (v - z_hat[j])[:, None]  # conditional mean
        start[np.arange(len(j)), j] = v
        pad = pad_rows(np.arange(len(j)), 2 * m if pad_batches else len(j))
        z, cost = (np.asarray(a, np.float64)[:len(j)]
                   for a in solve(jnp.asarray(start[pad]), jnp.asarray(j[pad]), jnp.asarray(v[pad]), data))
        n_solves += len(j)
        cost = np.where(np.isfinite(cost), cost, np.inf)
        i = int(np.argmin(cost))
        if cost[i] < best["cost"]:
            best["cost"], best["z"] = float(cost[i]), z[i]
        return np.sqrt(np.maximum(2.0 * (cost - cost_hat), 0.0)) / infl[j]

    rows = np.repeat(np.arange(m), 2)
    sides = np.tile([-1.0, 1.0], m)
    dist0 = Z90 * sd_z[rows]
    root0 = run(rows, sides, dist0) if m else np.zeros(0)
    disagree = root0 < Z90 / tolerance  # flatter than quadratic: the interval is too narrow there
    ends = dist0.copy()
    bounded = np.ones(2 * m, bool)
    # per searched side: its (distance, root deviance) points; the fit's optimum is (0, 0)
    hist = {s: [(0.0, 0.0), (float(dist0[s]), float(root0[s]))] for s in np.flatnonzero(disagree)}

    def end_of(pts):
        """(distance, bounded) of a side's end: from its farthest point inside (root <= 1.645)
        to the nearest point beyond that is outside, linearly in the root deviance; with none
        outside yet, the secant through its two farthest points, extrapolated. Where that
        secant does not rise (a rough profile: held fits stop in ripples, so the root deviance
        can fall from one point to the next), the mean rise from the optimum to the farthest
        point inside stands in for it; only a profile that has not risen at all is unbounded
        (measured: the shipped example's k1 profile at 1.07, 1.42, 1.24 read as unbounded and
        reported k1 0.200 [8e-05, 0.204])."""
        d_in, r_in = max(p for p in pts if p[1] <= Z90)
        out = [p for p in pts if p[1] > Z90 and p[0] > d_in]
        if out:
            d_out, r_out = min(out)
            return d_in + (Z90 - r_in) * (d_out - d_in) / (r_out - r_in), True
        (d_a, r_a) = max(p for p in pts if p[0] < d_in)
        slope = (r_in - r_a) / (d_in - d_a)
        if slope <= 1e-9:
            slope = r_in / d_in
        far = min(d_in + (Z90 - r_in) / slope, MAX_Z_DISTANCE) if slope > 1e-9 else MAX_Z_DISTANCE
        return max(far, d_in), far < MAX_Z_DISTANCE

    open_ = list(hist)
    for _ in range(rounds):
        if not open_:
            break
        nxt = []
        for s in open_:
            d_in = max(p for p in hist[s] if p[1] <= Z90)[0]
            guess, _ = end_of(hist[s])
            nxt.append(float(np.clip(guess, d_in * 1.05, min(4.0 * d_in, MAX_Z_DISTANCE))))
        roots = run(rows[np.asarray(open_)], sides[np.asarray(open_)], np.asarray(nxt))
        still = []
        for s, dist, r in zip(open_, nxt, roots):
            hist[s].append((dist, float(r)))
            if abs(r - Z90) > ROOT_RTOL * Z90 and not (r <= Z90 and dist >= MAX_Z_DISTANCE):
                still.append(s)
        open_ = still
    for s, pts in hist.items():
        ends[s], bounded[s] = end_of(pts)
    interval = (z_hat[coords][:, None] + np.stack([-ends[0::2], ends[1::2]], axis=1)) if m else np.zeros((0, 2))
    searched = {(int(s // 2), int(s % 2)): [(float(z_hat[coords[s // 2]] + sides[s] * dist), r) for dist, r in pts]
                for s, pts in hist.items()}
    return ProfileCheck(coords, root0.reshape(m, 2), disagree.reshape(m, 2), interval, bounded.reshape(m, 2),
                        float(cost_hat - best["cost"]), best["z"], searched, n_solves, time.perf_counter() - t0)


def checked_coords(space, cov_gn: np.ndarray) -> list[int]:
    """Coordinates :func:`profile_check` checks by default: those of :data:`CHECKED_KINDS` with
    a finite positive Gauss-Newton variance."""
    var = np.diag(np.asarray(cov_gn, np.float64))
    return [j for j, kind in enumerate(space.kinds) if kind in CHECKED_KINDS and math.isfinite(var[j]) and var[j] > 0]
