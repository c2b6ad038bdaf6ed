"""Figures: observed vs simulated velocity profiles with residuals, criticism's residuals and model
comparison, and what the tracker saw (crops along each track, measurement quality)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from galileo_jax.observation import trace_names  # noqa: E402
from galileo_jax.report.results import atomic_path  # noqa: E402


def _save(fig, path, title: str | None, layout: bool = True) -> None:
    """Title, lay out, write ``fig`` atomically as PNG (110 dpi) and close it."""
    if title:
        fig.suptitle(title, fontsize=10)
    if layout:
        fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def profile_figure(path: str | Path, times: np.ndarray, observed: np.ndarray, simulated: np.ndarray,
                   velocity_sd: np.ndarray, mask: np.ndarray, band: np.ndarray | None = None,
                   title: str = "") -> None:
    """Plot observed vs simulated velocity profiles and standardised residuals; write a PNG.

    Args:
        path: output PNG path (written atomically).
        times: (T,) time of each velocity sample in s (mid-frame).
        observed: (R, T) observed profile in m/s (R = 2 * n_objects traces).
        simulated: (R, T) simulated profile at the estimate, in m/s.
        velocity_sd: (R,) noise SD of each trace in m/s (error bars, residual scale).
        mask: (T,) bool, samples used in the fit.
        band: optional (2, R, T) lower/upper 90% posterior-predictive band in m/s.
        title: figure title.
    """
    n_traces = observed.shape[0]
    names = trace_names(n_traces // 2)
    fig, axes = plt.subplots(n_traces, 2, figsize=(11, 2.3 * n_traces), sharex=True,
                             gridspec_kw={"width_ratios": [3, 2]}, squeeze=False)
    for r in range(n_traces):
        ax, axr = axes[r]
        if band is not None:
            ax.fill_between(times, band[0, r], band[1, r], color="tab:orange", alpha=0.3, lw=0,
                            label="90% predictive band")
        ax.errorbar(times[mask], observed[r, mask], yerr=velocity_sd[r], fmt="o", ms=3, color="k",
                    elinewidth=0.6, label="observed")
        if (~mask).any():
            ax.plot(times[~mask], observed[r, ~mask], "o", ms=3, color="0.7", label="not fitted")
        ax.plot(times, simulated[r], "-", color="tab:orange", lw=1.8, label="simulated")
        ax.set_ylabel(f"{names[r]}\n(m/s)")
        ax.grid(alpha=0.3)
        z = (observed[r] - simulated[r]) / velocity_sd[r]
        axr.axhspan(-2, 2, color="tab:green", alpha=0.12, lw=0)
        axr.plot(times[mask], z[mask], ".-", color="tab:red", lw=0.8, ms=4)
        axr.axhline(0, color="k", lw=0.6)
        axr.set_ylabel("residual / sd")
        axr.grid(alpha=0.3)
    axes[0, 0].legend(loc="best", fontsize=8)
    axes[0, 1].set_title("standardised residuals (band: +-2 sd)", fontsize=9)
    axes[-1, 0].set_xlabel("time in video (s)")
    axes[-1, 1].set_xlabel("time in video (s)")
    _save(fig, path, title)


#: Shading colour of each motion phase (:data:`galileo_jax.criticism.phases.PHASES`) in residual figures.
PHASE_COLORS = {"before_release": "0.75", "ramp": "tab:blue", "floor": "tab:green", "collision": "tab:red",
                "rest": "tab:purple"}


def _phase_runs(labels: np.ndarray) -> list[tuple[str, int, int]]:
    """Contiguous runs (phase, first, last) of a 1-D label array (inclusive indices)."""
    runs, start = [], 0
    for k in range(1, labels.size + 1):
        if k == labels.size or labels[k] != labels[start]:
            runs.append((str(labels[start]), start, k - 1))
            start = k
    return runs


def residual_figure(path: str | Path, times: np.ndarray, standardised_residuals: np.ndarray, phases: np.ndarray,
                    mask: np.ndarray, title: str = "", flagged=()) -> dict:
    """Standardised residuals over time with the motion phases shaded; write a PNG.

    One panel per object: the horizontal (x) trace's residuals as dark points, the vertical
    (y) trace's as faint points, a +-2 band, the phases of the fitted simulation shaded
    (legend) and the structured (trace, phase) pairs outlined in red and labelled.

    Args:
        path: output PNG path (written atomically).
        times: (T,) time of each velocity sample in s (mid-frame).
        standardised_residuals: (2n, T) (observed - simulated) / sd per trace, rows as the
            profile (obj1 x, obj1 y, obj2 x, ...); see :func:`galileo_jax.criticism.noise.standardised_residuals`.
        phases: (n, T) phase labels per object (:func:`galileo_jax.criticism.phases.motion_phases`).
        mask: (T,) bool, samples used in the fit (only these are plotted).
        title: figure title.
        flagged: iterable of (trace name, phase) pairs to mark, e.g.
            :func:`galileo_jax.criticism.residuals.flagged` of the residual table; phase "all" is
            written in the panel's title.

    Returns:
        What was drawn, read back from the figure: {"panels": [{"object", "x": (t, z) arrays of
        the x points, "y": (t, z) of the y points, "spans": [(phase, t0, t1)] shaded, "marked":
        ["structured: <trace>" per outlined span, "structured overall: <trace>" per "all" flag]}]}.

    Raises:
        ValueError: inconsistent shapes.
    """
    times = np.asarray(times, np.float64)
    z = np.asarray(standardised_residuals, np.float64)
    phases = np.asarray(phases)
    mask = np.asarray(mask, bool)
    n_traces, n_t = z.shape
    n_obj = n_traces // 2
    if times.shape != (n_t,) or mask.shape != (n_t,) or phases.shape != (n_obj, n_t) or n_traces != 2 * n_obj:
        raise ValueError(f"shapes do not match: times {times.shape}, residuals {z.shape}, phases {phases.shape}, "
                         f"mask {mask.shape}")
    names = trace_names(n_obj)
    marks: dict[int, list[tuple[str, str]]] = {}
    for trace, phase in flagged:
        if trace in names:
            marks.setdefault(names.index(trace) // 2, []).append((trace, phase))
    if n_t > 1:
        half = np.diff(times) / 2.0
        edges = np.concatenate([[times[0] - half[0]], times[:-1] + half, [times[-1] + half[-1]]])
    else:
        edges = np.concatenate([times - 0.5, times + 0.5])
    fig, axes = plt.subplots(n_obj, 1, figsize=(12, 2.8 * n_obj), sharex=True, squeeze=False)
    out = {"panels": []}
    for j in range(n_obj):
        ax = axes[j, 0]
        spans, seen = [], set()
        for phase, a, b in _phase_runs(phases[j]):
            t0, t1 = float(edges[a]), float(edges[b + 1])
            ax.axvspan(t0, t1, color=PHASE_COLORS.get(phase, "0.9"), alpha=0.13, lw=0,
                       label=None if phase in seen else phase.replace("_", " "))
            seen.add(phase)
            spans.append((phase, t0, t1))
        ax.axhspan(-2, 2, color="0.5", alpha=0.08, lw=0)
        for level in (-2, 2):
            ax.axhline(level, color="0.4", lw=0.7, ls="--")
        ax.axhline(0, color="k", lw=0.6)
        (px,) = ax.plot(times[mask], z[2 * j, mask], "o", ms=3.5, color="k", label=f"{names[2 * j]} residual")
        (py,) = ax.plot(times[mask], z[2 * j + 1, mask], ".", ms=3.5, color="tab:orange", alpha=0.45,
                        label=f"{names[2 * j + 1]} residual")
        marked, where = [], {}
        finite = z[2 * j: 2 * j + 2][:, mask]
        finite = finite[np.isfinite(finite)]
        top = max(2.5, float(np.max(np.abs(finite))) if finite.size else 2.5)
        ax.set_ylim(-1.15 * top, 1.3 * top)
        t_range = float(edges[-1] - edges[0]) or 1.0
        stacked: dict[tuple[float, float], int] = {}
        for trace, phase in marks.get(j, []):
            where.setdefault(trace, []).append("whole window" if phase == "all" else phase.replace("_", " "))
            if phase == "all":
                marked.append(f"structured overall: {trace}")
                continue
            for p, t0, t1 in spans:
                if p != phase:
                    continue
                slot = stacked.get((t0, t1), 0)
                stacked[(t0, t1)] = slot + 1
                narrow = (t1 - t0) < 0.12 * t_range
                ax.axvspan(t0, t1, fill=False, edgecolor="tab:red", lw=1.6)
                ax.annotate(trace, xy=(t0 + (0.3 + 0.35 * slot) * (t1 - t0) if narrow else 0.5 * (t0 + t1),
                                       (1.25 - (0 if narrow else 0.12 * slot)) * top),
                            ha="center", va="top", fontsize=7, color="tab:red", rotation=90 if narrow else 0)
                marked.append(f"structured: {trace}")
        panel_title = f"object {j + 1}: standardised residuals (dashed: +-2)"
        if where:
            panel_title += "; structured: " + "; ".join(f"{t} ({', '.join(ps)})" for t, ps in where.items())
        ax.set_title(panel_title, fontsize=9, color="tab:red" if where else "k")
        ax.set_ylabel("residual / sd")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=7, borderaxespad=0.0)
        out["panels"].append({"object": j + 1, "x": tuple(np.asarray(a, np.float64) for a in px.get_data()),
                              "y": tuple(np.asarray(a, np.float64) for a in py.get_data()),
                              "spans": spans, "marked": marked})
    axes[-1, 0].set_xlabel("time in video (s)")
    _save(fig, path, title)
    return out


def model_comparison_figure(path: str | Path, models: list[dict], title: str = "") -> dict:
    """Compare fitted models: RMSE per model against the noise floor, and log-likelihood gain.

    Args:
        path: output PNG path (written atomically).
        models: one dict per model, the first being the base model, with keys "name" (str),
            "rmse" (m/s, RMS of observed - simulated over the fit window), "loglik" (nats at
            the fit; None/NaN if not available) and "noise_floor" (m/s, the RMSE a perfect
            model would reach, e.g. :func:`galileo_jax.criticism.noise.noise_floor`); optionally
            "loglik_reference" (nats): the base model's log-likelihood on the same simulation
            engine, which this model's gain is measured from (log-likelihoods from different
            engines are not comparable); without it, the first model's.
        title: figure title.

    Returns:
        What was drawn, read back from the bars: {"names", "rmse" (bar heights, m/s),
        "noise_floor" (dashed line heights, m/s), "delta_loglik" (bar heights, nats, loglik -
        its reference, the first model's by default; NaN where not available)}.

    Raises:
        ValueError: no models, or a model without a name or rmse.
    """
    if not models:
        raise ValueError("model_comparison_figure needs at least one model")
    try:
        names = [str(m["name"]) for m in models]
        rmse = np.array([float(m["rmse"]) for m in models])
    except KeyError as err:
        raise ValueError(f"every model needs a name and an rmse; missing {err}") from None
    floor = np.array([np.nan if m.get("noise_floor") is None else float(m["noise_floor"]) for m in models])
    ll = np.array([np.nan if m.get("loglik") is None else float(m["loglik"]) for m in models])
    ref = np.array([ll[0] if m.get("loglik_reference") is None else float(m["loglik_reference"]) for m in models])
    dll = ll - ref
    x = np.arange(len(models))
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(max(7.0, 1.6 * len(models) + 4), 3.6))
    bars1 = ax1.bar(x, rmse, color="tab:blue", alpha=0.8)
    floor_lines = []
    for i, f in enumerate(floor):
        if np.isfinite(f):
            floor_lines.append(ax1.hlines(f, i - 0.45, i + 0.45, colors="k", linestyles="--", lw=1.2,
                                          label="noise floor" if not floor_lines else None))
    for i, v in enumerate(rmse):
        ax1.annotate(f"{v:.3f}", xy=(i, v), ha="center", va="bottom", fontsize=7)
    ax1.set_xticks(x, names, rotation=20, ha="right", fontsize=8)
    ax1.set_ylabel("RMSE (m/s)")
    ax1.set_title("velocity RMSE (dashed: noise floor)", fontsize=9)
    if floor_lines:
        ax1.legend(fontsize=7)
    ax1.grid(alpha=0.3, axis="y")
    heights = np.where(np.isfinite(dll), dll, 0.0)
    colors = ["tab:green" if d > 0 else "tab:red" if d < 0 else "0.6" for d in heights]
    bars2 = ax2.bar(x, heights, color=colors, alpha=0.8)
    for i, d in enumerate(dll):
        ax2.annotate("n/a" if not np.isfinite(d) else f"{d:+.1f}", xy=(i, heights[i]), ha="center",
                     va="bottom" if heights[i] >= 0 else "top", fontsize=7)
    ax2.axhline(0, color="k", lw=0.7)
    ax2.set_xticks(x, names, rotation=20, ha="right", fontsize=8)
    ax2.set_ylabel(f"log L - log L({names[0]}) (nats)")
    ax2.set_title("log-likelihood relative to the base model"
                  + (" on the same engine" if any(m.get("loglik_reference") is not None for m in models) else ""),
                  fontsize=9)
    ax2.grid(alpha=0.3, axis="y")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    drawn_floor = np.full(len(models), np.nan)
    for line in floor_lines:
        seg = line.get_segments()[0]
        drawn_floor[round(float(seg[:, 0].mean()))] = seg[0, 1]
    out = {"names": [t.get_text() for t in ax1.get_xticklabels()],
           "rmse": np.array([b.get_height() for b in bars1]),
           "noise_floor": drawn_floor,
           "delta_loglik": np.where(np.isfinite(dll), np.array([b.get_height() for b in bars2]), np.nan)}
    _save(fig, path, None, layout=False)
    return out


def tracking_figure(path: str | Path, frames: np.ndarray, pixels: np.ndarray, quality: np.ndarray,
                    measured: np.ndarray, radius_px, fps: float, methods=(), quality_min: float = 0.5,
                    n_crops: int = 12, title: str = "") -> None:
    """What the tracker saw: per object a strip of crops along its track with the measured
    centre marked, and the measurement quality over time; write a PNG.

    Args:
        path: output PNG path (written atomically).
        frames: (N, H, W, 3) uint8 BGR frames.
        pixels: (N, n, 2) tracked centres (u, v) in px.
        quality: (N, n) measurement quality in [0, 1].
        measured: (N, n) bool, frames used in the fit.
        radius_px: (n,) half width of each object's crop in px (about its diagonal).
        fps: frame rate (frames per second), for the time axis.
        methods: per object the tracking method's name (for the labels).
        quality_min: the threshold below which measurements are dropped (drawn as a line).
        n_crops: crops per object, evenly over the frames in which it was measured (frames
            dropped in between are shown with a grey mark).
        title: figure title.
    """
    N, n = quality.shape
    fig, axes = plt.subplots(2 * n, 1, figsize=(11, 2.6 * n), squeeze=False,
                             gridspec_kw={"height_ratios": [1.2, 1] * n})
    times = np.arange(N) / fps
    for i in range(n):
        ax_strip, ax_q = axes[2 * i, 0], axes[2 * i + 1, 0]
        seen = np.flatnonzero(np.all(np.isfinite(pixels[:, i]), axis=1) & (quality[:, i] > 0))
        if len(seen):
            ks = seen[np.unique(np.linspace(0, len(seen) - 1, min(n_crops, len(seen))).round().astype(int))]
            ax_strip.imshow(_crop_strip(frames, pixels[:, i], ks, measured[:, i], float(radius_px[i])))
            ax_strip.set_xticks((np.arange(len(ks)) + 0.5) * 64)
            ax_strip.set_xticklabels([f"{k}" for k in ks], fontsize=7)
        ax_strip.set_yticks([])
        name = f"object {i + 1}" + (f" ({methods[i]})" if i < len(methods) else "")
        ax_strip.set_title(f"{name}: crops along the track (frame numbers), + measured centre "
                           "(yellow: used, grey: dropped)", fontsize=8, loc="left")
        ax_q.plot(times, quality[:, i], "-", color="tab:blue", lw=1)
        ax_q.plot(times[measured[:, i]], quality[measured[:, i], i], "o", ms=2, color="tab:blue")
        dropped = ~measured[:, i] & (quality[:, i] > 0)
        ax_q.plot(times[dropped], quality[dropped, i], "x", ms=4, color="tab:red", label="dropped")
        ax_q.axhline(quality_min, color="0.5", lw=0.8, ls="--")
        ax_q.set_ylim(-0.05, 1.05)
        ax_q.set_ylabel("quality", fontsize=8)
        ax_q.set_xlabel("video time (s)", fontsize=8)
        ax_q.tick_params(labelsize=7)
    _save(fig, path, title)


def _crop_strip(frames: np.ndarray, track: np.ndarray, ks: np.ndarray, used: np.ndarray, radius: float,
                size: int = 64) -> np.ndarray:
    """(size, size * len(ks), 3) RGB strip of square crops of ``2 radius`` px around the track
    in frames ``ks``, scaled to ``size`` px, each with a cross at the tracked centre."""
    import cv2

    r = max(int(np.ceil(radius)), 4)
    tiles = []
    for k in ks:
        u, v = track[k]
        M = np.array([[size / (2 * r), 0.0, size / 2 - u * size / (2 * r)],
                      [0.0, size / (2 * r), size / 2 - v * size / (2 * r)]])
        tile = cv2.warpAffine(frames[k], M, (size, size), flags=cv2.INTER_NEAREST, borderValue=(0, 0, 0))
        colour = (0, 255, 255) if used[k] else (170, 170, 170)  # BGR: yellow where used
        c = size // 2
        for col, width in (((0, 0, 0), 3), (colour, 1)):  # outlined, to show on any colour
            cv2.line(tile, (c - 8, c), (c + 8, c), col, width)
            cv2.line(tile, (c, c - 8), (c, c + 8), col, width)
        tiles.append(tile[..., ::-1])
    return np.concatenate(tiles, axis=1)
