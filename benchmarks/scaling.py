"""Cost of a fit as the video gets longer and as the MH chains and grad starts grow (log-log).

Issue 5, benchmark 4. Observations of the 20 degree two-box scene (``scenes/ramp_20.yaml``, fit
settings as ``fit`` runs them: release-time nuisance on, so theta = k1, k2, phi, dt_release)
are simulated in MJX (:func:`galileo_jax.inference.problem.simulated_observation`, truth
k1 0.2, k2 0.25, phi 1/3, 1 mm position noise, released at 0.1 s; past about 1.5 s both objects
are at rest and the rest of the video is still). Three sweeps, each point one fixed amount of
work, so the time measures the cost of the work and not how soon a solver stops:

* ``length``: video length (``--lengths``, s) for a ``grad`` fit (4 starts, the best of a
  256-point screen, exactly ``--grad-steps`` Levenberg-Marquardt steps: tolerances 0, no
  polish) and an ``mh`` run (16 chains, ``--mh-steps`` steps, no warm-up);
* ``chains``: ``mh`` with ``--chains`` chains (``--mh-steps`` steps each), ``--base-length`` s video;
* ``starts``: ``grad`` with ``--starts`` starts (screen ``max(256, starts)``, ``--grad-steps``
  steps), ``--base-length`` s video.

Engine (``--engine``): the fits' rollouts run on ``mjx`` or ``mujoco`` (C MuJoCo), default the
one ``fit --engine auto`` picks with the default settings on this machine
(:func:`galileo_jax.config.resolve_engine`: ``mujoco`` on a CPU). Records carry their engine;
a run with one engine keeps the other engine's records in the JSON (same settings), so the
tables and the plot show both. Records written before the option existed were MJX runs.

Large grad batches could hang. fit_grad used to vmap all starts' Levenberg-Marquardt iterations
together, each with its 2d + 1 finite-difference rollouts: 64 starts were 576 rollouts in one
MJX batch, whose Newton solver calls jaxlib's batched LAPACK Cholesky (``lapack_dpotrf_ffi``).
In jaxlib 0.10.2 that kernel splits a large batch over XLA's intra-op thread pool and blocks
waiting for the pieces (``jax::ParallelBatchMap``); when as many such calls run at once as the
pool has threads (2 here), every thread waits and nothing runs: a deadlock (seen with gdb, 2 of
2 tries with 64 starts; 32 starts, 288 rollouts, finished; ``--xla_cpu_multi_thread_eigen=false``
does not help). fit_grad now runs the starts in chunks of at most
:data:`galileo_jax.inference.grad.MAX_LM_STARTS` (16), so 64 starts run. Every point still runs
under a watchdog (``--point-timeout``): a point without a result in time ends its worker
process, is recorded as hung, and a new worker goes on with the rest.

Every configuration runs once first (JAX compiles it; that "first call" time is kept), then
``--repeats`` more times: "time" is their median wall time (compilation excluded). Rollouts
are those the batched programs run (mh: chains x steps; grad: screen + starts x steps x
(2d + 1) + 2 per start + one final Jacobian, every start running the same number of steps).
The log-log slope of time against the swept size is fitted by least squares over all points
and over the upper half (the asymptotic cost, once fixed overheads no longer dominate).
Writes ``benchmarks/results/scaling.{md,json,png}`` atomically after every point; rerunning with
the same settings resumes from the JSON (``--fresh``: start again).

    nice -n 19 python benchmarks/scaling.py --engine mujoco  # defaults: minutes on 2 busy cores
    nice -n 19 python benchmarks/scaling.py --engine mjx     # MJX (13 min without the 64-start point)
    python benchmarks/scaling.py --lengths 1 2 4 8 16 --chains 4 16 64 256 1024 --starts 1 4 16 32 64 --repeats 3
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
from _common import machine_line  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
TRUTH = {"k1": 0.2, "k2": 0.25, "m1": 0.6, "m2": 0.3}  # phi = 1/3, the shipped example's truth
SCREEN = 256


def make_problem(length: float, noise: float, engine: str = "mjx"):
    """The fit problem of a ``length`` s observation (MJX-simulated, ``noise`` m position noise),
    its rollouts on ``engine`` ("mjx" or "mujoco")."""
    from galileo_jax.inference import Problem, simulated_observation
    from galileo_jax.physics.simulate import PhysParams
    from galileo_jax.scene import load_scene

    scene = load_scene(ROOT / "scenes" / "ramp_20.yaml")
    truth = PhysParams(np.array([TRUTH["m1"], TRUTH["m2"]]), np.array([TRUTH["k1"], TRUTH["k2"]]))
    obs = simulated_observation(scene, truth, fps=30.0, duration=length, position_sd=noise, release_time=0.1, seed=0)
    return Problem(scene, obs, engine=engine)


def default_engine() -> str:
    """The engine ``fit --engine auto`` picks with the default settings on this machine."""
    from galileo_jax.config import FitConfig, resolve_engine

    return resolve_engine(FitConfig())


def run_grad(problem, starts: int, steps: int) -> tuple[float, int]:
    """One grad fit of fixed work; returns (wall time s, rollouts)."""
    import jax

    from galileo_jax.inference import fit_grad

    screen = max(SCREEN, starts)
    t = time.perf_counter()
    res = fit_grad(problem, jax.random.PRNGKey(0), n_starts=starts, n_screen=screen, max_steps=steps,
                   rtol=0.0, atol=0.0, polish_rounds=0)
    elapsed = time.perf_counter() - t
    d = problem.dim
    s = len(res.starts_iterations)
    rollouts = screen + s * int(np.max(res.starts_iterations)) * (2 * d + 1) + 2 * s + (2 * d + 1)
    return elapsed, int(rollouts)


def run_mh(problem, chains: int, steps: int) -> tuple[float, int]:
    """One mh run of fixed work (no warm-up, one chunk of ``steps``); returns (wall time s, rollouts)."""
    import jax

    from galileo_jax.inference import run_mh as mh

    t = time.perf_counter()
    res = mh(problem, jax.random.PRNGKey(0), n_chains=chains, n_warmup=0, n_samples=steps, chunk=steps,
             progress=False)
    jax.block_until_ready(res.theta)
    return time.perf_counter() - t, int(chains * steps)


def points(args) -> list[dict]:
    """Every (sweep, method, x) to measure, in order."""
    out = []
    for length in args.lengths:
        out.append({"sweep": "length", "method": "grad", "x": float(length), "length": float(length),
                    "starts": 4, "steps": args.grad_steps})
        out.append({"sweep": "length", "method": "mh", "x": float(length), "length": float(length),
                    "chains": 16, "steps": args.mh_steps})
    for c in args.chains:
        out.append({"sweep": "chains", "method": "mh", "x": int(c), "length": args.base_length, "chains": int(c),
                    "steps": args.mh_steps})
    for s in args.starts:
        out.append({"sweep": "starts", "method": "grad", "x": int(s), "length": args.base_length, "starts": int(s),
                    "steps": args.grad_steps})
    return [{**p, "engine": args.engine} for p in out]


POINT_KEYS = ("method", "engine", "length", "starts", "chains", "steps")


def key_of(p: dict) -> str:
    """What a measurement depends on (not which sweep it belongs to)."""
    return json.dumps({k: p[k] for k in POINT_KEYS if k in p}, sort_keys=True)


def measure(p: dict, problems: dict, args) -> dict:
    from galileo_jax.inference.problem import clear_caches

    if p["length"] not in problems:
        if len(problems) >= 2:  # keep a few compiled programs only (memory maps; problem.clear_caches)
            problems.clear()
            clear_caches()
        problems[p["length"]] = make_problem(p["length"], args.noise, p["engine"])
    problem = problems[p["length"]]
    fn = (lambda: run_grad(problem, p["starts"], p["steps"])) if p["method"] == "grad" else \
        (lambda: run_mh(problem, p["chains"], p["steps"]))
    first, rollouts = fn()
    times = [fn()[0] for _ in range(args.repeats)]
    t = float(np.median(times))
    return {**p, "first_s": first, "times_s": times, "time_s": t, "rollouts": rollouts,
            "rollouts_per_s": rollouts / t, "compile_s": max(first - t, 0.0),
            "n_steps": int(problem.n_steps), "n_samples": int(problem.n_samples)}


def slope(xs, ys) -> float:
    xs, ys = np.log(np.asarray(xs, float)), np.log(np.asarray(ys, float))
    return float(np.polyfit(xs, ys, 1)[0]) if xs.size >= 2 else float("nan")


def series(records: list[dict]) -> dict:
    """{"sweep/method/engine": sorted records} with the fitted slopes."""
    out = {}
    for r in records:
        if r.get("hung"):
            continue
        out.setdefault(f"{r['sweep']}/{r['method']}/{r.get('engine', 'mjx')}", []).append(r)
    summary = {}
    for k, rs in sorted(out.items()):
        rs = sorted(rs, key=lambda r: r["x"])
        xs, ts = [r["x"] for r in rs], [r["time_s"] for r in rs]
        half = max(2, (len(xs) + 1) // 2)
        summary[k] = {"x": xs, "time_s": ts, "slope": slope(xs, ts), "slope_upper": slope(xs[-half:], ts[-half:]),
                      "slope_rollouts": slope(xs, [r["rollouts"] for r in rs])}
    return summary


XLABEL = {"length": "video length (s)", "chains": "MH chains", "starts": "grad starts"}


def plot(path: Path, summary: dict, doc: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    from galileo_jax.report.results import atomic_path

    sweeps = [s for s in ("length", "chains", "starts") if any(k.startswith(s + "/") for k in summary)]
    if not sweeps:
        return
    fig, axes = plt.subplots(1, len(sweeps), figsize=(4.6 * len(sweeps), 4.0), squeeze=False)
    for ax, sweep in zip(axes[0], sweeps):
        for k, s in summary.items():
            if not k.startswith(sweep + "/"):
                continue
            method, engine = k.split("/")[1:]
            ax.loglog(s["x"], s["time_s"], "o-" if engine == "mujoco" else "s--",
                      label=f"{method}, {engine} (slope {s['slope']:.2f}, upper {s['slope_upper']:.2f})")
            x0, t0 = s["x"][0], s["time_s"][0]
            xs = np.array([s["x"][0], s["x"][-1]], float)
            ax.loglog(xs, t0 * xs / x0, ":", color="grey", lw=1)
        ticks = sorted({x for k, v in summary.items() if k.startswith(sweep + "/") for x in v["x"]})
        ax.set_xticks(ticks)
        ax.xaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.yaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
        ax.yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel(XLABEL[sweep])
        ax.set_ylabel("wall time (s), compilation excluded")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"fit cost scaling ({doc['machine']}); dotted: slope 1", fontsize=9)
    fig.tight_layout()
    with atomic_path(path.with_suffix(".png")) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def write_all(path: Path, doc: dict) -> None:
    from galileo_jax.report.results import atomic_path, write_json

    summary = series(doc["records"])
    doc["summary"] = summary
    write_json(path.with_suffix(".json"), doc)
    plot(path, summary, doc)
    s = doc["settings"]
    lines = ["# Fit cost scaling: video length, MH chains, grad starts", "", f"machine: {doc['machine']}", "",
             "Commands: " + "; ".join(f"{e}: `{c}`" for e, c in doc["commands"].items())
             + " (module docstring of `benchmarks/scaling.py`; engine: where the fits' rollouts ran, mjx = "
             "MuJoCo-MJX, mujoco = C MuJoCo; each engine's records come from its own run). 20 degree two-box scene, "
             f"theta = k1, k2, phi, dt_release; grad: {s['grad_steps']} LM steps per start (tolerances 0, no polish), "
             f"screen max(256, starts); mh: {s['mh_steps']} steps, no warm-up; base video {s['base_length']} s "
             "at 30 fps "
             f"for the chains and starts sweeps. Time: median of {s['repeats']} run(s) after a first (compiling) call; "
             f"JAX's persistent compilation cache {doc.get('compilation_cache', 'on')} (with it on, a first call "
             "that finds its programs in the cache skips most of the compilation). "
             f"Plot: `{path.with_suffix('.png').name}`.", "",
             "| sweep | method | engine | x | time (s) | first call (s) | rollouts | rollouts/s | physics steps "
             "per rollout | physics steps/s (all rollouts) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(doc["records"], key=lambda r: (r["sweep"], r["method"], r["engine"], r["x"])):
        head = f"| {r['sweep']} | {r['method']} | {r['engine']} | {r['x']:g} |"
        if r.get("hung"):
            lines.append(f"{head} hung: no result in {r['timeout_s']:g} s | - | - | - | - | - |")
            continue
        lines.append(f"{head} {r['time_s']:.2f} | {r['first_s']:.1f} | "
                     f"{r['rollouts']} | {r['rollouts_per_s']:.0f} | {r['n_steps']} | "
                     f"{r['rollouts'] * r['n_steps'] / r['time_s']:.0f} |")
    lines += ["", "Fitted log-log slopes of time against the swept size (all points; upper half; rollouts):", "",
              "| sweep / method / engine | slope | slope, upper half | rollouts slope |", "|---|---|---|---|"]
    for k, v in summary.items():
        lines.append(f"| {k} | {v['slope']:.2f} | {v['slope_upper']:.2f} | {v['slope_rollouts']:.2f} |")
    with atomic_path(path.with_suffix(".md")) as tmp:
        tmp.write_text("\n".join(lines) + "\n")




def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lengths", type=float, nargs="+", default=[1.0, 2.0, 4.0, 8.0], help="video lengths (s)")
    ap.add_argument("--chains", type=int, nargs="+", default=[4, 16, 64, 256], help="MH chain counts")
    ap.add_argument("--starts", type=int, nargs="+", default=[1, 4, 16, 32, 64], help="grad start counts")
    ap.add_argument("--engine", choices=("mjx", "mujoco"), default=None,
                    help="simulation engine of the fits (default: what fit --engine auto picks here)")
    ap.add_argument("--base-length", type=float, default=2.0, help="video length (s) of the chains and starts sweeps")
    ap.add_argument("--grad-steps", type=int, default=3, help="LM steps per grad start")
    ap.add_argument("--mh-steps", type=int, default=10, help="MH steps")
    ap.add_argument("--repeats", type=int, default=1, help="timed runs after the compiling one (median)")
    ap.add_argument("--noise", type=float, default=1e-3, help="position noise SD (m)")
    ap.add_argument("--out", default=str(RESULTS / "scaling"), help="results stem (.md, .json, .png)")
    ap.add_argument("--fresh", action="store_true", help="measure this engine's points again (the other engine's records stay)")
    ap.add_argument("--no-cache", action="store_true",
                    help="skip JAX's persistent compilation cache (first-call times then always include compilation)")
    ap.add_argument("--point-timeout", type=float, default=900.0,
                    help="s after which a point counts as hung: recorded as such, measuring goes on in a new process")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if min(args.lengths + [args.base_length]) <= 0 or min(args.chains) < 2 or min(args.starts) < 1 or args.repeats < 1:
        ap.error("lengths must be > 0, chains >= 2, starts >= 1, repeats >= 1")
    argv = list(sys.argv[1:] if argv is None else argv)
    if args.engine is None:
        args.engine = default_engine()
        argv += ["--engine", args.engine]
    if args.worker:
        return worker(args, argv)
    # Supervisor: a worker process measures the points. The watchdog ends a worker whose point
    # takes longer than --point-timeout, leaving the point marked as pending in the JSON; the
    # next worker records it as hung and goes on.
    argv = [a for a in argv if a != "--fresh"]
    first = True
    while True:
        cmd = [sys.executable, str(Path(__file__).resolve()), *argv, "--worker"] + (["--fresh"] if first and args.fresh
                                                                                    else [])
        rc = subprocess.call(cmd)
        first = False
        out = Path(args.out).with_suffix(".json")
        if rc == 0 or not (out.exists() and json.loads(out.read_text()).get("pending")):
            return rc
        print(f"a point did not finish within {args.point_timeout:g} s; it is recorded as hung, continuing in a "
              "new process", flush=True)


def worker(args, argv: list[str]) -> int:
    """Measure every point not yet in the JSON (one process; compiled programs are shared)."""
    import faulthandler

    from galileo_jax.jaxcache import enable_compilation_cache

    if not args.no_cache:
        enable_compilation_cache()
    path = Path(args.out)
    settings = {k: getattr(args, k) for k in ("grad_steps", "mh_steps", "repeats", "noise", "base_length")}
    cache = "off" if args.no_cache else "on"
    shown = [a for a in argv if a not in ("--worker", "--fresh")]
    command = " ".join(["python benchmarks/scaling.py", *shown])
    doc = {"machine": machine_line(), "commands": {args.engine: command},
           "settings": settings, "compilation_cache": cache, "records": []}
    old = path.with_suffix(".json")
    if old.exists():
        prev = json.loads(old.read_text())
        for r in prev.get("records", []) + ([prev["pending"]] if prev.get("pending") else []):
            r.setdefault("engine", "mjx")  # written before --engine existed: MJX runs
        if args.fresh:  # measure this engine again, keep the other's records
            prev["records"] = [r for r in prev.get("records", []) if r["engine"] != args.engine]
            prev.pop("pending", None)
        if prev.get("settings") == settings:
            commands = prev.get("commands", {"mjx": prev["command"]} if "command" in prev else {})
            doc["commands"] = {**commands, args.engine: command}
            doc["records"] = prev.get("records", [])
            was = prev.get("compilation_cache", cache)
            doc["compilation_cache"] = was if was == cache else f"{was}, then {cache} (resumed)"
            if prev.get("pending"):  # the previous worker's watchdog stopped it on this point
                doc["records"].append({**prev["pending"], "hung": True, "timeout_s": args.point_timeout})
                write_all(path, doc)
    done = {(r["sweep"], key_of(r)) for r in doc["records"]}
    problems: dict = {}
    # Base-length points first, grouped by video length so that each Problem is built once; the
    # largest grad batches last (they are the ones that can hang).
    todo = sorted(points(args), key=lambda p: (p["length"] != args.base_length, p["length"], p.get("starts", 0)))
    for p in todo:
        if (p["sweep"], key_of(p)) in done:
            continue
        same = [r for r in doc["records"] if key_of(r) == key_of(p)]  # e.g. 16 chains at the base length
        if same:
            rec = {**same[0], "sweep": p["sweep"], "x": p["x"]}
        else:
            doc["pending"] = p
            write_all(path, doc)
            # The watchdog is a C thread: it ends the process even while XLA holds it in a wait.
            faulthandler.dump_traceback_later(args.point_timeout, exit=True)
            try:
                rec = measure(p, problems, args)
            except BaseException:
                doc.pop("pending", None)  # an error is not a hang: say so in the JSON, then stop
                write_all(path, doc)
                raise
            finally:
                faulthandler.cancel_dump_traceback_later()
            doc.pop("pending", None)
        doc["records"].append(rec)
        write_all(path, doc)
        if rec.get("hung"):
            print(f"{p['sweep']:7s} {p['method']:4s} x={p['x']:<6g} hung", flush=True)
        else:
            print(f"{p['sweep']:7s} {p['method']:4s} x={p['x']:<6g} time {rec['time_s']:.2f} s "
                  f"(first {rec['first_s']:.1f} s), {rec['rollouts']} rollouts", flush=True)
    write_all(path, doc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
