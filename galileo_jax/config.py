"""Settings of ``fit``: defaults here, mirrored in ``configs/fit.yaml``; override with
``--config FILE`` (same keys, any subset) and command-line flags.

Errors: :func:`load_config` raises :class:`~galileo_jax.errors.ConfigError` (one line naming
the key) for unknown keys, wrong types or impossible values.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from galileo_jax.errors import GalileoError
from galileo_jax.likelihood import DEFAULT_KIND, DEFAULT_SD_MODEL
from galileo_jax.scene import MAX_SCALE_TOLERANCE


#: Where grad and mh start (``fit --init``): "auto" (grad from the trained CNN's estimate where a
#: network reads the video, else from the prior; mh from the prior), "prior" or "cnn"
#: (:func:`galileo_jax.pipeline.run_fit`).
INITS = ("auto", "prior", "cnn")


class ConfigError(GalileoError):
    """The fit configuration file is missing or invalid."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class MHConfig(_Strict):
    """Random-walk Metropolis-Hastings: chains advanced together, warm-up and kept steps
    (``warmup_cnn``: warm-up when the chains start from the CNN, ``--init cnn``), and the
    probabilities of a population-wide jump proposal (``jump``) and of an independence
    proposal (``independent``, :func:`~galileo_jax.inference.mh.run_mh`)."""

    chains: int = Field(16, ge=2, le=1024)
    warmup: int = Field(300, ge=0)
    warmup_cnn: int = Field(100, ge=0)
    samples: int = Field(400, ge=10)
    jump: float = Field(0.5, ge=0.0, lt=1.0)
    independent: float = Field(0.9, ge=0.0, lt=1.0)


class SeedMHConfig(_Strict):
    """The seed's sampler (dissertation Algorithm 1): 16 chains x 75 steps."""

    chains: int = Field(16, ge=1, le=1024)
    steps: int = Field(75, ge=1)


class GradConfig(_Strict):
    """Levenberg-Marquardt: batched starts, iteration cap, Jacobian kind, the CMA-ES search
    after it, and whether each interval is checked against the profile likelihood
    (:mod:`galileo_jax.inference.profile`)."""

    starts: int = Field(4, ge=1, le=256)
    screen: int = Field(256, ge=1, le=4096)
    max_steps: int = Field(100, ge=1)
    jacobian: Literal["fd", "ad"] = "fd"
    profile: bool = True
    #: CMA-ES generations (32 rollouts each) from the best LM end, then LM from the search's best
    #: (:func:`~galileo_jax.inference.grad.fit_grad`'s ``search_generations``); 0: no search.
    search_generations: int = Field(40, ge=0, le=1000)
    #: Fit again from inside the window of a calibration nuisance (dt_release, scale_error) that
    #: ended at one of its ends (:func:`~galileo_jax.inference.grad.from_inside`).
    inside: bool = True


class CNNConfig(_Strict):
    """The amortised-inference CNN (``--method cnn``, ``--init cnn``): the model folder (None:
    the shipped model matching the scene, :func:`galileo_jax.inference.cnn.model_dirs`) and, for grad started from it,
    the smallest half-width of the screen around its estimate (fraction of each range; wider
    where the CNN's 90% interval is wider)."""

    model: str | None = None
    local_screen: float = Field(0.05, gt=0, le=1)


#: Most rollouts a fit's ensemble averages (``likelihood.ensemble``, ``fit --ensemble``).
MAX_ENSEMBLE = 64


#: mh's rollout ensemble where the settings name none (:func:`ensemble_for`). Measured
#: (``benchmarks/results/mh_mixing.md``: the five videos where mh mixed worst, fit's other mh
#: settings, independence proposals on): worst R-hat per video 1.10 / 1.06 / 1.03 / 1.06 /
#: 1.02 with 1, 1.05 / 1.02 / 1.02 / 1.02 / 1.03 with 2, 1.04 / 1.02 / 1.02 / 1.02 / 1.01 with
#: 4; median smallest bulk ESS 379 / 817 / 773, median ESS per second 14.9 / 15.6 / 7.2. 2 is
#: the least that brings every video to R-hat <= 1.05. (Before the independence proposals,
#: 4 was the default: R-hat 1.07-1.12, ESS 155, 1.4 ESS per second.)
MH_ENSEMBLE = 2


class LikelihoodConfig(_Strict):
    """Likelihood kind and the model-error floor (m/s) added in quadrature to the noise.
    ``ensemble``: each simulated profile is the mean of this many rollouts whose start is
    shifted by fractions of a physics step's travel
    (:func:`galileo_jax.physics.simulate.ensemble_offsets`), which smooths the likelihood's
    pseudo-random response to where in a step the impact falls; it costs that many times the
    rollouts. None (default): the method's own, :func:`ensemble_for` (mh 2, the others 1: off)."""

    kind: str = DEFAULT_KIND
    sd_model: float = Field(DEFAULT_SD_MODEL, ge=0)
    ensemble: int | None = Field(None, ge=1, le=MAX_ENSEMBLE)


def ensemble_for(cfg: "FitConfig", method: str) -> int:
    """Rollouts per simulated profile of a fit by ``method``: ``likelihood.ensemble`` where the
    settings give one, else :data:`MH_ENSEMBLE` for mh (a random walk needs the smoother
    likelihood to mix) and 1 for the others (grad's coverage with 8, measured on one family
    only, ``benchmarks/results/coverage.md``, does not yet justify 3-4x its time)."""
    if cfg.likelihood.ensemble is not None:
        return int(cfg.likelihood.ensemble)
    return MH_ENSEMBLE if method == "mh" else 1


class PredictionConfig(_Strict):
    """Prediction beyond the video: seconds simulated after it, posterior draws used."""

    tail: float = Field(3.0, ge=0, le=60)
    draws: int = Field(32, ge=1, le=1024)


class FitConfig(_Strict):
    """All settings of one ``fit`` run. ``effects``: physical effects (names from
    :mod:`galileo_jax.effects`) added to the base model, on top of the scene's own.
    ``engine``: the simulator of the fit's rollouts, "mjx", "mujoco" (C MuJoCo's batched
    ``mujoco.rollout``) or "auto" (:func:`resolve_engine`). ``scale_tolerance``: relative
    tolerance of the camera's scale where the scene file states none (``camera.scale_tolerance``):
    grad and mh then fit the nuisance ``scale_error``, uniform on +-tolerance (0: such a scale is
    taken as exact). 3%, as ``diagnose`` allows: a scale read off the image is rarely better, and
    through a perspective camera the tracked near faces are magnified against the plane of the
    objects' centres, where a scale is measured (1.3% on ``examples/plain_cubes.mp4``, whose
    k1 interval missed the truth by 2 interval widths without the nuisance)."""

    effects: list[str] = Field(default_factory=list)
    engine: Literal["auto", "mjx", "mujoco"] = "auto"
    scale_tolerance: float = Field(0.03, ge=0.0, le=MAX_SCALE_TOLERANCE)
    mh: MHConfig = MHConfig()
    seed_mh: SeedMHConfig = SeedMHConfig()
    grad: GradConfig = GradConfig()
    cnn: CNNConfig = CNNConfig()
    likelihood: LikelihoodConfig = LikelihoodConfig()
    prediction: PredictionConfig = PredictionConfig()


def resolve_engine(cfg: FitConfig, effects=()) -> str:
    """The simulation engine a fit with these settings runs on.

    "auto" picks C MuJoCo ("mujoco"), measured several times faster than MJX for the ramp
    scene on a CPU and, at a fit's batch sizes, on a GPU too (``benchmarks/results/engines.md``),
    unless the fit needs what only MJX has: derivatives (``grad.jacobian: ad``) or effects that
    act every physics step and have no C form (velocity-dependent friction; quadratic drag has one).

    Args:
        cfg: the settings.
        effects: the fit's effects (:class:`~galileo_jax.effects.Effect`), the scene's own included.

    Raises:
        ConfigError: "mujoco" asked for together with ``grad.jacobian: ad``.
    """
    from galileo_jax.effects.runtime import needs_mjx

    if cfg.engine == "mujoco" and cfg.grad.jacobian == "ad":
        raise ConfigError("grad.jacobian 'ad' needs derivatives, which the C MuJoCo engine has not; "
                          "use --engine mjx or grad.jacobian fd")
    return pick_engine(cfg.engine, cfg.grad.jacobian == "ad" or needs_mjx(effects))


def pick_engine(requested: str, needs_mjx: bool = False) -> str:
    """The engine for a request "auto", "mjx" or "mujoco": "auto" is C MuJoCo unless
    ``needs_mjx`` (derivatives, per-step effects), on a GPU too. Measured on an H100 with 16 CPU
    cores (``benchmarks/results/engines.md``, ``cnn_accuracy.md``): C MuJoCo 76 rollouts/s at
    batch 1 and 682/s at 256 against MJX's 1.9 and 202; MJX leads only at batch 4096 (1,671
    against 847/s), and CNN training with 1,024 rollouts a step ran 4,751 examples/s on C MuJoCo
    against 2,108 on MJX. Used by fits (:func:`resolve_engine`) and by CNN training."""
    if requested != "auto":
        return requested
    return "mjx" if needs_mjx else "mujoco"


def load_config(path: str | Path | None) -> FitConfig:
    """Read a YAML config (any subset of :class:`FitConfig`'s keys); ``None`` gives the defaults.

    Raises:
        ConfigError: missing file, invalid YAML, unknown key or bad value.
    """
    if path is None:
        return FitConfig()
    return load_yaml_model(path, FitConfig, "configs/fit.yaml")


def load_yaml_model(path: str | Path, model: type[BaseModel], example: str) -> BaseModel:
    """Read YAML file ``path`` into the pydantic ``model`` (any subset of its keys).

    Raises:
        ConfigError: missing file, invalid YAML, unknown key or bad value; the one-line message
            names the key and points to ``example``.
    """
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"config file {path} not found; see {example} for the format")
    try:
        data = yaml.safe_load(path.read_text()) or {}
        return model.model_validate(data)
    except yaml.YAMLError:
        raise ConfigError(f"config file {path} is not valid YAML; fix the syntax") from None
    except ValidationError as err:
        raise ConfigError(f"config file {path}: {first_error(err)} (see {example})") from None


def first_error(err: ValidationError) -> str:
    """'key.path: what is wrong' of a pydantic validation error's first error (one line)."""
    first = err.errors()[0]
    loc = ".".join(str(p) for p in first["loc"])
    return f"{loc}: {'unknown key' if first['type'] == 'extra_forbidden' else first['msg']}"
