"""``python -m galileo_jax.train --config configs/cnn_ramp20.yaml``: train the amortised-inference CNN.

Training data is never a file on disk. Each step is ONE jitted function
(:func:`make_train_step`): draw ``rollouts`` parameter vectors from the training prior
(:func:`~galileo_jax.inference.cnn_training.training_prior`), run them as one batch of rollouts (vmapped
MJX, or C MuJoCo's batched rollout through a callback: ``engine``, auto picks C MuJoCo,
12.7x the simulated examples per second of MJX on 2 cores and 2.3x on an H100 machine at 1,024
rollouts a step, ``benchmarks/results/cnn_accuracy.md``),
make ``views`` noisy, cut copies of each (:func:`~galileo_jax.inference.cnn_training.simulate_examples`:
the observation noise model of :mod:`galileo_jax.likelihood`), and take one optax step
(AdamW, cosine-decayed learning rate, gradient clipping) on the batch of rollouts x views.

Resumable: every ``checkpoint_every`` steps the whole training state (parameters, optimiser
state, step, PRNG key) goes to an Orbax ``CheckpointManager`` in ``<out>.train/checkpoints``
(the last 2 kept); a rerun of the same command continues from the latest one. Metrics go to
``<out>.train/metrics.jsonl`` (one JSON line per log: step, loss, validation loss and mean
absolute errors on a fixed validation set, examples per second). The trained model
(:func:`~galileo_jax.inference.cnn_files.save_model`: ``model.json`` + Orbax ``weights/``) is written
atomically to ``<out>`` at the end, where ``fit --method cnn`` finds it.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path
from typing import Callable, Literal, NamedTuple

os.environ.setdefault("MUJOCO_GL", "egl")

from pydantic import BaseModel, ConfigDict, Field  # noqa: E402

from galileo_jax.cli import OneLineParser  # noqa: E402
from galileo_jax.errors import GalileoError, cli_entry  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: MJX rollouts vmapped at once (more are chunked with lax.map). Measured on 2 CPU cores, 20 degree
#: two-box scene, 833 physics steps: 25 rollouts/s at 16, 20/s at 8, 15/s at 4 and at 32 in one vmap.
#: On a GPU up to GPU_MAX_BATCH are one vmap. The C MuJoCo engine takes the whole batch in one native call
#: (it splits it itself).
ROLLOUT_CHUNK = 16


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class NoiseConfig(_Strict):
    """Observation noise and cuts of the training profiles (see ``cnn_training.NoiseModel``)."""

    position_sd: tuple[float, float] = (5e-5, 3e-3)
    min_samples: int = Field(24, ge=4)
    prefix: int = Field(6, ge=0)
    scale_error: float = Field(0.0, ge=0.0, lt=0.5)


class TrainConfig(_Strict):
    """All settings of one training run (``configs/cnn_ramp20.yaml`` documents each key).

    ``family`` (a mapping, ``{}`` for the default ranges): train a scene-conditioned network on
    scenes drawn from a :class:`~galileo_jax.scene_family.SceneFamily` with these ranges
    ({feature: [low, high]}; ``configs/cnn_family.yaml``) instead of one ``scene``; ``fps`` is then
    the network's time grid and ``engine`` C MuJoCo (the family's rollouts,
    :mod:`galileo_jax.physics.simulate_family`).

    ``init_from`` (a trained model folder): start from that model's weights instead of a fresh
    network (fine-tuning: a fresh optimiser, warm-up and cosine schedule over ``steps``); its
    network must be the one this config describes. Only a run without checkpoints uses it.
    """

    scene: str = "scenes/ramp_20.yaml"
    fps: float = Field(30.0, gt=0)
    engine: Literal["auto", "mjx", "mujoco"] = "auto"
    architecture: Literal["profile", "seed"] = "profile"
    n_samples: int = Field(96, ge=16)
    release_offset: float = Field(0.25, ge=0)
    width: int = Field(32, ge=1)
    hidden: int = Field(128, ge=1)
    steps: int = Field(1500, ge=1)
    rollouts: int = Field(16, ge=1)
    views: int = Field(8, ge=1)
    learning_rate: float = Field(1e-3, gt=0)
    nll_beta: float = Field(0.5, ge=0, le=1)
    weight_decay: float = Field(1e-4, ge=0)
    slide_margin: float = Field(0.02, ge=0)
    prior: Literal["scene", "seed"] = "scene"
    noise: NoiseConfig = NoiseConfig()
    validation: int = Field(512, ge=1)
    log_every: int = Field(100, ge=1)
    checkpoint_every: int = Field(200, ge=1)
    seed: int = 0
    out: str = "models/ramp_20_cnn"
    family: dict[str, tuple[float, float]] | None = None
    ramp_feature: bool = False
    init_from: str | None = None


def load_train_config(path: str | Path | None) -> TrainConfig:
    """Read a training config (YAML, any subset of :class:`TrainConfig`'s keys).

    Raises:
        GalileoError: missing file, invalid YAML, unknown key or bad value (one line).
    """
    if path is None:
        return TrainConfig()
    from galileo_jax.config import load_yaml_model

    return load_yaml_model(path, TrainConfig, "configs/cnn_ramp20.yaml")


class TrainState(NamedTuple):
    """Everything a training step reads and writes (a pytree).

    Attributes:
        params: the network's parameter state (``nnx.State``).
        opt_state: the optax optimiser state.
        step: () int, steps taken.
        key: (2,) uint32 raw PRNG key.
    """

    params: object
    opt_state: object
    step: object
    key: object


class Setup(NamedTuple):
    """The static parts of a training run, built once by :func:`setup`."""

    cfg: TrainConfig
    scene: object
    spec: object
    noise: object
    engine: object
    graphdef: object
    tx: object


def setup(cfg: TrainConfig, scene=None) -> tuple[Setup, TrainState]:
    """Build the simulator, network, optimiser and the initial :class:`TrainState` (for
    ``cfg.family``: the scene family instead of one scene, :func:`_setup_family`).

    Raises:
        GalileoError: the scene file is missing or invalid, or settings that do not fit it.
    """
    import jax

    from galileo_jax.config import pick_engine
    from galileo_jax.inference import cnn
    from galileo_jax.inference.problem import GPU_MAX_BATCH, get_engine
    from galileo_jax.scene import load_scene

    if cfg.family is not None:
        return _setup_family(cfg)
    if scene is None:
        path = Path(cfg.scene)
        scene = load_scene(path if path.is_absolute() or path.exists() else ROOT / path)
    if scene.effects:
        raise GalileoError(f"scene {scene.name!r} has effects; the CNN learns the base model only: remove them")
    spec, noise = _spec_and_noise(cfg, lambda **kw: cnn.CNNSpec.for_scene(scene, cfg.fps, **kw))
    kind = pick_engine(cfg.engine)
    on_cpu = jax.default_backend() == "cpu"
    chunk = cfg.rollouts if kind == "mujoco" else min(cfg.rollouts, ROLLOUT_CHUNK if on_cpu else GPU_MAX_BATCH)
    engine = get_engine(scene, cfg.fps, (), spec.n_samples / cfg.fps, chunk, kind)
    return _with_network(cfg, scene, spec, noise, engine)


def _spec_and_noise(cfg: TrainConfig, make_spec) -> tuple:
    """The network's spec (``make_spec(**network settings)``) and the :class:`NoiseModel` of
    ``cfg``, checked. Raises GalileoError (one line) on settings that do not fit."""
    from galileo_jax.inference import cnn_training

    try:
        spec = make_spec(n_samples=cfg.n_samples, release_offset=cfg.release_offset, architecture=cfg.architecture,
                         width=cfg.width, hidden=cfg.hidden, ramp_feature=cfg.ramp_feature)
        noise = cnn_training.NoiseModel(tuple(cfg.noise.position_sd), cfg.noise.min_samples, cfg.noise.prefix,
                                        cfg.noise.scale_error)
        if not 0 < noise.position_sd[0] <= noise.position_sd[1]:
            raise ValueError(f"noise.position_sd must be [low, high] with 0 < low <= high, got {noise.position_sd}")
        if noise.min_samples > spec.n_samples:
            raise ValueError(f"noise.min_samples {noise.min_samples} exceeds n_samples {spec.n_samples}")
    except ValueError as err:
        raise GalileoError(f"training settings: {err}") from None
    return spec, noise


def _with_network(cfg: TrainConfig, scene, spec, noise, engine) -> tuple[Setup, TrainState]:
    """The :class:`Setup` with a fresh network for ``spec`` and its optimiser (AdamW, warm-up
    then cosine decay to 5%, gradient clipping), and the initial :class:`TrainState`."""
    import jax
    import jax.numpy as jnp
    import optax
    from flax import nnx

    from galileo_jax.inference import cnn

    graphdef, params = nnx.split(cnn.build_network(spec, cfg.seed), nnx.Param)
    warmup = min(100, cfg.steps // 10 + 1)  # the schedule needs at least one decay step (steps: 1 too)
    schedule = optax.warmup_cosine_decay_schedule(0.0, cfg.learning_rate, warmup, max(cfg.steps, warmup + 1),
                                                  cfg.learning_rate * 0.05)
    tx = optax.chain(optax.clip_by_global_norm(1.0), optax.adamw(schedule, weight_decay=cfg.weight_decay))
    state = TrainState(params, tx.init(params), jnp.asarray(0, jnp.int32), jax.random.PRNGKey(cfg.seed + 1))
    return Setup(cfg, scene, spec, noise, engine, graphdef, tx), state


def _setup_family(cfg: TrainConfig) -> tuple[Setup, TrainState]:
    """:func:`setup` of a scene-conditioned network (``cfg.family``): no simulator object (each
    rollout builds its scene, :mod:`galileo_jax.physics.simulate_family`); ``Setup.scene`` is
    the :class:`~galileo_jax.scene_family.SceneFamily`, ``Setup.engine`` the family's
    :class:`~galileo_jax.params.ParamSpace`."""
    from galileo_jax.inference import cnn, cnn_training
    from galileo_jax.scene_family import SceneFamily

    if cfg.engine == "mjx":
        raise GalileoError("a scene-conditioned network trains on C MuJoCo (engine auto or mujoco), not mjx")
    if cfg.prior != "scene":
        raise GalileoError("training settings: a scene-conditioned network trains on each scene's prior (prior: scene)")
    try:
        family = SceneFamily.from_dict(cfg.family)
    except ValueError as err:
        raise GalileoError(f"training settings: {err}") from None
    spec, noise = _spec_and_noise(cfg, lambda **kw: cnn.CNNSpec.for_family(family, cfg.fps, **kw))
    return _with_network(cfg, family, spec, noise, cnn_training.family_space(spec))


def draw_prior(s: Setup, key, n: int):
    """n training draws (n, d) of theta from the config's ``prior`` (pure): ``scene``: the scene's
    prior with object 1 sliding (:func:`~galileo_jax.inference.cnn_training.training_prior`); ``seed``: the
    seed's (:func:`~galileo_jax.inference.cnn_training.seed_prior`)."""
    from galileo_jax.inference import cnn_training

    if s.cfg.prior == "seed":
        return cnn_training.seed_prior(s.engine.space, key, n)
    return cnn_training.training_prior(s.engine.space, s.scene, key, n, s.cfg.slide_margin)


def make_batch_fn(s: Setup, views: int | None = None) -> Callable:
    """Pure ``batch(key, n_rollouts) -> (x (n * views, L, C), theta (n * views, d))``:
    simulated, noisy network inputs (C = ``spec.channels``) and their true parameters (``views``
    copies of each rollout; default the config's); for a scene-conditioned network each rollout
    of a scene drawn from the family."""
    import jax
    import jax.numpy as jnp

    from galileo_jax.inference import cnn_training

    views = s.cfg.views if views is None else views

    def batch(key, n):
        k_theta, k_sim = jax.random.split(key)
        if s.spec.family is not None:  # a scene per rollout, then its parameters
            k_scene, k_theta = jax.random.split(k_theta)
            features = s.scene.draw(k_scene, n)
            theta = cnn_training.family_prior(s.engine, features, k_theta, s.cfg.slide_margin)
            x = cnn_training.simulate_family_examples(s.spec, s.noise, features, theta, k_sim, views)
            return x, jnp.tile(theta, (views, 1)).astype(jnp.float32)
        theta = draw_prior(s, k_theta, n)
        x = cnn_training.simulate_examples(s.engine, s.spec, s.noise, theta, k_sim, views)
        return x, jnp.tile(theta, (views, 1)).astype(jnp.float32)

    return batch


def make_train_step(s: Setup) -> Callable[[TrainState], tuple[TrainState, dict]]:
    """The training step, ONE jitted function ``step(state) -> (state, metrics)``: draws
    parameters, simulates (the config's engine), adds noise, and takes an optimiser step.

    ``metrics``: ``loss`` (the batch's :func:`~galileo_jax.inference.cnn.loss`, beta-weighted by
    ``nll_beta``) and ``grad_norm``.
    """
    import jax
    import optax

    from galileo_jax.inference import cnn

    batch = make_batch_fn(s)

    def step(state: TrainState) -> tuple[TrainState, dict]:
        key, k_batch = jax.random.split(state.key)
        x, theta = batch(k_batch, s.cfg.rollouts)
        value, grads = jax.value_and_grad(
            lambda p: cnn.loss(s.spec, s.graphdef, p, x, theta, s.cfg.nll_beta))(state.params)
        updates, opt_state = s.tx.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        return TrainState(params, opt_state, state.step + 1, key), {"loss": value, "grad_norm": optax.tree.norm(grads)}

    return jax.jit(step, donate_argnums=0)


def validation_set(s: Setup, n: int, seed: int = 12345):
    """A fixed validation set ``(x, theta)`` of ``n`` simulated examples (one view each)."""
    import jax

    return jax.jit(make_batch_fn(s, views=1), static_argnums=1)(jax.random.PRNGKey(seed), n)


def make_eval_fn(s: Setup) -> Callable:
    """Jitted ``evaluate(params, x, theta) -> {loss, mae_<name>..., coverage90}`` on a set."""
    import jax
    import jax.numpy as jnp

    from galileo_jax.inference import cnn

    @jax.jit
    def evaluate(params, x, theta):
        pred = cnn.predict(s.spec, s.graphdef, params, x)
        out = {"loss": cnn.loss(s.spec, s.graphdef, params, x, theta)}
        w = cnn.usable(x)
        n = jnp.maximum(jnp.sum(w), 1)
        err = jnp.abs(pred.theta - theta)
        inside = (theta >= pred.interval90[..., 0]) & (theta <= pred.interval90[..., 1])
        for j, name in enumerate(s.spec.names):
            out[f"mae_{name}"] = jnp.sum(jnp.where(w, err[:, j], 0.0)) / n
            out[f"cover90_{name}"] = jnp.sum(jnp.where(w, inside[:, j], False)) / n
        out["usable"] = jnp.mean(w)
        return out

    return evaluate


def _checkpoint_manager(work: Path):
    import orbax.checkpoint as ocp

    opts = ocp.CheckpointManagerOptions(max_to_keep=2, create=True)
    return ocp.CheckpointManager((work / "checkpoints").resolve(), options=opts)


def _restore(manager, state: TrainState) -> TrainState:
    import jax
    import orbax.checkpoint as ocp

    latest = manager.latest_step()
    if latest is None:
        return state
    target = jax.tree_util.tree_map(lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype), state)
    return manager.restore(latest, args=ocp.args.StandardRestore(target))


def train(cfg: TrainConfig, *, out: Path, fresh: bool = False, progress: bool = True, scene=None) -> dict:
    """Train (or resume training of) the network of ``cfg`` and save it to ``out``.

    Returns:
        The training record saved in ``model.json`` (steps, examples, throughput, time,
        validation metrics).

    Raises:
        GalileoError: bad settings or scene (see :func:`setup`).
    """
    import shutil

    import jax
    import numpy as np
    import orbax.checkpoint as ocp
    from tqdm import tqdm
    from galileo_jax.inference import cnn_files

    from galileo_jax.jaxcache import enable_compilation_cache

    enable_compilation_cache()
    s, state = setup(cfg, scene)
    work = out.with_name(out.name + ".train")
    if fresh:
        shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True, exist_ok=True)
    manager = _checkpoint_manager(work)
    restored = manager.latest_step() is not None
    state = _restore(manager, state)
    lineage = None
    if cfg.init_from:  # a resumed fine-tuning run keeps its checkpoint, and its lineage
        tuned, lineage = _init_from(s, state, Path(cfg.init_from))
        state = state if restored else tuned
    start = int(state.step)
    step_fn = make_train_step(s)
    evaluate = make_eval_fn(s)
    x_val, th_val = validation_set(s, cfg.validation)
    per_step = cfg.rollouts * cfg.views
    log = (work / "metrics.jsonl").open("a")
    bar = tqdm(total=cfg.steps, initial=start, desc="training", unit="step", disable=not progress, dynamic_ncols=True)
    t_start = time.perf_counter()
    t_log, n_log, metrics, val = t_start, 0, {}, {}
    compile_s = None
    try:
        for i in range(start, cfg.steps):
            t0 = time.perf_counter()
            state, metrics = step_fn(state)
            if compile_s is None:
                jax.block_until_ready(metrics["loss"])
                compile_s = time.perf_counter() - t0
                t_log, n_log = time.perf_counter(), 0
            else:
                n_log += 1
            bar.update(1)
            done = i + 1
            if done % cfg.log_every == 0 or done == cfg.steps:
                val = {k: float(v) for k, v in evaluate(state.params, x_val, th_val).items()}
                now = time.perf_counter()
                rate = n_log * per_step / max(now - t_log, 1e-9) if n_log else float("nan")
                t_log, n_log = now, 0
                row = {"step": done, "loss": float(metrics["loss"]), "grad_norm": float(metrics["grad_norm"]),
                       "examples_per_s": rate, "rollouts_per_s": rate / cfg.views,
                       "elapsed_s": now - t_start, **{f"val_{k}": v for k, v in val.items()}}
                log.write(json.dumps(row) + "\n")
                log.flush()
                if not (np.isfinite(row["loss"]) and np.isfinite(row["val_loss"])):
                    raise GalileoError(f"training diverged by step {done} (the loss is not finite); lower "
                                       f"learning_rate, or rerun to resume from the last checkpoint")
                bar.set_postfix(loss=f"{row['loss']:.3f}", val=f"{val['loss']:.3f}")
            if done % cfg.checkpoint_every == 0 or done == cfg.steps:
                manager.save(done, args=ocp.args.StandardSave(state))
        manager.wait_until_finished()
    finally:
        bar.close()
        log.close()
        manager.close()
    rows = [json.loads(line) for line in (work / "metrics.jsonl").read_text().splitlines() if line.strip()]
    rates = [r["examples_per_s"] for r in rows if np.isfinite(r.get("examples_per_s", float("nan")))]
    info = {"trained_steps": int(state.step), "examples_seen": int(state.step) * per_step,
            "rollouts_simulated": int(state.step) * cfg.rollouts,
            "examples_per_s": float(np.median(rates)) if rates else None,
            "compile_s": compile_s, "session_s": time.perf_counter() - t_start,
            "train_s_total": float(rows[-1]["elapsed_s"]) if rows else None,
            "validation": val or (rows[-1] if rows else {}),
            "config": json.loads(cfg.model_dump_json()), "machine": _machine()}
    if lineage is not None:
        info["initialised_from"] = lineage
        info["trained_steps_total"] = int(state.step) + lineage.get("trained_steps_total", lineage["trained_steps"])
    cnn_files.save_model(out, s.spec, state.params, info)
    return info


def _init_from(s: Setup, state: TrainState, path: Path) -> tuple[TrainState, dict]:
    """``state`` with the weights of the trained model in folder ``path`` (``TrainConfig.init_from``)
    and a fresh optimiser state, and that model's lineage for the new model's record: {"model",
    "trained_steps", "trained_steps_total", "train_s_total", "validation", "initialised_from" (its
    own, if it was fine-tuned too)}.

    Raises:
        GalileoError: not a model folder, or its network differs from the config's.
    """
    from galileo_jax.inference import cnn_files
    from galileo_jax.inference.cnn import CNNError

    try:
        model = cnn_files.load_model(path)
    except CNNError as err:
        raise GalileoError(f"init_from: {err}") from None
    if model.spec != s.spec:
        raise GalileoError(f"init_from: the network in {path} differs from this config's (width, hidden, samples, "
                           "scene or family); start from a model trained with the same settings")
    params = model.params
    info = model.info
    lineage = {"model": str(path), "trained_steps": int(info.get("trained_steps", 0)),
               "trained_steps_total": int(info.get("trained_steps_total", info.get("trained_steps", 0))),
               "train_s_total": info.get("train_s_total"), "validation": info.get("validation", {})}
    if "initialised_from" in info:
        lineage["initialised_from"] = info["initialised_from"]
    return state._replace(params=params, opt_state=s.tx.init(params)), lineage


def _machine() -> str:
    import platform

    import jax

    return f"{platform.machine()}, {os.cpu_count()} CPU cores, {jax.devices()[0].platform}"


@cli_entry
def main(argv: list[str] | None = None) -> int:
    p = OneLineParser(prog="python -m galileo_jax.train",
                      description="Train the amortised-inference CNN on simulations of a scene (never stored on disk).")
    p.add_argument("--config", help="settings (YAML; see configs/cnn_ramp20.yaml)")
    p.add_argument("--scene", help="scene file (overrides the config's scene)")
    p.add_argument("--out", help="model folder (overrides the config's out)")
    p.add_argument("--steps", type=int, help="training steps (overrides the config)")
    p.add_argument("--architecture", choices=("profile", "seed"), help="network (overrides the config)")
    p.add_argument("--init-from", help="trained model folder to start from (fine-tuning; overrides the config)")
    p.add_argument("--learning-rate", type=float, help="peak learning rate (overrides the config)")
    p.add_argument("--fresh", action="store_true", help="ignore checkpoints of an earlier run and start again")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    args = p.parse_args(argv)
    cfg = load_train_config(args.config)
    updates = {k: v for k, v in (("scene", args.scene), ("out", args.out), ("steps", args.steps),
                                 ("architecture", args.architecture), ("init_from", args.init_from),
                                 ("learning_rate", args.learning_rate)) if v is not None}
    if args.steps is not None and args.steps < 1:
        raise GalileoError(f"--steps must be a positive integer, got {args.steps}")
    if args.learning_rate is not None and not args.learning_rate > 0:
        raise GalileoError(f"--learning-rate must be positive, got {args.learning_rate}")
    cfg = cfg.model_copy(update=updates)
    if args.scene is not None and not Path(args.scene).is_file():
        raise GalileoError(f"scene file {args.scene} not found; check the path")
    out = Path(cfg.out)
    info = train(cfg, out=out, fresh=args.fresh, progress=not args.quiet)
    val = info["validation"]
    maes = ", ".join(f"{k[4:]} {v:.4g}" for k, v in val.items() if k.startswith("mae_"))
    print(f"trained {info['trained_steps']} steps ({info['examples_seen']} simulated examples, "
          f"{info['examples_per_s'] or float('nan'):.0f}/s); validation MAE: {maes}; model: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
