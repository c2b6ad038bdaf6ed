"""Figures: observed vs simulated velocity profiles, with residuals."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from galileo_jax.report.results import atomic_path  # noqa: E402


def trace_names(n_objects: int) -> list[str]:
    """Names of the profile's rows: "object 1 x", "object 1 y", ... (y is vertical, up)."""
    return [f"object {i + 1} {axis}" for i in range(n_objects) for axis in ("x", "y")]


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
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
