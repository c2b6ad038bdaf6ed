"""The CNN on rendered (tracked) videos, next to grad and mh, and as their starting point.

Issue 4, "What it must show" 3 and 4. Renders ``--videos`` videos of the 20 degree scene
(C MuJoCo renderer, 480x270, image noise, random informative parameters as ``synth --random``
draws them), tracks them, and on each runs:

* ``cnn``: the shipped model's estimate (one forward pass);
* ``grad``: Levenberg-Marquardt as ``fit`` runs it (4 starts, the best of a 256-point screen);
* ``grad --init cnn``: one start at the CNN's estimate, plus the best of a screen around it
  as wide as the CNN's 90% interval, at least +-5% of each range (``fit --init cnn``);
* with ``--mh``: ``mh`` from the prior with the default 300 warm-up steps and with 100, and
  chains started at the CNN's posterior draws with 100 warm-up steps, with and without the
  annealing (``fit --init cnn`` keeps it).

Per run: |error| of k1, k2, phi against the renderer's truth, Levenberg-Marquardt steps (all
starts together) or max R-hat, simulations run, and wall time (compilation excluded: every
method runs once on a warm-up video first). Writes ``benchmarks/results/cnn_videos.{md,json}``
(resumable: per-video records under ``--out``, default ``benchmarks/results/cnn_videos/``; the
tables are named after that folder).

    python benchmarks/cnn_videos.py --videos 8 [--mh]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402
from _common import machine_line, rendered  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
NAMES = ("k1", "k2", "phi")
#: The benchmarks' rendered videos (cnn_videos, samplers, sweep_rendered): 2.5 s at 30 fps,
#: 480x270, pixel noise SD 2, released after 9 frames.
VIDEO = dict(fps=30.0, duration=2.5, width=480, height=270, noise_sd=2.0, rest_frames=9)


def render_informative(scene, path: Path, rng: np.random.Generator, noise_seed: int) -> None:
    """Render ``path`` (with its scene and truth) of ``scene`` at parameters drawn from ``rng``
    as ``synth --random`` draws them (object 1 slides and reaches object 2), :data:`VIDEO` settings."""
    from galileo_jax.synth import draw_informative_params, render_video

    v = VIDEO
    params = draw_informative_params(scene, rng, (), fps=v["fps"], rest_frames=v["rest_frames"],
                                     n_frames=int(round(v["fps"] * v["duration"])))
    render_video(scene, params, path, progress=False, seed=noise_seed, **v)


def render(i: int, work: Path, seed: int) -> Path:
    from galileo_jax.scene import load_scene

    video = work / f"video_{i}.mp4"
    if rendered(video):
        return video
    render_informative(load_scene(ROOT / "scenes" / "ramp_20.yaml"), video, np.random.default_rng(seed * 1000 + i),
                       seed + i)
    return video


def run_methods(video: Path, with_mh: bool) -> dict:
    import jax

    from galileo_jax.config import FitConfig, resolve_engine
    from galileo_jax.inference import Problem, fit_grad, run_mh, summarize_mh
    from galileo_jax.inference import cnn
    from galileo_jax.inference import cnn_files
    from galileo_jax.observe import observe
    from galileo_jax.pipeline import grad_start_from_cnn, mh_start_from_cnn
    from galileo_jax.scene import load_scene

    cfg = FitConfig()
    scene = load_scene(video.with_suffix(".yaml"))
    truth = json.loads(video.with_suffix(".truth.json").read_text())
    obs = observe(video, scene, progress=False)
    engine = resolve_engine(cfg)  # what fit runs on: C MuJoCo on a CPU
    problem = Problem(scene, obs, likelihood=cfg.likelihood.kind, sd_model=cfg.likelihood.sd_model, engine=engine)
    model = cnn_files.find_model(scene, obs.fps)
    out = {"video": video.name, "truth": {n: truth[n] for n in NAMES}, "engine": engine, "runs": {}}

    def errors(theta):
        d = dict(zip(problem.space.names, np.asarray(theta, float)))
        return {n: abs(float(d[n]) - float(truth[n])) for n in NAMES}

    t = time.perf_counter()
    est = cnn.estimate(model, obs, problem.space, jax.random.PRNGKey(0))
    out["runs"]["cnn"] = {"error": errors(est.theta), "time_s": time.perf_counter() - t, "simulations": 0,
                          "inside90": {n: bool(est.interval90[j, 0] <= truth[n] <= est.interval90[j, 1])
                                       for j, n in enumerate(est.names) if n in NAMES}}
    for name, kw in (("grad", dict(n_starts=cfg.grad.starts, n_screen=cfg.grad.screen)),
                     ("grad --init cnn", grad_start_from_cnn(est, problem.space, cfg))):
        t = time.perf_counter()
        res = fit_grad(problem, jax.random.PRNGKey(1), max_steps=cfg.grad.max_steps, **kw)
        out["runs"][name] = {"error": errors(res.theta), "time_s": time.perf_counter() - t,
                             "lm_steps": int(np.sum(res.starts_iterations)), "lm_steps_best": int(res.iterations),
                             "loglik": float(res.loglik)}
    if with_mh:
        start = mh_start_from_cnn(est, cfg.mh.chains)
        for name, kw in (("mh (warm-up 300)", dict(n_warmup=300)), ("mh (warm-up 100)", dict(n_warmup=100)),
                         ("mh --init cnn (warm-up 100)", dict(n_warmup=100, **start)),
                         ("mh --init cnn, no annealing (warm-up 100)", dict(n_warmup=100, anneal=0.0, **start))):
            t = time.perf_counter()
            res = run_mh(problem, jax.random.PRNGKey(2), n_chains=cfg.mh.chains, n_samples=200, progress=False, **kw)
            summ = summarize_mh(res, problem.space)["parameters"]
            med = [summ[n]["median"] for n in problem.space.names]
            out["runs"][name] = {"error": errors(med), "time_s": time.perf_counter() - t,
                                 "max_rhat": float(max(summ[n]["rhat"] for n in NAMES)),
                                 "inside90": {n: bool(summ[n]["interval90"][0] <= truth[n] <= summ[n]["interval90"][1])
                                              for n in NAMES},
                                 "best_loglik": float(np.max(res.loglik))}
    return out


def write_tables(work: Path) -> None:
    from galileo_jax.report.results import atomic_path, write_json

    name = work.name
    records = [json.loads(p.read_text()) for p in sorted(work.glob("video_*.json")) if not p.name.endswith("truth.json")]
    records = [r for r in records if "runs" in r]
    machine = machine_line()
    methods = list(dict.fromkeys(m for r in records for m in r["runs"]))
    summary = {}
    for m in methods:
        rs = [r["runs"][m] for r in records if m in r["runs"]]
        row = {"videos": len(rs), "time_s": float(np.median([r["time_s"] for r in rs]))}
        for n in NAMES:
            row[f"mae_{n}"] = float(np.mean([r["error"][n] for r in rs]))
        if "lm_steps" in rs[0]:
            row["lm_steps"] = float(np.median([r["lm_steps"] for r in rs]))
        if "max_rhat" in rs[0]:
            row["max_rhat"] = float(np.max([r["max_rhat"] for r in rs]))
        if "inside90" in rs[0]:
            row["cover90"] = float(np.mean([[r["inside90"][n] for n in NAMES] for r in rs]))
        summary[m] = row
    write_json(RESULTS / f"{name}.json", {"machine": machine, "summary": summary, "records": records})
    engines = sorted({r.get("engine", "mjx") for r in records})
    lines = [f"# CNN on rendered videos, next to grad and mh ({len(records)} videos, 20 degree scene)", "",
             f"machine: {machine}; simulation engine of grad and mh: {', '.join(engines)}", "",
             "Command: `python benchmarks/cnn_videos.py` (module docstring). Mean |error| over the videos; "
             "time: median wall time per video, compilation excluded; LM steps: Levenberg-Marquardt steps of all "
             "starts together (median); cover90: share of (video, parameter) pairs whose truth is in the 90% interval.",
             "", "| method | videos | k1 | k2 | phi | LM steps | max R-hat | cover90 | time (s) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for m, row in summary.items():
        lines.append(f"| {m} | {row['videos']} | {row['mae_k1']:.4f} | {row['mae_k2']:.4f} | {row['mae_phi']:.4f} | "
                     f"{row.get('lm_steps', '-')} | {round(row['max_rhat'], 3) if 'max_rhat' in row else '-'} | "
                     f"{round(row['cover90'], 2) if 'cover90' in row else '-'} | {row['time_s']:.2f} |")
    lines += ["", "Per video |error| k1 / k2 / phi:", "", "| video | truth k1, k2, phi | " + " | ".join(methods) + " |",
              "|---|---|" + "---|" * len(methods)]
    for r in records:
        t = r["truth"]
        cells = [" / ".join(f"{r['runs'][m]['error'][n]:.3f}" for n in NAMES) if m in r["runs"] else "-" for m in methods]
        lines.append(f"| {r['video']} | {t['k1']:.3f}, {t['k2']:.3f}, {t['phi']:.3f} | " + " | ".join(cells) + " |")
    with atomic_path(RESULTS / f"{name}.md") as tmp:
        tmp.write_text("\n".join(lines) + "\n")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--videos", type=int, default=8)
    ap.add_argument("--mh", action="store_true", help="also run mh (about 10 min per video on 2 cores)")
    ap.add_argument("--seed", type=int, default=4)
    ap.add_argument("--out", default=str(RESULTS / "cnn_videos"))
    ap.add_argument("--no-warmup", action="store_true",
                    help="skip the compilation warm-up video (the first video's times then include compilation)")
    args = ap.parse_args(argv)
    from galileo_jax.jaxcache import enable_compilation_cache

    enable_compilation_cache()
    work = Path(args.out)
    work.mkdir(parents=True, exist_ok=True)
    # Warm-up: compile every method on one extra video so that the timings exclude compilation.
    if not args.no_warmup:
        run_methods(render(10_000, work, args.seed), args.mh)
    for i in range(args.videos):
        rec_path = work / f"video_{i}.json"
        if rec_path.exists():
            continue
        video = render(i, work, args.seed)
        rec = run_methods(video, args.mh)
        from galileo_jax.report.results import write_json

        write_json(rec_path, rec)
        print(f"video {i}: " + ", ".join(f"{m} k1 err {r['error']['k1']:.4f} ({r['time_s']:.1f} s)"
                                         for m, r in rec["runs"].items()), flush=True)
        write_tables(work)
    write_tables(work)
    return 0


if __name__ == "__main__":
    sys.exit(main())
