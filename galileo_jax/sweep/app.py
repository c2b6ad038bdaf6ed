"""The Hydra app behind ``python -m galileo_jax.sweep``: one job = one (video, method, settings) fit.

Config: ``configs/sweep.yaml`` (``fit``'s settings from ``configs/fit.yaml`` merged in, so
``grad.starts=1``, ``mh.chains=8``, ``likelihood.kind=gaussian_ma1`` override them per sweep).
The app runs in Hydra's multirun mode by default. Its ``video`` index is swept over every
video of the sweep: ``hydra.sweeper.params.video`` is ``${galileo_sweep_videos:}``, a resolver
that, in the launching process and before any job starts, lists the videos
(:func:`~galileo_jax.sweep.inputs.sweep_inputs`), checks the swept methods and returns
``range(0,N)``. A mistake there (missing dataset folder, no videos, a setting without a scene,
unknown method) stops the sweep with one line on stderr.

Each job (:func:`run_job`) writes into its Hydra job folder: ``result.json`` and
``profiles.png`` from :func:`~galileo_jax.pipeline.run_fit` (no overlay video) and
``job.json``, the record that ``python -m galileo_jax.sweep.gather`` tabulates. A job whose
fit fails (tracking lost, no CNN for the scene, ...) records ``status: failed`` with the
one-line message and returns normally, so the other jobs go on. With ``batch: true``, method
grad's videos of one scene file are fitted in ONE job as one batched computation
(:func:`run_batch_job`), which writes one record per video in the same format.
"""

from __future__ import annotations

import logging
import math
import os
import sys
import time
import traceback
from pathlib import Path
from typing import Any

os.environ.setdefault("MUJOCO_GL", "egl")

import hydra  # noqa: E402
from hydra.core.hydra_config import HydraConfig  # noqa: E402
from hydra.core.override_parser.overrides_parser import OverridesParser  # noqa: E402
from hydra.errors import HydraException  # noqa: E402
from omegaconf import DictConfig, OmegaConf  # noqa: E402
from omegaconf.errors import OmegaConfBaseException  # noqa: E402

from galileo_jax.errors import GalileoError, cli_entry  # noqa: E402
from galileo_jax.sweep.inputs import VideoItem, absolute, check_method, sweep_inputs  # noqa: E402

log = logging.getLogger("galileo_jax.sweep")
#: Parameters a video determines (without a known mass): the job record's estimates and errors.
IDENTIFIABLE = ("k1", "k2", "phi")
#: Keys of the sweep config that pick the job or its inputs rather than describe its settings.
JOB_KEYS = ("video", "method", "videos", "dataset", "scenes", "camera", "batch")
RECORD = "job.json"
#: The sweep config's folder (configs/sweep.yaml; configs/fit.yaml merged in, hydra/launcher presets).
CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"


def _base(cfg: DictConfig) -> Path:
    """The directory the sweep was started in (relative paths are read against it): Hydra's
    ``runtime.cwd``, from the job's Hydra config or the launching process's root config."""
    if HydraConfig.initialized():
        return Path(HydraConfig.get().runtime.cwd)
    try:
        return Path(cfg.hydra.runtime.cwd)
    except (AttributeError, OmegaConfBaseException):
        return Path.cwd()


def inputs_of(cfg: DictConfig) -> list[VideoItem]:
    """The sweep's videos from the config's ``videos``, ``dataset``, ``scenes`` and ``camera``."""
    videos = OmegaConf.to_container(cfg.videos, resolve=True) if cfg.get("videos") else []
    scenes = OmegaConf.to_container(cfg.scenes, resolve=True) if cfg.get("scenes") else {}
    return sweep_inputs(videos, cfg.get("dataset"), {str(k): str(v) for k, v in scenes.items()},
                        str(cfg.get("camera") or "Camera_1"), _base(cfg))


def swept_values(cfg: DictConfig, key: str) -> list[str]:
    """Every value of ``key`` the sweep will run: its config value, and the values the sweeper's
    params and the command line's overrides give it (``method=grad,mh`` -> grad, mh)."""
    params = cfg.hydra.sweeper.get("params")
    params = OmegaConf.to_container(params, resolve=False) if params is not None else {}  # video's own resolver
    lines = [f"{k}={v}" for k, v in params.items() if k == key]
    lines += [o for o in cfg.hydra.overrides.task if o.split("=", 1)[0].lstrip("+~") == key]
    if not lines:
        return [str(cfg[key])]
    values = []
    for override in OverridesParser.create().parse_overrides(lines):
        if override.is_sweep_override():
            values += list(override.sweep_string_iterator())
        else:
            values.append(override.get_value_element_as_str())
    return values


def _sweep_videos(*, _root_: DictConfig) -> str:
    """Resolver ``${galileo_sweep_videos:}``: check the sweep (methods, fit settings, videos and
    their scenes) and return ``range(0,N)`` over its N videos."""
    for method in swept_values(_root_, "method"):
        check_method(method)
    fit_config(_root_)
    return f"range(0,{len(inputs_of(_root_))})"


OmegaConf.register_new_resolver("galileo_sweep_videos", _sweep_videos, replace=True)


def fit_config(cfg: DictConfig) -> "FitConfig":  # noqa: F821
    """The job's :class:`~galileo_jax.config.FitConfig` from the sweep config's ``fit`` keys.

    Raises:
        ConfigError: a bad value (one line naming the key).
    """
    from pydantic import ValidationError

    from galileo_jax.config import ConfigError, FitConfig, first_error

    data = {name: OmegaConf.to_container(cfg[name], resolve=True) if OmegaConf.is_config(cfg[name]) else cfg[name]
            for name in FitConfig.model_fields if name in cfg}
    try:
        return FitConfig.model_validate(data)
    except ValidationError as err:
        raise ConfigError(f"setting {first_error(err)} (see configs/fit.yaml)") from None


def _truth(video: Path) -> dict[str, float] | None:
    """k1, k2, phi from ``<video stem>.truth.json`` next to the video (phi from m1, m2 if absent); None if none."""
    import json

    path = video.with_suffix(".truth.json")
    if not path.is_file():
        return None
    data = json.loads(path.read_text())
    if "phi" not in data and "m1" in data and "m2" in data:
        data["phi"] = (data["m1"] - data["m2"]) / (data["m1"] + data["m2"])
    return {n: float(data[n]) for n in IDENTIFIABLE if isinstance(data.get(n), (int, float))}


def _estimates(parameters: dict) -> dict[str, dict[str, Any]]:
    """Per reported parameter its estimate and 90% interval (None where the method gives none);
    phi from the m1, m2 estimates where the method reports masses only (the seed's sampler)."""
    out = {name: {"estimate": p.get("estimate"), "interval90": p.get("interval90")} for name, p in parameters.items()}
    if "phi" not in out and "m1" in out and "m2" in out:
        m1, m2 = out["m1"]["estimate"], out["m2"]["estimate"]
        out["phi"] = {"estimate": (m1 - m2) / (m1 + m2), "interval90": None}
    return out


def _one_line(err: BaseException) -> str:
    text = " ".join(str(err).split()) or type(err).__name__
    return text if isinstance(err, GalileoError) else f"{type(err).__name__}: {text}"


def _new_record(cfg: DictConfig, out: Path, overrides: list[str], index: int) -> dict[str, Any]:
    """A job record of video ``index`` before its fit: status "running" (see :func:`run_job`)."""
    variant = " ".join(o for o in overrides if o.split("=", 1)[0].lstrip("+~").split(".")[0] not in JOB_KEYS)
    return {"status": "running", "message": None, "video": None, "id": None, "setting": None, "scene": None,
            "method": str(cfg.method), "init": str(cfg.init), "seed": int(cfg.seed), "index": index,
            "variant": variant, "overrides": overrides, "job_dir": str(out)}


def _describe(record: dict, item: VideoItem, scene) -> None:
    """Fill in the record's video, id, setting and scene (name, file, where from, angle in degrees)."""
    record.update(video=str(item.video), id=item.id, setting=item.setting,
                  scene={"name": scene.name, "file": str(item.scene), "from": item.scene_from,
                         "angle_deg": math.degrees(scene.ramp.angle)})


def _record_fit(record: dict, report, item: VideoItem) -> None:
    """Fill in a finished fit's estimates, errors against the truth, RMSE and timings."""
    params = _estimates(report.parameters)
    truth = _truth(item.video)
    record.update(status="ok", parameters=params, rmse_m_per_s=report.rmse["all"]["rmse"],
                  timings_s=report.timings, truth=truth,
                  abs_error=None if truth is None else
                  {n: abs(float(params[n]["estimate"]) - v) for n, v in truth.items()
                   if n in params and params[n]["estimate"] is not None})


def _record_failure(record: dict, err: BaseException) -> None:
    """Mark the record failed with the error's one line (and log it, with the traceback if it is not ours)."""
    record.update(status="failed", message=_one_line(err))
    if not isinstance(err, GalileoError):
        log.error("job failed:\n%s", "".join(traceback.format_exception(type(err), err, err.__traceback__)))
    log.error("error: %s", record["message"])


def _job_inputs(cfg: DictConfig, index: int) -> list[VideoItem]:
    """The sweep's videos, checking that ``index`` is one of them.

    Raises:
        GalileoError: any error of :func:`inputs_of`, or ``index`` out of range.
    """
    items = inputs_of(cfg)
    if not 0 <= index < len(items):
        raise GalileoError(f"video={index} is out of range: the sweep has {len(items)} videos (0 to {len(items) - 1})")
    return items


def batched(cfg: DictConfig) -> bool:
    """Whether the job runs in batched mode: ``batch: true``, method grad, init prior."""
    return bool(cfg.get("batch")) and str(cfg.method) == "grad" and str(cfg.init) == "prior"


def run_job(cfg: DictConfig, out: Path, overrides: list[str] | None = None) -> dict:
    """Fit the sweep's video ``cfg.video`` with ``cfg.method`` and write ``out/job.json``
    (in batched mode, :func:`batched`, :func:`run_batch_job` instead).

    Args:
        cfg: the job's composed sweep config.
        out: the job's folder (created).
        overrides: the job's command-line overrides (its ``variant`` is those other than
            :data:`JOB_KEYS`, e.g. ``grad.starts=1``).

    Returns:
        The job record: ``status`` ("ok" or "failed"; "running" while the fit runs, so a killed
        job shows as such), ``message`` (the failure's one line), ``video``, ``id``,
        ``setting``, ``scene`` (name, file, where from, angle in degrees), ``method``,
        ``init``, ``seed``, ``variant``, ``settings`` (the FitConfig), ``parameters``
        (estimate and 90% interval per reported parameter), ``truth`` and ``abs_error`` (k1,
        k2, phi, when ``<video stem>.truth.json`` exists), ``rmse_m_per_s`` (all traces,
        over the fit window), ``wall_s`` (the job's wall time, compilation included) and
        ``timings_s`` (per stage).
    """
    from galileo_jax.report.results import write_json

    if batched(cfg):
        return run_batch_job(cfg, out, overrides)
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    record = _new_record(cfg, out, list(overrides or []), int(cfg.video))
    write_json(out / RECORD, record)
    try:
        check_method(record["method"])
        item = _job_inputs(cfg, record["index"])[record["index"]]
        from galileo_jax.jaxcache import enable_compilation_cache
        from galileo_jax.pipeline import run_fit
        from galileo_jax.scene import load_scene

        scene = load_scene(item.scene)
        _describe(record, item, scene)
        settings = fit_config(cfg)
        record["settings"] = settings.model_dump()
        write_json(out / RECORD, record)
        enable_compilation_cache()
        fps = None if cfg.get("fps") is None else float(cfg.fps)
        report = run_fit(item.video, scene, settings, method=record["method"], out=out, fps=fps, seed=record["seed"],
                         overlay=False, progress=False, init=record["init"])
        _record_fit(record, report, item)
    except Exception as err:  # noqa: BLE001 - a failed job is recorded, not raised: the sweep goes on
        _record_failure(record, err)
    record["wall_s"] = time.perf_counter() - t0
    write_json(out / RECORD, record)
    return record


def run_batch_job(cfg: DictConfig, out: Path, overrides: list[str] | None = None) -> dict:
    """Batched mode (``batch: true``, method grad): the job of the FIRST video of each scene
    fits every video of the sweep with that scene file as one batched computation
    (:func:`~galileo_jax.pipeline.run_fit_batch`) and writes one record per video,
    ``out/video_<index>/job.json`` (with ``result.json`` and ``profiles.png``), the same
    record :func:`run_job` writes, plus ``batch`` (``job_dir``, ``videos``: the indices
    fitted together, ``job_wall_s``); its ``wall_s`` is the job's wall time divided by the
    videos in it. A video whose tracking fails is recorded failed and the others still fit.
    The other videos' jobs return at once and write nothing.

    Returns:
        ``{"status": "batch", "records": [...]}`` for the first video's job,
        ``{"status": "batched", "index", "batch_index"}`` for the others'.
    """
    from galileo_jax.report.results import write_json

    t0 = time.perf_counter()
    index = int(cfg.video)
    try:
        items = _job_inputs(cfg, index)
    except GalileoError:  # recorded as a one-video job does
        return run_job(OmegaConf.merge(cfg, {"batch": False}), out, overrides)
    group = [i for i, it in enumerate(items) if it.scene == items[index].scene]
    if index != group[0]:
        log.info("video %d (%s) is fitted in the batched job of video %d", index, items[index].id, group[0])
        return {"status": "batched", "index": index, "batch_index": group[0]}
    outs = [out / f"video_{i}" for i in group]
    records = [_new_record(cfg, o, list(overrides or []), i) for i, o in zip(group, outs)]
    for rec, o in zip(records, outs):
        rec["batch"] = {"job_dir": str(out), "videos": group}
        o.mkdir(parents=True, exist_ok=True)
        write_json(o / RECORD, rec)
    try:
        from galileo_jax.jaxcache import enable_compilation_cache
        from galileo_jax.pipeline import run_fit_batch
        from galileo_jax.scene import load_scene

        scene = load_scene(items[index].scene)
        settings = fit_config(cfg)
        for rec, i, o in zip(records, group, outs):
            _describe(rec, items[i], scene)
            rec["settings"] = settings.model_dump()
            write_json(o / RECORD, rec)
        enable_compilation_cache()
        fps = None if cfg.get("fps") is None else float(cfg.fps)
        results = run_fit_batch([items[i].video for i in group], scene, settings, outs=outs, fps=fps,
                                seed=int(cfg.seed), overlay=False, progress=False)
    except Exception as err:  # noqa: BLE001 - recorded for every video of the batch: the sweep goes on
        results = [err] * len(group)
    wall = time.perf_counter() - t0
    for rec, i, o, res in zip(records, group, outs, results):
        if isinstance(res, Exception):
            _record_failure(rec, res)
        else:
            _record_fit(rec, res, items[i])
        rec["wall_s"] = wall / len(group)
        rec["batch"]["job_wall_s"] = wall
        write_json(o / RECORD, rec)
    return {"status": "batch", "records": records}


@hydra.main(version_base="1.3", config_path=str(CONFIG_DIR), config_name="sweep")
def _app(cfg: DictConfig) -> dict:
    hc = HydraConfig.get()
    return run_job(cfg, absolute(hc.runtime.output_dir, Path(hc.runtime.cwd)), list(hc.overrides.task))


def _galileo_cause(err: BaseException) -> GalileoError | None:
    """The GalileoError that ``err`` wraps (Hydra and OmegaConf wrap a resolver's errors), if any."""
    seen = set()
    while err is not None and id(err) not in seen:
        if isinstance(err, GalileoError):
            return err
        seen.add(id(err))
        err = err.__cause__ or err.__context__
    return None


def _from_launcher(err: BaseException) -> bool:
    """Whether ``err`` came out of a launcher's engine (submitit, joblib, loky) rather than our code."""
    names = (type(err).__module__, *(f.filename for f in traceback.extract_tb(err.__traceback__)[-1:]))
    return any(part in name for name in names for part in ("submitit", "joblib", "loky"))


@cli_entry
def main(argv: list[str] | None = None) -> int:
    """``python -m galileo_jax.sweep [OVERRIDES]``: Hydra's command line; mistakes end in one line."""
    argv = sys.argv[1:] if argv is None else list(argv)
    given = dict(a.split("=", 1) for a in argv if "=" in a and not a.startswith("-"))
    given = {k.lstrip("+~"): v for k, v in given.items()}
    if "video" in given and "true" in given.get("batch", "").lower():  # a batched job fits all its scene's videos
        raise GalileoError("batch=true fits every video of each scene in one job; drop video=... or use batch=false")
    os.environ.setdefault("HYDRA_FULL_ERROR", "1")  # let errors reach us (Hydra would print a stack trace)
    saved = sys.argv
    sys.argv = [saved[0] if saved else "galileo_jax.sweep", *argv]
    try:
        _app()
    except GalileoError:
        raise
    except (HydraException, OmegaConfBaseException) as err:
        cause = _galileo_cause(err)
        raise (cause or GalileoError(f"{' '.join(str(err).split())} (see configs/sweep.yaml)")) from None
    except Exception as err:
        if not _from_launcher(err):
            raise
        # Submission failed (no Slurm here, sbatch refused) or a job's process died (crash, out of
        # memory, killed): the launcher stops. Finished jobs keep their records; a died one says so.
        raise GalileoError(f"the launcher stopped ({_one_line(err)[:300]}); finished jobs' records are in the "
                           f"sweep folder: python -m galileo_jax.sweep.gather SWEEP_DIR") from None
    finally:
        sys.argv = saved
    return 0
