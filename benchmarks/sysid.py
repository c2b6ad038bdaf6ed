"""Our ``grad`` next to MuJoCo's own system identification (``mujoco.sysid``), same profiles, same parameters.

Issue 5, benchmark 3. For ``--sets`` random true parameter sets of the 20 degree two-box scene
(``scenes/ramp_20.yaml``; informative draws as ``synth --random`` makes them: object 1 slides
and reaches object 2), an observation is simulated (``--truth c``: C MuJoCo,
:func:`galileo_jax.synth.simulate_motion`, the renderer's physics; ``--truth mjx``:
:func:`galileo_jax.inference.problem.simulated_observation`) and Gaussian position noise
(``--noise`` m, per x and z trace) is added. The objects are released at a known time
(``--rest`` frames), so neither side fits the release time (``simulation.fit_release: false``):
both fit theta = (k1, k2, phi) and nothing else. Then:

* ``grad`` (ours): :func:`~galileo_jax.inference.grad.fit_grad` on a
  :class:`~galileo_jax.inference.problem.Problem` (rollouts on ``--engine``: ``mjx``, MJX's
  vmapped rollouts, or ``mujoco``, C MuJoCo's batched ``mujoco.rollout``; default the engine
  ``fit --engine auto`` picks with the default settings here, :func:`galileo_jax.config.resolve_engine`:
  ``mujoco`` on a CPU; finite-difference Jacobian with step 0.05 in the logit coordinates, Levenberg-Marquardt, polish), with the
  default settings of ``configs/fit.yaml`` (likelihood ``gaussian_iid``, sd_model 0.05 m/s;
  4 starts, the best of a 256-point screen; 40 steps), and from one given start.
* ``sysid``: ``mujoco.sysid.optimize`` (shipped with mujoco 4.0.0; ``pip install
  "mujoco[sysid]"`` for its extra dependencies colorama, tabulate, plotly, ...) on the same
  scene as a C MuJoCo model (:func:`galileo_jax.physics.model.build_spec` plus two ``framepos``
  sensors on the objects' bodies). Parameters (``sysid.Parameter`` with MjSpec modifiers):
  k1 and k2 write both sliding columns of the object's contact pairs with the ramp and the
  floor (the model carries friction in pairs, as :func:`galileo_jax.physics.model.set_physics` and
  :func:`galileo_jax.physics.simulate.apply_params` do), and ``m1`` writes object 1's geom mass with
  object 2's fixed at 0.5 kg (the compiler then recomputes the inertia and ``invweight0``, as
  ``mj_setConst`` does); ``param=phi`` instead writes phi into both masses (total 1 kg). The
  measured data are a ``sysid.ModelSequences`` (no actuators: a zero-width control series
  sets the rollout length; initial state at rest at the scene's start poses; the noisy
  positions at the frame times as the framepos sensor series) and the residual is sysid's own
  ``build_residual_fn`` with a ``modify_residual`` callback: it samples the predicted sensor
  series at the frame times (minus the release time), differences the x and z of both
  objects at 30 fps into the velocity profile exactly as ``simulate.velocity_profile`` does
  (``mj_step`` computes the sensors before it integrates, so a rollout's sensor row k is the
  state at k dt although sysid stamps it (k + 1) dt; the callback uses the true times, and
  ``tests/test_sysid_benchmark.py`` checks the residual against ``synth.simulate_motion``),
  and whitens (observed - simulated) with the SAME per-trace weights as our likelihood
  (``Likelihood.whiten``), so both minimise the same cost 0.5 |r|^2, one in MJX, one in C.

Variants (``--sysid``, specs ``backend[:key=value;...]``): ``mujoco`` is sysid as shipped
(its default backend ``mujoco.minimize.least_squares``: Levenberg-Marquardt-style
regularised Gauss-Newton, forward differences with step 1.5e-8 x max(1, |x|)); ``scipy`` its
scipy backend (``scipy.optimize.least_squares``, 2-point differences); ``mujoco:eps=0.01``
the default backend with a 1% difference step; ``...;x_scale=jac`` with Jacobian column
scaling; also ``scipy:diff_step=0.01``, ``...;param=phi`` (the phi parametrisation),
``...;max_iters=N``. Starts: ``shared`` (one random point per set, k1 in
[0.05, tan 20 - 0.05] so that object 1 slides, k2 in [0.05, 0.6], phi in [-0.6, 0.6]; the same
point for both tools), ``default`` (ours: the 4 best of a 256-point screen; sysid: the
model's nominal values k1 = k2 = 0.3, m1 = m2 = 0.5 kg, i.e. phi = 0) and, for sysid,
``screened``: one run from each of grad's 4 screened starts, the lowest end cost wins (the
same starts as ours, without the screen's cost: 256 MJX rollouts, about 2 s).

Our rows are named by engine, ``grad (mjx)`` and ``grad (mujoco)``. A run with one engine
keeps the other engine's grad rows of the JSON (same settings) and runs sysid again, so the
sysid rows and this engine's grad rows come from the same run (same load). Records written
before ``--engine`` existed hold MJX grad rows named ``grad``: read as ``grad (mjx)``.

Per set and method: |error| of k1, k2, phi; the profile RMSE (m/s, all four traces) of the
estimate against the observation, simulated in C MuJoCo and in MJX, and 0.5 |r|^2 in both;
wall time (ours: compilation excluded, every configuration runs once on a warm-up set first;
the warm-up times are reported as "first call", measured without JAX's persistent
compilation cache unless ``--cache``; sysid's rollouts run on ``os.cpu_count()`` C threads
through ``mujoco.rollout``, ours on XLA's CPU threads); simulations (sysid: rollouts counted
in the residual callback; ours: rollouts the batched programs ask for, counted from the
iteration counts, :func:`galileo_jax.inference.grad.count_rollouts`: on the C engine fewer are
simulated, as its callback remembers recent rollouts); iterations. Writes
``benchmarks/results/sysid.{md,json}`` atomically after each set; rerunning with the same
settings resumes from the JSON (``--fresh``: start again).

    nice -n 19 python benchmarks/sysid.py --engine mujoco   # 5 sets
    nice -n 19 python benchmarks/sysid.py --engine mjx      # 5 sets: 12 min on 2 busy cores
    python benchmarks/sysid.py --sets 20 --truth mjx --out benchmarks/results/sysid_mjx
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import logging
import math
import os
import re
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
sys.path.insert(0, str(Path(__file__).resolve().parent))  # _common, also when loaded by path (tests)
from _common import machine_line  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
NAMES = ("k1", "k2", "phi")
#: Object 2's mass (kg) held fixed in sysid's ``m1`` parametrisation (the model's nominal mass).
M2_FIXED = 0.5
#: |phi| bound used for sysid's box bounds (phi = +-1 is a zero mass).
PHI_MAX = 0.98
#: grad's polish (rounds, points): fit_grad's defaults, as fit runs it.
POLISH = (3, 64)


# --------------------------------------------------------------------------- observation
def load_fit_scene():
    from galileo_jax.scene import load_scene

    scene = load_scene(ROOT / "scenes" / "ramp_20.yaml")
    return scene.model_copy(update={"simulation": scene.simulation.model_copy(update={"fit_release": False})})


def theta_to_phys(theta):
    """(k1, k2, phi) -> PhysParams with total mass 1 kg (the profile depends on the ratio only)."""
    from galileo_jax.physics.simulate import PhysParams

    k1, k2, phi = (float(v) for v in theta)
    return PhysParams(np.array([0.5 * (1 + phi), 0.5 * (1 - phi)]), np.array([k1, k2]))


def c_positions(scene, theta, fps: float, rest: int, n_frames: int) -> np.ndarray:
    """(N, 2, 2) object centres (x, z) at the frames, C MuJoCo (the renderer's simulation)."""
    from galileo_jax.synth import simulate_motion

    return simulate_motion(scene, theta_to_phys(theta), fps, rest, n_frames=n_frames).positions


def make_observation(scene, theta, args, seed: int):
    """Noisy observation of theta (k1, k2, phi), simulated in C MuJoCo or MJX."""
    from galileo_jax.inference.problem import simulated_observation
    from galileo_jax.observation import Observation, profile_from_positions

    fps, rest, n_frames = args.fps, args.rest, n_frames_of(args)
    if args.truth == "mjx":
        return simulated_observation(scene, theta_to_phys(theta), fps=fps, duration=(n_frames - 1) / fps,
                                     position_sd=args.noise, release_time=rest / fps, seed=seed)
    ft = np.arange(n_frames) / fps
    pos = c_positions(scene, theta, fps, rest, n_frames)
    rng = np.random.default_rng(seed)
    noisy = pos + rng.normal(size=pos.shape) * args.noise
    moved = np.abs(pos[-1, :, 0] - pos[0, :, 0]) > 1e-3
    return Observation(frame_times=ft, positions=noisy, pixels=noisy * scene.camera.scale,
                       profile=profile_from_positions(noisy, ft), position_sd=np.full(4, args.noise),
                       mask=np.ones(n_frames - 1, bool), release_time=rest / fps, fps=fps, moved=moved)


def n_frames_of(args) -> int:
    return int(round(args.duration * args.fps)) + 1


def draw_set(scene, i: int, args) -> tuple[np.ndarray, np.ndarray]:
    """(truth theta, shared start theta) of set i (-1: the warm-up set)."""
    from galileo_jax.synth import draw_informative_params

    rng = np.random.default_rng([args.seed, i + 1])
    p = draw_informative_params(scene, rng, (), fps=args.fps, rest_frames=args.rest, n_frames=n_frames_of(args))
    truth = np.array([p["k1"], p["k2"], (p["m1"] - p["m2"]) / (p["m1"] + p["m2"])])
    k1_hi = math.tan(scene.ramp.angle) - 0.05
    start = np.array([rng.uniform(0.05, k1_hi), rng.uniform(0.05, 0.6), rng.uniform(-0.6, 0.6)])
    return truth, start


# --------------------------------------------------------------------------- common referee
class Referee:
    """Profile RMSE and cost of any theta against one observation, in C MuJoCo and in MJX
    (``problem`` must run on MJX)."""

    def __init__(self, scene, obs, problem, args):
        self.scene, self.obs, self.problem, self.args = scene, obs, problem, args
        n = obs.profile.shape[1]
        self.whiten = np.asarray(problem.likelihood.whiten)[:, :n]
        self.mask = np.asarray(obs.mask, bool)

    def _score(self, sim: np.ndarray) -> tuple[float, float]:
        r = (self.obs.profile - sim)[:, self.mask]
        w = (self.whiten * (self.obs.profile - sim))[:, self.mask]
        return float(np.sqrt(np.mean(r**2))), float(0.5 * np.sum(w**2))

    def __call__(self, theta) -> dict:
        from galileo_jax.observation import profile_from_positions

        pos = c_positions(self.scene, theta, self.args.fps, self.args.rest, self.obs.frame_times.size)
        rmse_c, cost_c = self._score(profile_from_positions(pos, self.obs.frame_times))
        rmse_m, cost_m = self._score(np.asarray(self.problem.simulate(np.asarray(theta, np.float64)), np.float64))
        return {"rmse_c": rmse_c, "rmse_mjx": rmse_m, "cost_c": cost_c, "cost_mjx": cost_m}


# --------------------------------------------------------------------------- ours
def run_grad(problem, cfg, start, mode: str) -> dict:
    import jax

    from galileo_jax.inference import fit_grad
    from galileo_jax.inference.grad import count_rollouts

    kw = dict(max_steps=cfg.grad.max_steps, jacobian=cfg.grad.jacobian, polish_rounds=POLISH[0],
              polish_points=POLISH[1])
    if mode == "default":
        kw.update(n_starts=cfg.grad.starts, n_screen=cfg.grad.screen)
    else:
        kw.update(n_starts=0, init=np.asarray(start, np.float64))
    t = time.perf_counter()
    res = fit_grad(problem, jax.random.PRNGKey(1), **kw)
    elapsed = time.perf_counter() - t
    names = list(problem.space.names)
    theta = np.array([res.theta[names.index(n)] for n in NAMES])
    return {"theta": theta.tolist(), "time_s": elapsed, "starts": _starts(res, names),
            "simulations": count_rollouts(res, n_screen=cfg.grad.screen if mode == "default" else 0,
                                          polish_rounds=POLISH[0], polish_points=POLISH[1]),
            "iterations": int(np.sum(res.starts_iterations)), "iterations_best": int(res.iterations),
            "converged": bool(res.converged), "message": res.result or "successful"}


def _starts(res, names) -> list[list[float]]:
    """The fit's LM starting points as (k1, k2, phi) rows."""
    return [[float(row[names.index(n)]) for n in NAMES] for row in np.asarray(res.starts_theta0)]


# --------------------------------------------------------------------------- mujoco.sysid
def parse_variant(spec: str) -> tuple[str, dict]:
    """'backend[:k=v;k=v]' -> (backend, options)."""
    backend, _, rest = spec.partition(":")
    if backend not in ("mujoco", "scipy", "scipy_parallel_fd"):
        raise SystemExit(f"error: --sysid {spec!r}: backend must be mujoco, scipy or scipy_parallel_fd")
    opts = {}
    for item in filter(None, rest.split(";")):
        key, _, val = item.partition("=")
        if key in ("param", "x_scale") and not _is_number(val):
            opts[key] = val
        elif key in ("eps", "diff_step", "x_scale", "xtol", "gtol", "ftol"):
            opts[key] = float(val)
        elif key == "max_iters":
            opts[key] = int(val)
        else:
            raise SystemExit(f"error: --sysid {spec!r}: unknown option {key!r} (eps, diff_step, x_scale, "
                             f"xtol, gtol, ftol, max_iters, param)")
    if opts.get("param", "m1") not in ("m1", "phi"):
        raise SystemExit(f"error: --sysid {spec!r}: param must be m1 or phi")
    return backend, opts


def _is_number(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


class SysidSetup:
    """The observation as a ``mujoco.sysid`` problem (module docstring)."""

    def __init__(self, scene, obs, whiten: np.ndarray, args):
        import mujoco
        from mujoco import sysid

        from galileo_jax.physics.model import build_spec
        from galileo_jax.physics.simulate import physics_timestep

        self.sysid = sysid
        self.obs = obs
        self.fps = float(obs.fps)
        self.ft = np.asarray(obs.frame_times, np.float64)
        self.release = float(obs.release_time)
        self.whiten = whiten
        dt = physics_timestep(self.fps, scene.simulation.substeps)
        spec = build_spec(scene)
        spec.option.timestep = dt
        for i in (1, 2):
            spec.add_sensor(name=f"object{i}_pos", type=mujoco.mjtSensor.mjSENS_FRAMEPOS,
                            objtype=mujoco.mjtObj.mjOBJ_BODY, objname=f"object{i}")
        self.spec = spec
        model = spec.compile()
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        init = sysid.create_initial_state(model, data.qpos.copy(), np.zeros(model.nv))
        n_steps = int(math.ceil((self.ft[-1] - self.release) / dt - 1e-9)) + 2  # sensors lag one step
        control = sysid.TimeSeries(np.arange(n_steps + 1) * dt, np.zeros((n_steps + 1, 0)))
        meas = np.zeros((self.ft.size, 6))
        meas[:, [0, 2]] = obs.positions[:, 0]
        meas[:, [3, 5]] = obs.positions[:, 1]
        self.sequences = sysid.ModelSequences("ramp", spec, "observed", init,
                                              control, sysid.TimeSeries.from_names(self.ft, meas, model))
        self.rollouts = 0

    def modify_residual(self, params, pred, measured, model, return_pred_all, state=None, **_):
        """sysid callback: predicted framepos series -> whitened velocity-profile residual."""
        self.rollouts += 1
        # mj_step evaluates the sensors before it integrates, so row k of a rollout's sensordata
        # is the state at k dt (row 0: the initial state), although sysid stamps it (k + 1) dt.
        t = np.asarray(pred.times) - model.opt.timestep
        p = np.asarray(pred.data)
        s = np.clip(self.ft - self.release, 0.0, None)
        pos = np.stack([np.interp(s, t, p[:, j]) for j in range(p.shape[1])], axis=1)
        cols = [0, 2, 3, 5]  # object 1 x, z; object 2 x, z: the profile's row order
        sim = np.diff(pos[:, cols], axis=0).T * self.fps
        ob = np.diff(np.asarray(measured.data)[:, cols], axis=0).T * self.fps
        res = (self.whiten * (ob - sim)).ravel()
        if not np.all(np.isfinite(res)):
            res = np.full_like(res, 1e6)
        return res, self.sysid.TimeSeries(self.ft, pos, measured.signal_mapping), measured

    def params(self, theta, param: str):
        """ParameterDict (k1, k2, m1 or phi) starting at theta (k1, k2, phi)."""
        sysid = self.sysid

        def friction(i):
            def apply(spec, p):
                for surf in ("ramp", "floor"):
                    pair = spec.pair(f"object{i}_{surf}")
                    if pair is not None:
                        pair.friction[0:2] = float(p.value[0])
            return apply

        def mass1(spec, p):
            spec.geom("object1").mass = float(p.value[0])

        def phi(spec, p):
            spec.geom("object1").mass = 0.5 * (1.0 + float(p.value[0]))
            spec.geom("object2").mass = 0.5 * (1.0 - float(p.value[0]))

        k1, k2, ph = (float(v) for v in theta)
        pd = sysid.ParameterDict()
        pd.add(sysid.Parameter("k1", k1, 0.0, 1.0, modifier=friction(1)))
        pd.add(sysid.Parameter("k2", k2, 0.0, 1.0, modifier=friction(2)))
        if param == "phi":
            pd.add(sysid.Parameter("phi", ph, -PHI_MAX, PHI_MAX, modifier=phi))
        else:
            lo, hi = (M2_FIXED * (1 + v) / (1 - v) for v in (-PHI_MAX, PHI_MAX))
            pd.add(sysid.Parameter("m1", M2_FIXED * (1 + ph) / (1 - ph), lo, hi, modifier=mass1))
        return pd

    def run(self, theta0, backend: str, opts: dict) -> dict:
        sysid = self.sysid
        opts = dict(opts)
        param = opts.pop("param", "m1")
        pd = self.params(theta0, param)
        rfn = sysid.build_residual_fn(models_sequences=[self.sequences], modify_residual=self.modify_residual,
                                      resample_true=False)
        out = io.StringIO()
        if backend == "mujoco":
            # sysid always runs its backends verbosely (per-iteration log): keep the log, it
            # gives the iterations and the stop reason
            opts.update(output=out)
        self.rollouts = 0
        t = time.perf_counter()
        with contextlib.redirect_stdout(out):
            opt, result = sysid.optimize(pd, rfn, optimizer=backend, verbose=False, **opts)
        elapsed = time.perf_counter() - t
        x = opt.as_vector()
        r = np.concatenate(rfn(x, opt.copy())[0])  # the end point's cost (not timed, not counted)
        ph = float(x[2]) if param == "phi" else float((x[2] - M2_FIXED) / (x[2] + M2_FIXED))
        log = out.getvalue()
        if backend == "mujoco":
            stop = [ln for ln in log.splitlines() if ln.startswith("Terminated")]
            message = stop[-1] if stop else ""
            found = re.match(r"Terminated after (\d+) iterations", message)
            iterations = int(found.group(1)) if found else len(result.extras.get("objective", []))
        else:
            message = str(getattr(result, "message", ""))
            iterations = int(getattr(result, "nfev", 0))
        return {"theta": [float(x[0]), float(x[1]), ph], "time_s": elapsed, "simulations": int(self.rollouts) - 1,
                "iterations": iterations, "message": message.strip(), "cost": float(0.5 * r @ r)}

    def run_multi(self, starts, backend: str, opts: dict) -> dict:
        """One run from each start; the lowest end cost wins (times, simulations, iterations summed)."""
        runs = [self.run(th0, backend, opts) for th0 in starts]
        best = min(runs, key=lambda r: r["cost"] if np.isfinite(r["cost"]) else np.inf)
        return {**best, "time_s": sum(r["time_s"] for r in runs), "simulations": sum(r["simulations"] for r in runs),
                "iterations": sum(r["iterations"] for r in runs), "starts_cost": [r["cost"] for r in runs]}


# --------------------------------------------------------------------------- one set
def grad_name(engine: str) -> str:
    """Our method's name in the tables, by engine."""
    return f"grad ({engine})"


def run_set(scene, cfg, i: int, args, variants) -> dict:
    """Set i: our grad on ``args.engine`` (default and shared start), then every sysid variant."""
    from galileo_jax.inference import Problem

    truth, start = draw_set(scene, i, args)
    obs = make_observation(scene, truth, args, seed=args.seed * 1000 + i + 1)
    kw = dict(likelihood=cfg.likelihood.kind, sd_model=cfg.likelihood.sd_model)
    problem = Problem(scene, obs, engine=args.engine, **kw)
    if list(problem.space.names) != list(NAMES):
        raise SystemExit(f"error: expected parameters {NAMES}, the problem has {problem.space.names}")
    referee = Referee(scene, obs, problem if args.engine == "mjx" else Problem(scene, obs, engine="mjx", **kw), args)
    setup = SysidSetup(scene, obs, referee.whiten, args)
    default_start = np.array([0.3, 0.3, 0.0])  # the model's nominal frictions and equal masses
    runs = {}
    ours = grad_name(args.engine)
    for mode in ("default", "shared"):
        runs[f"{ours} | {mode}"] = run_grad(problem, cfg, start, mode)
    screened = runs[f"{ours} | default"]["starts"]
    for v in variants:
        backend, opts = parse_variant(v)
        for mode, th0 in (("default", default_start), ("shared", start)):
            runs[f"sysid {v} | {mode}"] = setup.run(th0, backend, opts)
        runs[f"sysid {v} | screened"] = setup.run_multi(screened, backend, opts)
    for r in runs.values():
        r["error"] = {n: abs(r["theta"][j] - float(truth[j])) for j, n in enumerate(NAMES)}
        r.update(referee(r["theta"]))
    return {"set": i, "truth": dict(zip(NAMES, truth.tolist())), "start_shared": dict(zip(NAMES, start.tolist())),
            "start_default_sysid": dict(zip(NAMES, default_start.tolist())), "at_truth": referee(truth),
            "at_start": referee(start), "runs": runs}


# --------------------------------------------------------------------------- tables


def _values(rs, key) -> np.ndarray:
    """The runs' ``key`` as floats, NaN where it is missing (JSON null: a rollout that was not finite)."""
    return np.array([np.nan if r.get(key) is None else float(r[key]) for r in rs])


def summarise(records: list[dict]) -> dict:
    """Per method: mean |error|, mean RMSE / cost in C MuJoCo, median RMSE / cost in MJX (MJX can
    blow up at an estimate that C MuJoCo simulates fine, e.g. k2 = 0 on its bound), mean and
    median time, mean simulations and iterations."""
    methods = list(dict.fromkeys(m for r in records for m in r["runs"]))
    out = {}
    for m in methods:
        rs = [r["runs"][m] for r in records if m in r["runs"]]
        row = {"sets": len(rs)}
        for n in NAMES:
            row[f"mae_{n}"] = float(np.mean([r["error"][n] for r in rs]))
        for key in ("rmse_c", "cost_c", "time_s", "simulations", "iterations"):
            row[key] = float(np.mean(_values(rs, key)))
        for key in ("rmse_mjx", "cost_mjx"):
            v = _values(rs, key)
            row[key + "_median"] = float(np.median(np.where(np.isfinite(v), v, np.inf)))
        v = _values(rs, "rmse_mjx")
        row["mjx_blown_up"] = int(np.sum(~(v < 1.0)))  # not finite, or > 1 m/s (the objects move < 1 m/s)
        row["time_s_median"] = float(np.median(_values(rs, "time_s")))
        out[m] = row
    for key in ("at_truth", "at_start"):
        out[key] = {k: float(np.nanmean(_values([r[key] for r in records], k)))
                    for k in ("rmse_c", "rmse_mjx", "cost_c", "cost_mjx")}
    return out


def _fmt(v, spec: str = ".4f") -> str:
    return "n/a" if v is None or not np.isfinite(v) else format(v, spec)


def write_tables(path: Path, doc: dict) -> None:
    from galileo_jax.report.results import atomic_path, write_json

    records = doc["records"]
    doc["summary"] = summarise(records) if records else {}
    write_json(path.with_suffix(".json"), doc)
    s, a = doc["settings"], doc["summary"]
    lines = [f"# grad vs mujoco.sysid ({len(records)} parameter sets, 20 degree two-box scene)", "",
             f"machine: {doc['machine']}", "",
             f"Command: `{doc['command']}` (module docstring of `benchmarks/sysid.py`). Observation: "
             f"{s['duration']} s at {s['fps']} fps simulated in {'C MuJoCo' if s['truth'] == 'c' else 'MJX'}, "
             f"released after {s['rest']} frames (known to both: theta = k1, k2, phi), position noise "
             f"{s['noise'] * 1000:g} mm. Both minimise the same whitened velocity-profile cost 0.5 |r|^2 "
             "(gaussian_iid, sd_model 0.05 m/s); grad on the engine in its name (mjx: MuJoCo-MJX, mujoco: C "
             "MuJoCo), sysid in C MuJoCo. Mean over sets: |error|; "
             "RMSE (m/s, all four traces) and cost of the estimate's profile simulated in C MuJoCo (C; mean) and "
             "MJX (median: MJX blows up at some estimates C MuJoCo simulates fine, such as k2 = 0 on its bound; "
             "'MJX blown up' counts them: rollout not finite or RMSE > 1 m/s); "
             "time: wall time per fit, mean (median), compilation excluded for grad; simulations: rollouts "
             "(grad: asked for by its batched programs, fewer simulated on C MuJoCo, whose callback remembers recent "
             "rollouts; sysid: counted in its residual callback); iterations: "
             "grad LM steps of all starts; sysid mujoco backend iterations, scipy backend function evaluations.", ""]
    runs_of = doc.get("engine_runs", {})
    if runs_of:
        lines += ["Runs: " + "; ".join(f"grad ({e}): `{c}`" for e, c in runs_of.items()) + ". The sysid rows come "
                  f"from the last run (`{doc['command']}`), together with that run's grad rows; another engine's "
                  "grad rows were measured in their own run (other load: compare its times with care).", ""]
    if "compile" in doc:
        cache = "on: programs found in the cache are not compiled again" if s.get("cache") else "off"
        lines += ["grad's first call (warm-up set, compilation included; persistent compilation cache "
                  f"{cache}): " + ", ".join(
            f"{k} {v:.1f} s" for k, v in doc["compile"].items()) + ".", ""]
    if records:
        t, st = a["at_truth"], a["at_start"]
        lines += [f"At the true parameters: RMSE C {t['rmse_c']:.4f}, MJX {t['rmse_mjx']:.4f} m/s; cost C "
                  f"{t['cost_c']:.1f}, MJX {t['cost_mjx']:.1f}. At the shared starts: RMSE C {st['rmse_c']:.4f} m/s.",
                  "", "| method | start | k1 | k2 | phi | RMSE C | RMSE MJX (median) | cost C | cost MJX (median) | "
                  "MJX blown up | time (s) | simulations | iterations |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for m, row in a.items():
            if m.startswith("at_"):
                continue
            name, mode = m.split(" | ")
            lines.append(f"| {name} | {mode} | {row['mae_k1']:.4f} | {row['mae_k2']:.4f} | {row['mae_phi']:.4f} | "
                         f"{row['rmse_c']:.4f} | {row['rmse_mjx_median']:.4f} | {row['cost_c']:.1f} | "
                         f"{row['cost_mjx_median']:.1f} | {row['mjx_blown_up']} | "
                         f"{row['time_s']:.2f} ({row['time_s_median']:.2f}) | {row['simulations']:.0f} | "
                         f"{row['iterations']:.0f} |")
        methods = [m for m in a if not m.startswith("at_")]
        lines += ["", "Per set: truth, then per method estimate k1 / k2 / phi, RMSE C (m/s), time (s), stop reason:",
                  ""]
        for r in records:
            tr = r["truth"]
            lines += [f"**set {r['set']}**: truth k1 {tr['k1']:.3f}, k2 {tr['k2']:.3f}, phi {tr['phi']:.3f}; "
                      f"shared start {', '.join(format(r['start_shared'][n], '.3f') for n in NAMES)}; RMSE at truth "
                      f"C {r['at_truth']['rmse_c']:.4f}, MJX {_fmt(r['at_truth']['rmse_mjx'])}", "",
                      "| method | start | k1 | k2 | phi | RMSE C | time (s) | simulations | stop |",
                      "|---|---|---|---|---|---|---|---|---|"]
            for m in methods:
                if m not in r["runs"]:
                    continue
                x = r["runs"][m]
                name, mode = m.split(" | ")
                lines.append(f"| {name} | {mode} | {x['theta'][0]:.4f} | {x['theta'][1]:.4f} | {x['theta'][2]:.4f} | "
                             f"{x['rmse_c']:.4f} | {x['time_s']:.2f} | {x['simulations']} | {x['message']} |")
            lines.append("")
    with atomic_path(path.with_suffix(".md")) as tmp:
        tmp.write_text("\n".join(lines) + "\n")


# --------------------------------------------------------------------------- main
def read_previous(path: Path, ours: str, fresh: bool) -> dict:
    """The JSON of an earlier run, grad rows named by engine (rows named ``grad``, from before
    ``--engine``, are MJX's); with ``fresh``, without ``ours``'s rows (the other engine's stay)."""
    prev = json.loads(path.read_text())
    rename = lambda m: "grad (mjx)" + m[len("grad"):] if m.startswith("grad |") else m  # noqa: E731
    for r in prev.get("records", []):
        r["runs"] = {rename(m): v for m, v in r["runs"].items() if not (fresh and m.startswith(ours))}
    prev["compile"] = {rename(m): v for m, v in prev.get("compile", {}).items() if not (fresh and m.startswith(ours))}
    if "engine_runs" not in prev and any("grad (mjx) | default" in r["runs"] for r in prev.get("records", [])):
        prev["engine_runs"] = {"mjx": prev.get("command", "") + " (before --engine: MJX)"}
    return prev


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", type=int, default=5, help="random true parameter sets")
    ap.add_argument("--duration", type=float, default=2.0, help="observation length in s")
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--rest", type=int, default=3, help="frames at rest before the release")
    ap.add_argument("--noise", type=float, default=1e-3, help="position noise SD in m")
    ap.add_argument("--truth", choices=("c", "mjx"), default="c", help="simulator that makes the observation")
    ap.add_argument("--sysid", nargs="+", default=["mujoco", "scipy", "mujoco:eps=0.01", "mujoco:eps=0.01;x_scale=jac"],
                    help="mujoco.sysid variants, backend[:key=value;...] (module docstring)")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--engine", choices=("mjx", "mujoco"), default=None,
                    help="simulation engine of our grad (default: what fit --engine auto picks here)")
    ap.add_argument("--out", default=str(RESULTS / "sysid"), help="results stem (.md and .json are added)")
    ap.add_argument("--no-warmup", action="store_true",
                    help="skip the warm-up set (grad's times then include compilation)")
    ap.add_argument("--fresh", action="store_true", help="run every set again (drop this engine's grad rows; the other engine's stay)")
    ap.add_argument("--cache", action="store_true",
                    help="use JAX's persistent compilation cache (off by default, so that the first call's time "
                         "measures compilation)")
    args = ap.parse_args(argv)
    for v in args.sysid:
        parse_variant(v)
    try:
        from mujoco import sysid  # noqa: F401

        sysid.optimize  # noqa: B018 (the package swallows missing optional dependencies)
    except (ImportError, AttributeError):
        print("error: mujoco.sysid needs its optional dependencies: pip install \"mujoco[sysid]\"", file=sys.stderr)
        return 2
    logging.getLogger("absl").setLevel(logging.ERROR)
    from galileo_jax.config import FitConfig, resolve_engine
    from galileo_jax.jaxcache import enable_compilation_cache

    if args.cache:
        enable_compilation_cache()
    cfg = FitConfig()
    if args.engine is None:
        args.engine = resolve_engine(cfg)
    scene = load_fit_scene()
    path = Path(args.out)
    settings = {k: getattr(args, k) for k in ("duration", "fps", "rest", "noise", "truth", "sysid", "seed", "cache")}
    shown = [a for a in (sys.argv[1:] if argv is None else argv) if a != "--fresh"]
    if "--engine" not in shown and not any(a.startswith("--engine=") for a in shown):
        shown += ["--engine", args.engine]
    command = " ".join(["python benchmarks/sysid.py", *shown])
    ours = grad_name(args.engine)
    doc = {"machine": machine_line(), "command": command, "engine_runs": {args.engine: command},
           "settings": settings, "records": []}
    old = path.with_suffix(".json")
    if old.exists():
        prev = read_previous(old, ours, fresh=args.fresh)
        if prev.get("settings") == settings:
            doc["records"] = [r for r in prev.get("records", []) if r["set"] < args.sets]
            doc["compile"] = prev.get("compile", {})
            doc["engine_runs"] = {**prev.get("engine_runs", {}), args.engine: command}
    done = {r["set"] for r in doc["records"] if f"{ours} | default" in r["runs"]}
    todo = [i for i in range(args.sets) if i not in done]
    if todo and not args.no_warmup:
        rec = run_set(scene, cfg, -1, args, args.sysid)  # compiles every grad configuration
        doc["compile"] = {**doc.get("compile", {}),
                          **{m: r["time_s"] for m, r in rec["runs"].items() if m.startswith(ours)}}
    for i in todo:
        rec = run_set(scene, cfg, i, args, args.sysid)
        old_rec = next((r for r in doc["records"] if r["set"] == i), None)
        if old_rec is not None:  # keep the other engine's grad rows; sysid's come from this run
            rec["runs"] = {**{m: r for m, r in old_rec["runs"].items() if m.startswith("grad (")}, **rec["runs"]}
            doc["records"].remove(old_rec)
        doc["records"].append(rec)
        doc["records"].sort(key=lambda r: r["set"])
        write_tables(path, doc)
        print(f"set {i}: " + "; ".join(f"{m}: k1 {r['theta'][0]:.3f} k2 {r['theta'][1]:.3f} phi {r['theta'][2]:.3f} "
                                       f"({r['time_s']:.1f} s)" for m, r in rec["runs"].items()), flush=True)
    write_tables(path, doc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
