"""Motion phases of a simulated video (before release, ramp, floor, collision, rest): which
samples of a velocity profile belong to which, from the simulated poses (:func:`motion_phases`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: Motion phases in display (roughly chronological) order.
PHASES = ("before_release", "ramp", "floor", "collision", "rest")


#: Label of the table rows that pool every masked sample of a trace.
ALL = "all"


#: Default speed (m/s) below which a simulated object counts as at rest.
REST_SPEED = 0.02


#: Displacement (m) below which the verdict describes a velocity offset instead of a distance.
MIN_DISPLACEMENT = 0.01


def _sample_kinematics(poses: np.ndarray, frame_times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(speed, x_mid), each (n_objects, N-1): centre speed in m/s and mean centre x in m per sample."""
    p = np.asarray(poses, np.float64)[..., :2]
    dt = np.diff(np.asarray(frame_times, np.float64))
    speed = np.linalg.norm(np.diff(p, axis=0), axis=-1) / dt[:, None]
    x_mid = 0.5 * (p[1:, :, 0] + p[:-1, :, 0])
    return speed.T, x_mid.T


def impact_sample(poses: np.ndarray, frame_times: np.ndarray, release_time: float,
                  rest_speed: float = REST_SPEED) -> int | None:
    """Index of the impact's velocity sample: the first sample after release where object 2 moves.

    Args:
        poses: (N, n_objects, 3) simulated (x m, z m, pitch rad) at the frame times.
        frame_times: (N,) frame times in s.
        release_time: video time (s) at which the objects are released.
        rest_speed: speed (m/s) above which object 2 counts as moving.

    Returns:
        Sample index k (the interval between frames k and k + 1), or None with fewer than two
        objects or if object 2 never moves in the simulation.
    """
    poses = np.asarray(poses, np.float64)
    if poses.ndim != 3 or poses.shape[1] < 2:
        return None
    speed, _ = _sample_kinematics(poses, frame_times)
    after = np.asarray(frame_times, np.float64)[1:] > release_time
    hit = np.flatnonzero(after & (speed[1] > rest_speed))
    return int(hit[0]) if hit.size else None


def motion_phases(poses: np.ndarray, frame_times: np.ndarray, release_time: float, n_objects: int,
                  rest_speed: float = REST_SPEED, collision_halfwidth: int = 2) -> np.ndarray:
    """Label every velocity sample of every object with the motion phase of the SIMULATED fit.

    The phases come from the fitted simulation, not from the noisy observation, so the same
    samples are compared in both. Velocity sample k spans frames k and k + 1 (as in the
    profile). Rules, in order of precedence:

    * ``"before_release"``: the sample ends at or before the release (t[k+1] <= release_time);
    * ``"collision"``: with two or more objects, |k - k_c| <= collision_halfwidth where k_c is
      :func:`impact_sample` (first sample where object 2's simulated speed exceeds
      ``rest_speed``); applies to every object;
    * ``"rest"``: simulated centre speed |p[k+1] - p[k]| / dt < ``rest_speed``;
    * ``"ramp"``: moving with the sample's mean centre x < 0 (the ramp's foot is at x = 0);
    * ``"floor"``: moving with mean centre x >= 0.

    Args:
        poses: (N, n_objects, 3) simulated pose (x m, z m, pitch rad) at the frame times, world
            frame: x horizontal and positive downhill, z up.
        frame_times: (N,) frame times in s.
        release_time: video time (s) at which the objects are released.
        n_objects: number of objects (must match ``poses``).
        rest_speed: speed in m/s below which an object is at rest.
        collision_halfwidth: half-width of the collision window, in samples.

    Returns:
        (n_objects, N-1) array of phase names (str), values from :data:`PHASES`.

    Raises:
        ValueError: inconsistent shapes or negative parameters.
    """
    poses = np.asarray(poses, np.float64)
    t = np.asarray(frame_times, np.float64)
    if poses.ndim != 3 or poses.shape[2] < 2 or poses.shape[1] != n_objects:
        raise ValueError(f"poses has shape {poses.shape}, expected (N, {n_objects}, 3)")
    if t.shape != (poses.shape[0],) or t.size < 2:
        raise ValueError(f"frame_times has shape {t.shape}, expected ({poses.shape[0]},) with N >= 2")
    if rest_speed < 0 or collision_halfwidth < 0:
        raise ValueError("rest_speed and collision_halfwidth must be >= 0")
    speed, x_mid = _sample_kinematics(poses, t)
    labels = np.where(x_mid < 0.0, "ramp", "floor").astype("<U14")
    labels[speed < rest_speed] = "rest"
    kc = impact_sample(poses, t, release_time, rest_speed)
    if kc is not None:
        k = np.arange(t.size - 1)
        labels[:, np.abs(k - kc) <= collision_halfwidth] = "collision"
    labels[:, t[1:] <= release_time] = "before_release"
    return labels


def phase_spans(phases: np.ndarray, times: np.ndarray) -> list[list[dict[str, Any]]]:
    """Contiguous runs of one phase per object, as [{"phase", "start", "end", "first", "last"}].

    Args:
        phases: (n_objects, M) phase labels (:func:`motion_phases`).
        times: (M,) time of each velocity sample in s (e.g. mid-frame).

    Returns:
        Per object, the list of spans: start/end time in s (edges halfway between samples),
        first/last sample index (inclusive).
    """
    times = np.asarray(times, np.float64)
    if times.size == 0:
        return [[] for _ in range(len(phases))]
    half = np.diff(times) / 2.0 if times.size > 1 else np.array([0.5])
    edges = np.concatenate([[times[0] - half[0]], times[:-1] + half, [times[-1] + half[-1]]])
    out = []
    for row in np.asarray(phases):
        spans, start = [], 0
        for k in range(1, row.size + 1):
            if k == row.size or row[k] != row[start]:
                spans.append({"phase": str(row[start]), "start": float(edges[start]), "end": float(edges[k]),
                              "first": start, "last": k - 1})
                start = k
        out.append(spans)
    return out
