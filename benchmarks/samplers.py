"""Samplers on rendered videos with ground truth: mh, the seed's coin toss, grad, cnn, a random guess.

Issue 5, benchmark 1. Renders ``--videos`` videos per ramp angle (``scenes/ramp_10.yaml`` and
``scenes/ramp_20.yaml``; C MuJoCo renderer, 480x270, 2.5 s at 30 fps, pixel noise; random
informative parameters as ``synth --random`` draws them), tracks them, and on each runs:

* ``random guess``: ``--guesses`` draws from the prior (k1, k2, phi; the release at the tracker's
  estimate, as the seed's guesser had no release correction); errors averaged over the draws;
* ``seed coin-toss MH``: the seed's sampler (:func:`~galileo_jax.inference.seed_mh.run_seed_mh`,
  16 chains x 75 steps, its SD 0.05 m/s similarity, coin-toss acceptance); the answer is the best
  proposal, simulated with the release at the tracker's estimate (the seed fitted no release);
* ``mh``: random-walk Metropolis-Hastings with ``fit``'s defaults (``FitConfig().mh``: 16 chains,
  300 annealed warm-up + 400 kept steps); the answer is the posterior median (what ``fit`` reports),
  and ``mh (best draw)`` is the same run's highest-likelihood draw (what ``fit``'s profile shows);
* ``grad``: Levenberg-Marquardt as ``fit`` runs it (4 starts, the best of a 256-point screen);
* ``cnn``: the shipped network (one forward pass; its median and 90% interval). Only the
  20 degree scene has one: on ramp_10 the row says "no model";
* ``grad --init cnn``: grad started from the CNN's estimate (``fit --init cnn``); its time
  includes the forward pass.

Columns (per method, averaged over the videos, for all videos and per angle): mean |error| of
k1, k2, phi against the renderer's truth; the seed's profile errors L1 and L2 of the answer's
simulated profile against the tracked one, and their ratio to the random guess's on the same
videos; the share of (video, parameter) pairs whose truth lies in the 90% interval (mh, grad's
Gauss-Newton interval, cnn); the median over videos of mh's max R-hat (and the worst) and of its
ESS per second (smallest bulk ESS over the sampled identifiable parameters, ArviZ via
:func:`~galileo_jax.inference.summarize_mh`, divided by the sampler's wall time); rollouts
(counted for the samplers, estimated for grad from its settings and LM steps, see
:func:`galileo_jax.inference.grad.count_rollouts`); mean wall time of the method (compilation
excluded: every method first runs on one warm-up video per angle, with mh and the seed's sampler shortened to a chunk or
two, which compiles the same programs).

Profile errors (dissertation 4.3, "Comparison with a naive guesser"; NOTES.md): the seed's
velocity profile is the displacement per frame in metres (dissertation 4.2.3-4.2.4: "t' can be
ignored"), four traces (object 1 x, y, object 2 x, y) over the whole video, joined into one
sequence of 4T values; L1 = sum |sim - obs| and L2 = sqrt(sum (sim - obs)^2) over it (so
L2 < L1, as in the dissertation's 0.43 / 0.07). Here: ``(simulated - observed) / fps`` of the
m/s profiles over all video samples (not only the fit window). The absolute values depend on
the video's length and noise (the seed's were real Physics 101 clips), so the ratio to the
random guess on the same videos is the comparable number: the seed's was 0.43 / 0.78 = 0.55
(L1) and 0.07 / 0.11 = 0.64 (L2).

Rollouts run on the simulation engine ``fit`` would use (``--engine`` to choose; recorded per
video and in the tables' settings line).

Resumable: per-video records ``<out>/<scene>/video_<i>.json`` (skipped when present; the
settings are kept in ``<out>/settings.json`` and a run with other settings is refused). The
tables go beside the folder: ``<out>.md`` and ``<out>.json`` (default
``benchmarks/results/samplers.{md,json}``), written atomically after every video.

    python benchmarks/samplers.py --videos 5                  # full run, fit's default settings
    python benchmarks/samplers.py --videos 1 --quick --out /tmp/samplers_smoke   # smoke test
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import cnn_videos  # noqa: E402  (sets MUJOCO_GL=egl unless set; ROOT, RESULTS, NAMES)
import numpy as np  # noqa: E402
from _common import machine_line, rendered  # noqa: E402

ROOT, RESULTS, NAMES = cnn_videos.ROOT, cnn_videos.RESULTS, cnn_videos.NAMES
SCENES = ("ramp_10", "ramp_20")
#: Rendered videos: as benchmarks/cnn_videos.py renders them.
VIDEO = cnn_videos.VIDEO
#: Index of the warm-up (compilation) video of each scene.
WARMUP_INDEX = 10_000
#: The dissertation's profile errors (NOTES.md; dissertation 4.3, averaged over 30 runs).
DISSERTATION = (("seed MCMC (dissertation, Physics 101)", 0.43, 0.07),
                ("random guess (dissertation)", 0.78, 0.11),
                ("coin toss, no likelihood (dissertation)", 0.81, 0.11))
METHODS = ("random guess", "seed coin-toss MH", "mh", "mh (best draw)", "grad", "cnn", "grad --init cnn")
NO_MODEL = "no model"


# --------------------------------------------------------------------------- settings
def settings_from_args(args) -> dict:
    """The run's settings: ``fit``'s defaults (``FitConfig``), the flags, ``--quick``'s shrink."""
    from galileo_jax.config import FitConfig

    cfg = FitConfig()
    s = {"mh_chains": cfg.mh.chains, "mh_warmup": cfg.mh.warmup, "mh_samples": cfg.mh.samples,
         "seed_chains": cfg.seed_mh.chains, "seed_steps": cfg.seed_mh.steps,
         "grad_starts": cfg.grad.starts, "grad_screen": cfg.grad.screen, "grad_max_steps": cfg.grad.max_steps,
         "guesses": 32}
    if args.quick:
        s.update(mh_chains=4, mh_warmup=20, mh_samples=20, seed_chains=4, seed_steps=15,
                 grad_starts=1, grad_screen=16, grad_max_steps=5, guesses=8)
    for k in s:
        if getattr(args, k) is not None:
            s[k] = int(getattr(args, k))
    s.update(seed=args.seed, video=VIDEO)
    if args.engine is not None:
        s["engine"] = args.engine
    return s


def fit_config(s: dict):
    """A ``FitConfig`` with the run's settings (what the library functions read)."""
    from galileo_jax.config import FitConfig

    cfg = FitConfig()
    cfg.mh.chains, cfg.mh.warmup, cfg.mh.samples = s["mh_chains"], s["mh_warmup"], s["mh_samples"]
    cfg.seed_mh.chains, cfg.seed_mh.steps = s["seed_chains"], s["seed_steps"]
    cfg.grad.starts, cfg.grad.screen, cfg.grad.max_steps = s["grad_starts"], s["grad_screen"], s["grad_max_steps"]
    if "engine" in s:
        cfg.engine = s["engine"]
    return cfg


def problem_for(scene, obs, cfg, method: str = "grad"):
    """The :class:`Problem` of a fit by ``method`` as ``fit`` builds it (its simulation engine
    and its rollout ensemble, :func:`~galileo_jax.config.ensemble_for`, too)."""
    from galileo_jax.inference import Problem
    from galileo_jax.pipeline import problem_options

    return Problem(scene, obs, **problem_options(scene, cfg, method))


# --------------------------------------------------------------------------- videos
def scene_video(scene_name: str, i: int, work: Path, seed: int) -> Path:
    """Render (once) video ``i`` of ``scenes/<scene_name>.yaml`` into ``work/<scene_name>/``."""
    from galileo_jax.scene import load_scene

    path = work / scene_name / f"video_{i}.mp4"
    if rendered(path):
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    stream = np.random.SeedSequence([seed, SCENES.index(scene_name), i])
    cnn_videos.render_informative(load_scene(ROOT / "scenes" / f"{scene_name}.yaml"), path,
                                  np.random.default_rng(stream), int(stream.generate_state(1)[0] % 2**31))
    return path


# --------------------------------------------------------------------------- measures
def profile_errors(observed: np.ndarray, simulated: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """The seed's L1, L2 (module docstring) of simulated (B, 2n, T) vs observed (2n, T) m/s profiles:
    displacement per frame in m, summed over every trace and sample (non-finite samples skipped)."""
    diff = (np.asarray(simulated, np.float64) - np.asarray(observed, np.float64)[None]) / fps
    diff = np.where(np.isfinite(diff), diff, 0.0).reshape(diff.shape[0], -1)
    return np.abs(diff).sum(axis=1), np.sqrt((diff ** 2).sum(axis=1))


def mh_rollouts(n_chains: int, n_warmup: int, n_samples: int, chunk: int = 20) -> int:
    """Rollouts of one ``run_mh``: one per chain and step, steps rounded up to whole chunks."""
    return n_chains * chunk * (math.ceil(n_warmup / chunk) + math.ceil(n_samples / chunk))


# --------------------------------------------------------------------------- one video
class Evaluator:
    """Errors of answers theta (B, d) against the truth and the tracked profile."""

    def __init__(self, problem, truth: dict):
        self.problem, self.truth = problem, truth
        self.names = problem.space.names

    def __call__(self, thetas) -> dict:
        thetas = np.atleast_2d(np.asarray(thetas, np.float64))
        obs = self.problem.observation
        l1, l2 = profile_errors(obs.profile, np.asarray(self.problem.simulate(thetas)), float(obs.fps))
        err = {n: float(np.mean(np.abs(thetas[:, self.names.index(n)] - float(self.truth[n])))) for n in NAMES}
        out = {"error": err, "l1": float(np.mean(l1)), "l2": float(np.mean(l2))}
        if len(thetas) == 1:
            out["theta"] = dict(zip(self.names, map(float, thetas[0])))
        return out

    def inside(self, intervals: dict) -> dict:
        """{name: truth inside [lo, hi]} for the k1, k2, phi intervals given by name."""
        return {n: bool(intervals[n][0] <= float(self.truth[n]) <= intervals[n][1]) for n in NAMES}


def seed_theta(res, space) -> np.ndarray:
    """The seed sampler's answer in the problem's coordinates; the release at the tracker's
    estimate (dt_release 0: the seed fitted no release time)."""
    theta = np.array([float(res.best[n]) if n in res.best else 0.0 for n in space.names])
    return np.clip(theta, space.lower, space.upper)


def video_key(seed: int, scene_name: str, i: int) -> int:
    """The PRNG seed of video ``i`` of ``scene_name`` (the same on a rerun of chosen methods)."""
    return seed * 10_000 + SCENES.index(scene_name) * 1000 + i


def run_video(video: Path, s: dict, key_seed: int, models: dict, warm: bool = False, say=print,
              only: set | None = None) -> dict:
    """Every method on one rendered video (module docstring), or those in ``only``. ``warm``:
    the compilation run (mh and the seed's sampler shortened; same compiled programs)."""
    import jax

    from galileo_jax.config import ensemble_for
    from galileo_jax.inference import fit_grad, run_mh, run_seed_mh, summarize_mh
    from galileo_jax.errors import GalileoError
    from galileo_jax.inference import cnn_files
    from galileo_jax.inference.grad import count_rollouts
    from galileo_jax.observe import observe
    from galileo_jax.pipeline import cnn_estimate, grad_start_from_cnn
    from galileo_jax.scene import load_scene

    cfg = fit_config(s)
    scene = load_scene(video.with_suffix(".yaml"))
    truth = json.loads(video.with_suffix(".truth.json").read_text())
    t = time.perf_counter()
    obs = observe(video, scene, progress=False)
    observe_s = time.perf_counter() - t
    problem = problem_for(scene, obs, cfg)
    space = problem.space
    evaluate = Evaluator(problem, truth)
    key = jax.random.PRNGKey(key_seed)
    keys = dict(zip(METHODS, jax.random.split(key, len(METHODS))))
    runs: dict[str, dict] = {}

    def done(name: str, run: dict) -> None:
        runs[name] = run
        if not warm:
            e = run.get("error")
            say(f"    {name}: " + (run.get("status", "") if e is None else
                                   f"|err| k1 {e['k1']:.4f} k2 {e['k2']:.3f} phi {e['phi']:.3f}, "
                                   f"L1 {run['l1']:.3f} L2 {run['l2']:.4f}, {run['time_s']:.1f} s"), flush=True)

    def want(*names: str) -> bool:
        return only is None or any(n in only for n in names)

    if want("random guess"):  # draws from the prior, release at the tracker's estimate
        guesses = np.array(space.sample_prior(keys["random guess"], s["guesses"]), np.float64)
        if "dt_release" in space.names:
            guesses[:, space.names.index("dt_release")] = 0.0
        done("random guess", {**evaluate(guesses), "draws": len(guesses), "time_s": 0.0, "simulations": 0})

    if want("seed coin-toss MH"):
        steps = 15 if warm else s["seed_steps"]  # run_seed_mh's chunk: one compiled scan
        t = time.perf_counter()
        res = run_seed_mh(problem, keys["seed coin-toss MH"], n_chains=s["seed_chains"], n_steps=steps,
                          progress=False)
        elapsed = time.perf_counter() - t
        done("seed coin-toss MH", {**evaluate(seed_theta(res, space)), "time_s": elapsed,
                                   "simulations": s["seed_chains"] * (steps + 1),
                                   "best_similarity": float(res.best_similarity),
                                   "acceptance": float(np.mean(res.accepted))})

    if want("mh", "mh (best draw)"):
        n_warmup, n_samples = (40, 20) if warm else (s["mh_warmup"], s["mh_samples"])  # 2 chunks: annealing compiles
        t = time.perf_counter()
        res = run_mh(problem_for(scene, obs, cfg, "mh"), keys["mh"], n_chains=s["mh_chains"], n_warmup=n_warmup,
                     n_samples=n_samples, progress=False)
        elapsed = time.perf_counter() - t
        summ = summarize_mh(res, space)
        par, diag = summ["parameters"], summ["diagnostics"]
        common = {"time_s": elapsed, "simulations": ensemble_for(cfg, "mh") * mh_rollouts(s["mh_chains"], n_warmup,
                                                                                       n_samples),
                  "max_rhat": diag["max_rhat"], "min_ess_bulk": diag["min_ess_bulk"],
                  "ess_per_s": diag["min_ess_bulk"] / elapsed, "acceptance": diag["acceptance"]}
        done("mh", {**evaluate([par[n]["median"] for n in space.names]), **common,
                    "inside90": evaluate.inside({n: par[n]["interval90"] for n in NAMES})})
        done("mh (best draw)", {**evaluate(res.best_theta), **common, "best_loglik": diag["best_loglik"]})

    def grad_run(t0: float, **kw) -> dict:
        res = fit_grad(problem, keys["grad"], jacobian=cfg.grad.jacobian, max_steps=cfg.grad.max_steps,
                       search_generations=cfg.grad.search_generations, **kw)
        elapsed = time.perf_counter() - t0
        polish = {k: kw[k] for k in ("polish_rounds", "polish_points") if k in kw}
        return {**evaluate(res.theta), "time_s": elapsed,
                "simulations": count_rollouts(res, n_screen=kw["n_screen"], **polish),
                "lm_steps": int(np.sum(res.starts_iterations)), "loglik": float(res.loglik),
                "inside90": evaluate.inside({n: res.interval90[space.names.index(n)] for n in NAMES})}

    if want("grad"):
        done("grad", grad_run(time.perf_counter(), n_starts=cfg.grad.starts,
                              n_screen=max(cfg.grad.screen, cfg.grad.starts)))
    if want("cnn", "grad --init cnn"):
        if scene.name not in models:
            try:
                models[scene.name] = cnn_files.find_model(scene, obs.fps, cfg.cnn.model)
            except GalileoError as err:  # CNNError, OutOfFamily
                models[scene.name] = err
        model = models[scene.name]
        if isinstance(model, Exception):
            for name in ("cnn", "grad --init cnn"):
                done(name, {"status": NO_MODEL, "message": str(model)})
        else:
            t = time.perf_counter()
            est = cnn_estimate(problem, cfg, keys["cnn"], model)  # a scene-conditioned network reads the scene too
            elapsed = time.perf_counter() - t
            done("cnn", {**evaluate(est.theta), "time_s": elapsed, "simulations": 0,
                         "inside90": evaluate.inside({n: est.interval90[space.names.index(n)] for n in NAMES})})
            done("grad --init cnn", grad_run(t, **grad_start_from_cnn(est, space, cfg)))
    return {"video": video.name, "scene": scene.name, "engine": getattr(problem, "simulator_engine", "mjx"),
            "truth": {n: float(truth[n]) for n in NAMES},
            "samples": int(problem.n_samples), "observe_s": observe_s, "runs": runs}


# --------------------------------------------------------------------------- tables
def _median(xs):
    xs = [x for x in xs if x is not None]  # (R-hat is None for runs too short to split)
    return float(np.median(xs)) if len(xs) else None


def aggregate(records: list[dict]) -> dict:
    """Per method: the columns of the module docstring over ``records``."""
    rows = {}
    random_l = {r["video"] + r["scene"]: (r["runs"]["random guess"]["l1"], r["runs"]["random guess"]["l2"])
                for r in records if "random guess" in r["runs"]}
    for m in METHODS:
        got = [r for r in records if m in r["runs"]]
        ok = [r for r in got if "status" not in r["runs"][m]]
        if not got:
            continue
        if not ok:
            rows[m] = {"videos": 0, "status": got[0]["runs"][m]["status"]}
            continue
        rs = [r["runs"][m] for r in ok]
        row = {"videos": len(rs), **{f"mae_{n}": float(np.mean([x["error"][n] for x in rs])) for n in NAMES},
               "l1": float(np.mean([x["l1"] for x in rs])), "l2": float(np.mean([x["l2"] for x in rs])),
               "simulations": float(np.mean([x["simulations"] for x in rs])),
               "time_s": float(np.mean([x["time_s"] for x in rs]))}
        base = [random_l[r["video"] + r["scene"]] for r in ok if r["video"] + r["scene"] in random_l]
        if len(base) == len(rs):
            row["l1_vs_random"] = row["l1"] / float(np.mean([b[0] for b in base]))
            row["l2_vs_random"] = row["l2"] / float(np.mean([b[1] for b in base]))
        if all("inside90" in x for x in rs):
            row["cover90"] = float(np.mean([[x["inside90"][n] for n in NAMES] for x in rs]))
        if all("max_rhat" in x for x in rs):
            row["max_rhat_median"] = _median([x["max_rhat"] for x in rs])
            row["max_rhat_worst"] = max((x["max_rhat"] for x in rs if x["max_rhat"] is not None), default=None)
            row["ess_per_s_median"] = _median([x["ess_per_s"] for x in rs])
        if len(ok) < len(got):
            row["note"] = f"{len(got) - len(ok)} video(s): {got[0]['runs'][m].get('status', NO_MODEL)}"
        rows[m] = row
    return rows


def _cell(row: dict, key: str, fmt: str) -> str:
    v = row.get(key)
    return "-" if v is None else format(v, fmt)


def table_lines(rows: dict) -> list[str]:
    lines = ["| method | videos | k1 | k2 | phi | L1 | L2 | L1 / L2 vs random | cover90 | max R-hat (median, worst) "
             "| ESS/s | rollouts | time (s) |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for m, row in rows.items():
        if row["videos"] == 0:
            lines.append(f"| {m} | 0 | {row['status']} |" + " |" * 10)
            continue
        ratio = (f"{row['l1_vs_random']:.2f} / {row['l2_vs_random']:.2f}" if "l1_vs_random" in row else "-")
        rhat = (f"{row['max_rhat_median']:.3f}, {row['max_rhat_worst']:.3f}"
                if row.get("max_rhat_median") is not None else "-")
        note = f" ({row['note']})" if "note" in row else ""
        lines.append(f"| {m}{note} | {row['videos']} | {row['mae_k1']:.4f} | {row['mae_k2']:.4f} "
                     f"| {row['mae_phi']:.4f} | {row['l1']:.3f} | {row['l2']:.4f} | {ratio} "
                     f"| {_cell(row, 'cover90', '.2f')} | {rhat} "
                     f"| {_cell(row, 'ess_per_s_median', '.2f')} | {row['simulations']:.0f} | {row['time_s']:.2f} |")
    _, r1, r2 = DISSERTATION[1]
    for name, l1, l2 in DISSERTATION:
        lines.append(f"| {name} | - | - | - | - | {l1:.2f} | {l2:.2f} | {l1 / r1:.2f} / {l2 / r2:.2f} "
                     "| - | - | - | - | - |")
    return lines


def write_tables(work: Path, s: dict) -> None:
    from galileo_jax.report.results import atomic_path, write_json

    records = [json.loads(p.read_text()) for sc in SCENES for p in sorted((work / sc).glob("video_*.json"))
               if not p.name.endswith(".truth.json")]
    records = [r for r in records if "runs" in r]
    groups = {"all": records, **{sc: [r for r in records if r["scene"] == sc] for sc in SCENES}}
    summary = {g: aggregate(rs) for g, rs in groups.items() if rs}
    mach = machine_line()
    write_json(work.parent / f"{work.name}.json", {"machine": mach, "settings": s, "summary": summary,
                                                    "dissertation": [dict(zip(("method", "l1", "l2"), d))
                                                                     for d in DISSERTATION],
                                                    "records": records})
    cmd = "python benchmarks/samplers.py " + shlex.join(sys.argv[1:])
    lines = [f"# Samplers on rendered videos ({len(records)} videos: "
             + ", ".join(f"{len(groups[sc])} {sc}" for sc in SCENES) + ")", "",
             f"machine: {mach}", "", f"Command: `{cmd.strip()}` (module docstring of `benchmarks/samplers.py`).",
             "", "Settings: " + ", ".join(f"{k} {v}" for k, v in s.items() if k != "video")
             + f"; videos {s['video']['duration']} s at {s['video']['fps']:g} fps, {s['video']['width']}x"
               f"{s['video']['height']}, pixel noise {s['video']['noise_sd']}; simulation engine "
             + ", ".join(sorted({r.get("engine", "mjx") for r in records})) + ".", "",
             "k1, k2, phi: mean |error| against the renderer's truth. L1, L2: the seed's profile errors of the "
             "answer's simulated profile against the tracked one (displacement per frame in m, all four traces, "
             "whole video; sum |d| and sqrt(sum d^2)), mean over videos; 'vs random': their ratio to the random "
             "guess's on the same videos (the seed's: 0.55 / 0.64). cover90: share of (video, parameter) pairs "
             "whose truth is in the 90% interval. max R-hat: over the sampled identifiable parameters, median and "
             "worst over videos; ESS/s: smallest bulk ESS / sampler wall time, median over videos. rollouts: "
             "simulations the method ran (grad: estimated from its LM steps). time: mean wall time of the method, "
             "compilation excluded. The dissertation rows are the seed's real-video numbers (NOTES.md): only "
             "their ratios compare."]
    for g, rows in summary.items():
        lines += ["", f"## {g} ({len(groups[g])} videos)", ""] + table_lines(rows)
    lines += ["", "## Per video", "", "Absolute errors of k1 / k2 / phi, then L1, of each method's answer.", "",
              "| scene | video | truth k1, k2, phi | " + " | ".join(METHODS) + " |",
              "|---|---|---|" + "---|" * len(METHODS)]
    for r in records:
        t = r["truth"]

        def cell(m):
            run = r["runs"].get(m)
            if run is None or "status" in run:
                return "-" if run is None else run["status"]
            return " / ".join(f"{run['error'][n]:.3f}" for n in NAMES) + f", {run['l1']:.3f}"
        lines.append(f"| {r['scene']} | {r['video']} | {t['k1']:.3f}, {t['k2']:.3f}, {t['phi']:.3f} | "
                     + " | ".join(cell(m) for m in METHODS) + " |")
    with atomic_path(work.parent / f"{work.name}.md") as tmp:
        tmp.write_text("\n".join(lines) + "\n")


# --------------------------------------------------------------------------- main
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--videos", type=int, default=5, help="videos per ramp angle (default 5)")
    ap.add_argument("--scenes", default=",".join(SCENES), help="comma-separated, from " + ", ".join(SCENES))
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--out", default=str(RESULTS / "samplers"),
                    help="records folder; the tables go beside it as <out>.md, <out>.json")
    ap.add_argument("--quick", action="store_true",
                    help="smoke test: mh 4 chains x (20 + 20) steps, seed 4 x 15, grad 1 start of a 16-point screen, "
                         "5 LM steps, 8 guesses (use with a temporary --out)")
    for k, what in (("mh_chains", "mh chains"), ("mh_warmup", "mh warm-up steps"), ("mh_samples", "mh kept steps"),
                    ("seed_chains", "seed sampler chains"), ("seed_steps", "seed sampler steps"),
                    ("grad_starts", "grad starts"), ("grad_screen", "grad screen points"),
                    ("grad_max_steps", "LM steps per start"), ("guesses", "random-guess draws (default 32)")):
        ap.add_argument("--" + k.replace("_", "-"), dest=k, type=int, help=f"{what} (default: fit's)")
    ap.add_argument("--engine", help="simulation engine where galileo_jax has several (mjx, mujoco, auto); "
                                     "default: fit's")
    ap.add_argument("--rerun", default="",
                    help="comma-separated methods to run again on the videos already recorded (e.g. after "
                         "retraining the CNN: 'cnn,grad --init cnn'); their runs replace the recorded ones")
    ap.add_argument("--no-warmup", action="store_true",
                    help="skip the compilation warm-up videos (the first video's times then include compilation)")
    args = ap.parse_args(argv)
    scenes = [x.strip() for x in args.scenes.split(",") if x.strip()]
    if not scenes or any(x not in SCENES for x in scenes):
        ap.error(f"--scenes: choose from {', '.join(SCENES)}")
    from galileo_jax.jaxcache import enable_compilation_cache
    from galileo_jax.report.results import write_json

    s = settings_from_args(args)
    work = Path(args.out)
    work.mkdir(parents=True, exist_ok=True)
    kept = work / "settings.json"
    if kept.exists() and json.loads(kept.read_text()) != json.loads(json.dumps(s)):
        print(f"{work} holds records made with other settings ({kept}); use another --out or the same flags",
              file=sys.stderr)
        return 2
    write_json(kept, s)
    enable_compilation_cache()
    models: dict = {}
    rerun = {m.strip() for m in args.rerun.split(",") if m.strip()}
    if rerun - set(METHODS):
        ap.error(f"--rerun: choose from {', '.join(METHODS)}")
    for sc in scenes if rerun else ():
        done = [i for i in range(args.videos) if (work / sc / f"video_{i}.json").exists()]
        if done and not args.no_warmup:
            run_video(scene_video(sc, WARMUP_INDEX, work, args.seed), s, 0, models, warm=True, only=rerun)
        for i in done:
            path = work / sc / f"video_{i}.json"
            rec = json.loads(path.read_text())
            new = run_video(scene_video(sc, i, work, args.seed), s, video_key(args.seed, sc, i),
                            models, only=rerun)
            rec["runs"].update(new["runs"])
            write_json(path, rec)
            print(f"{sc} video {i + 1}: reran {', '.join(sorted(rerun))}", flush=True)
    for sc in scenes:
        todo = [i for i in range(args.videos) if not (work / sc / f"video_{i}.json").exists()]
        if not todo:
            continue
        if not args.no_warmup:
            t = time.perf_counter()
            run_video(scene_video(sc, WARMUP_INDEX, work, args.seed), s, 0, models, warm=True)
            print(f"{sc}: warm-up (compilation) {time.perf_counter() - t:.0f} s", flush=True)
        for i in todo:
            t = time.perf_counter()
            video = scene_video(sc, i, work, args.seed)
            render_s = time.perf_counter() - t
            truth = json.loads(video.with_suffix(".truth.json").read_text())
            print(f"{sc} video {i + 1}/{args.videos}: truth k1 {truth['k1']:.3f} k2 {truth['k2']:.3f} "
                  f"phi {truth['phi']:.3f} (rendered in {render_s:.0f} s)", flush=True)
            rec = run_video(video, s, video_key(args.seed, sc, i), models)
            rec.update(render_s=render_s, total_s=time.perf_counter() - t)
            write_json(work / sc / f"video_{i}.json", rec)
            print(f"{sc} video {i + 1}/{args.videos} done in {rec['total_s']:.0f} s", flush=True)
            write_tables(work, s)
    write_tables(work, s)
    print(f"tables: {work.parent / (work.name + '.md')}, {work.parent / (work.name + '.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
