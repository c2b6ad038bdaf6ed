"""Does mh mix? R-hat, ESS and errors of its proposal variants on rendered videos with ground truth.

The log-likelihood is rough around contact events (:mod:`galileo_jax.inference.mh`, "Jumps"), so
a random walk that adapts to the local spikes leaves each chain on its own spike. This runs
``run_mh`` with ``fit``'s defaults (16 chains, 300 annealed warm-up + 400 kept steps, C MuJoCo on a
CPU) and these proposals, same PRNG key, on the committed rendered videos whose R-hat was worst
(``benchmarks/results/samplers`` ramp_20 video_1 and video_4, ``benchmarks/results/cnn_videos``
video_0, 2, 3):

* ``local, within-chain shape``: the sampler before the change (adapt "within", no jumps);
* ``local, population shape``: the proposal's shape from all chains' draws (adapt "population");
* ``jump 0.3`` and ``jump 0.5``: population shape plus population-wide jumps with that probability
  (``jump 0.5`` is ``fit``'s default, ``mh.jump``);
* ``jump 0.5, ensemble K``: ``jump 0.5`` on the likelihood smoothed by a rollout ensemble of K
  (``fit --ensemble K``: each simulated profile the mean of K rollouts from starts shifted
  within one physics step), the pseudo-marginal idea of the coverage issue, at K times the rollouts;
* ``jump 0.5, independent V`` (with ``ensemble K``): ``jump 0.5`` plus independence proposals
  with probability V (a Student-t fitted to the population's warm-up draws, ``run_mh``'s
  ``independent``);
* ``jump 0.5, warm-up 100`` from the prior and ``jump 0.5, --init cnn, warm-up 100`` (chains
  started at the CNN's draws, :func:`galileo_jax.pipeline.mh_start_from_cnn`): does the CNN's start
  cut the warm-up (issue 4)?

Per video and variant: max R-hat and min bulk ESS over k1, k2, phi (ArviZ, via
:func:`~galileo_jax.inference.summarize_mh`), |error| of the posterior median, whether the 90%
interval holds the truth, the best log-likelihood, acceptance and wall time (compilation included
in the first run of each video only). Writes ``benchmarks/results/mh_mixing.{md,json}``; resumable
(one record per video and variant in the JSON).

    python benchmarks/mh_mixing.py [--variants NAME ...]
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
from _common import machine_line, write_atomic  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
sys.path.insert(0, str(ROOT / "benchmarks"))

NAMES = ("k1", "k2", "phi")
VIDEOS = ("samplers/ramp_20/video_1.mp4", "samplers/ramp_20/video_4.mp4", "cnn_videos/video_0.mp4",
          "cnn_videos/video_2.mp4", "cnn_videos/video_3.mp4")
VARIANTS = {
    "local, within-chain shape": dict(adapt="within", jump=0.0),
    "local, population shape": dict(adapt="population", jump=0.0),
    "jump 0.3": dict(jump=0.3),
    "jump 0.5": dict(jump=0.5),
    "jump 0.5, warm-up 100": dict(jump=0.5, n_warmup=100),
    "jump 0.5, --init cnn, warm-up 100": dict(jump=0.5, n_warmup=100, init_cnn=True),
    "jump 0.5, ensemble 2": dict(jump=0.5, ensemble=2),
    "jump 0.5, ensemble 4": dict(jump=0.5, ensemble=4),
    "jump 0.5, ensemble 8": dict(jump=0.5, ensemble=8),
    "jump 0.5, independent 0.7": dict(jump=0.5, independent=0.7),
    "jump 0.5, independent 0.7, ensemble 2": dict(jump=0.5, independent=0.7, ensemble=2),
    "jump 0.5, independent 0.7, ensemble 4": dict(jump=0.5, independent=0.7, ensemble=4),
    "jump 0.5, independent 0.9, ensemble 2": dict(jump=0.5, independent=0.9, ensemble=2),
}
OUT = RESULTS / "mh_mixing.json"


def run_video(video: str, variants: list[str], done: set) -> list[dict]:
    """Records of ``variants`` on one video (skipping those in ``done``)."""
    import jax

    from galileo_jax.config import FitConfig
    from galileo_jax.inference import Problem, cnn, run_mh, summarize_mh
    from galileo_jax.observe import observe
    from galileo_jax.pipeline import mh_start_from_cnn, problem_options
    from galileo_jax.scene import load_scene

    path = RESULTS / video
    cfg = FitConfig()
    scene = load_scene(path.with_suffix(".yaml"))
    truth = json.loads(path.with_suffix(".truth.json").read_text())
    obs = observe(path, scene, progress=False)
    problems = {}
    out = []
    for name in variants:
        if (video, name) in done:
            continue
        kw = dict(VARIANTS[name])
        k = kw.pop("ensemble", 1)
        if k not in problems:  # as fit builds mh's problem, with this variant's ensemble
            problems[k] = Problem(scene, obs, **{**problem_options(scene, cfg, "mh"), "ensemble": k})
        problem = problems[k]
        if kw.pop("init_cnn", False):
            est = cnn.estimate(cnn.find_model(scene, obs.fps), obs, problem.space, jax.random.PRNGKey(0))
            kw.update(mh_start_from_cnn(est, cfg.mh.chains))
        kw.setdefault("n_warmup", cfg.mh.warmup)
        t = time.perf_counter()
        res = run_mh(problem, jax.random.PRNGKey(2), n_chains=cfg.mh.chains, n_samples=cfg.mh.samples,
                     progress=False, **kw)
        p = summarize_mh(res, problem.space)["parameters"]
        rec = {"video": video, "variant": name, "engine": problem.simulator_engine, "time_s": time.perf_counter() - t,
               "rhat": {n: float(p[n]["rhat"]) for n in NAMES}, "ess_bulk": {n: float(p[n]["ess_bulk"]) for n in NAMES},
               "error": {n: abs(float(p[n]["median"]) - float(truth[n])) for n in NAMES},
               "inside90": {n: bool(p[n]["interval90"][0] <= truth[n] <= p[n]["interval90"][1]) for n in NAMES},
               "best_loglik": float(np.max(res.loglik)), "acceptance": float(np.mean(res.acceptance))}
        print(f"{video} | {name}: max R-hat {max(rec['rhat'].values()):.2f}, min ESS {min(rec['ess_bulk'].values()):.0f}, "
              f"{rec['time_s']:.0f} s", flush=True)
        out.append(rec)
    return out


def write_tables(records: list[dict]) -> str:
    """The markdown of ``mh_mixing.md`` from the records."""
    variants = [v for v in VARIANTS if any(r["variant"] == v for r in records)]
    videos = [v for v in VIDEOS if any(r["video"] == v for r in records)]
    by = {(r["video"], r["variant"]): r for r in records}
    lines = ["# mh mixing: proposal variants on rendered videos", "",
             f"machine: {machine_line()}; "
             f"engine: {', '.join(sorted({r['engine'] for r in records}))}", "",
             "Command: `python benchmarks/mh_mixing.py` (module docstring). 16 chains, 400 kept steps, warm-up 300 "
             "unless named; same PRNG key for every variant. max R-hat, min ESS: over k1, k2, phi (ArviZ rank-normalised "
             "split R-hat, bulk ESS). ESS/s: min ESS / wall time, per video (times measured with other work on this 2-core "
             "machine now and then: rough). Each row as recorded: 'jump 0.5' and the 'independent' rows ran on "
             "the same code, one after the other on an otherwise idle machine; the other rows on earlier versions "
             "(tracker and likelihood changed since; 'jump 0.5' then gave worst R-hats 1.54, 1.19, 1.19, 1.32, "
             "1.17). Errors: |posterior median - truth|, mean over videos. cover90: share of (video, "
             "parameter) pairs whose truth is in the 90% interval.", "",
             "| variant | max R-hat per video | videos with R-hat <= 1.05 / 1.1 | median min ESS | median ESS/s | "
             "k1 | k2 | phi | cover90 | median time (s) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for v in variants:
        rs = [by[(vid, v)] for vid in videos if (vid, v) in by]
        worst = [max(r["rhat"].values()) for r in rs]
        err = {n: np.mean([r["error"][n] for r in rs]) for n in NAMES}
        cover = np.mean([r["inside90"][n] for r in rs for n in NAMES])
        lines.append(f"| {v} | {', '.join(f'{w:.2f}' for w in worst)} | "
                     f"{sum(w <= 1.05 for w in worst)} / {sum(w <= 1.1 for w in worst)} of {len(rs)} | "
                     f"{np.median([min(r['ess_bulk'].values()) for r in rs]):.0f} | "
                     f"{np.median([min(r['ess_bulk'].values()) / r['time_s'] for r in rs]):.2f} | "
                     f"{err['k1']:.4f} | {err['k2']:.4f} | "
                     f"{err['phi']:.4f} | {cover:.2f} | {np.median([r['time_s'] for r in rs]):.0f} |")
    lines += ["", f"Videos, in the order of the R-hat column: {', '.join(videos)}.", ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--variants", nargs="*", default=list(VARIANTS), choices=list(VARIANTS))
    args = ap.parse_args(argv)
    records = json.loads(OUT.read_text())["records"] if OUT.exists() else []
    done = {(r["video"], r["variant"]) for r in records}
    for video in VIDEOS:
        records += run_video(video, args.variants, done)
        write_atomic(OUT, json.dumps({"records": records}, indent=1))
        write_atomic(OUT.with_suffix(".md"), write_tables(records))
    print(OUT.with_suffix(".md").read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
