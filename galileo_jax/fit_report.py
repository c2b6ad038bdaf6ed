"""What a fit returns: its typed results, before anything is written.

:func:`galileo_jax.pipeline.run_fit` returns a :class:`FitReport` (one video) and
:func:`~galileo_jax.pipeline.run_joint_fit` a :class:`JointFitReport` (several videos of one
setup); :mod:`galileo_jax.report` prints and writes them. Plain NumPy / Python values, so a
library user gets the same objects the command line prints.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from galileo_jax.observation import Observation
from galileo_jax.scene import Scene


class Posterior(NamedTuple):
    """A fit's posterior as draws, for ``posterior.nc``
    (:func:`galileo_jax.inference.summary.inference_data`).

    Attributes:
        draws: {name: (chains, draws) array} of the reported quantities
            (:func:`galileo_jax.inference.summary.posterior_draws`).
        sample_stats: {name: (chains, draws) array} (mh: ``lp``, ``log_likelihood_total``, nats)
            or None.
        kind: what the draws are: "mcmc" (mh's chains), "gauss_newton" (grad: the normal
            approximation at the Levenberg-Marquardt optimum, one chain) or "cnn" (the network's
            Gaussian, one chain).
    """

    draws: dict
    sample_stats: dict | None
    kind: str


@dataclass
class FitReport:
    """Everything a fit produced (plain NumPy / Python values).

    Attributes:
        video: path of the video.
        scene: the scene.
        method: "grad", "mh", "cnn" or "seed".
        observation: the tracked :class:`Observation`.
        parameters: per reported parameter (k1, k2, phi, m1, m2 as applicable) a dict with
            ``estimate``, ``mean``, ``median``, ``sd``, ``interval90`` [lo, hi], ``best``,
            ``identifiable`` and, for mh, ``r_hat``, ``ess_bulk``.
        diagnostics: method diagnostics (acceptance, iterations, convergence, timings ...).
        simulated: (2n, N-1) simulated profile at the estimate, whole video, m/s.
        band: (2, 2n, N-1) 90% posterior-predictive band (m/s) or None.
        rmse: per trace RMSE of observed - simulated (m/s) over the fit window.
        prediction: rest positions and "will it slide?" beyond the video.
        outputs: paths written.
        timings: seconds per stage.
        adequacy: the fit-adequacy verdict (:func:`galileo_jax.criticism.adequacy.adequacy`): do the
            residuals look like noise, and if not, where the model fails.
        posterior: the posterior as draws (:class:`Posterior`; None for the seed's sampler).
    """

    video: Path
    scene: Scene
    method: str
    observation: Observation
    parameters: dict
    diagnostics: dict
    simulated: np.ndarray
    band: np.ndarray | None
    rmse: dict
    prediction: dict
    outputs: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    adequacy: dict = field(default_factory=dict)
    posterior: Posterior | None = None


@dataclass
class JointFitReport:
    """Everything a joint fit of several videos produced.

    Attributes:
        videos, scenes, observations: per video.
        method: "grad" or "mh".
        per_video: the parameter names fitted per video (``name@j``); the rest are shared.
        parameters: per joint coordinate the summary entry (estimate, 90% interval, ...).
        diagnostics: method diagnostics.
        simulated: per video (2n, N-1) simulated profile at the estimate, m/s.
        bands: per video (2, 2n, N-1) 90% predictive band, m/s.
        rmse: per video the per-trace RMSE dict (as :class:`FitReport`).
        video_loglik: per video the log-likelihood at the estimate (nats).
        outputs: paths written.
        timings: seconds per stage.
        adequacy: per video the fit-adequacy verdict (:func:`galileo_jax.criticism.adequacy.adequacy`).
    """

    videos: list[Path]
    scenes: list[Scene]
    method: str
    observations: list[Observation]
    per_video: tuple[str, ...]
    parameters: dict
    diagnostics: dict
    simulated: list[np.ndarray]
    bands: list[np.ndarray]
    rmse: list[dict]
    video_loglik: list[float]
    outputs: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    adequacy: list[dict] = field(default_factory=list)


def identifiability_statement(scene: Scene) -> str:
    """One plain sentence on what the video can determine about the masses."""
    if scene.n_objects == 1:
        return ("A lone sliding object's motion does not depend on its mass: the video determines k1 only; "
                "m1 is not identifiable.")
    if scene.mass_scale_known():
        return "A known mass in the scene fixes the mass scale: m1 and m2 follow from phi = (m1 - m2)/(m1 + m2)."
    return ("Velocities depend on the masses only through phi = (m1 - m2)/(m1 + m2): m1 and m2 are NOT separately "
            "identifiable from the video (their values are the prior's, conditioned on phi). Give a known mass "
            "in the scene file to fix the scale.")
