"""Coverage of the fit's intervals on rendered videos, in the manner of simulation-based calibration.

Simulation-based calibration (Talts et al. 2018, arXiv:1804.06788): draw parameters from the
prior, simulate data, fit, and look where the truth falls in the posterior. Over many videos a
calibrated method's 50% intervals hold the truth in about half of them and its 90% intervals in
about nine in ten, and the truth's rank among the posterior draws is uniform.

Videos, in turns of three (video ``j``):

* ``ramp_10``, ``ramp_20``: the shipped scenes, textured cubes, orthographic camera, 480x270,
  2.5 s at 30 fps, pixel noise SD 2 (``benchmarks/cnn_videos.py``'s settings);
* ``world``: plain cubes of random colours through a perspective camera at 960x540, random
  ramp, sizes, direction, backdrop and noise, the hand in every other video, motion blur in
  every other (``benchmarks/world.py``).

Masses and frictions are drawn from the scene's prior, kept where object 1 slides and reaches
object 2 (``synth.draw_informative_params``: the videos a user films). Each video is fitted as
``python -m galileo_jax.fit VIDEO --method M`` does (:func:`galileo_jax.pipeline.run_fit`, default
settings: tracked from the pixels, objects found automatically, the scene file as written by
the renderer, which states no scale tolerance, so grad and mh fit the camera's scale error as a
nuisance within +-3%; cnn fits no nuisance, and the scene-conditioned network's intervals allow
for a +-3% scale error it was trained with, ``configs/cnn_family.yaml``). The intervals are the central 50% and
90% intervals of the fit's posterior draws (``posterior.nc``: mh's chains, grad's and cnn's
Gaussian approximation); the rank is the share of draws below the truth. ``grad`` is grad
from the prior (``--init prior``: four starts from a screen of the whole prior); ``grad+cnn``
is grad started from the trained CNN's estimate (``--init cnn``), which ``fit`` does by default
wherever a network reads the scene, as it does for every video here. ``grad-plain`` is grad's own fits with the
Gauss-Newton intervals it had before widening them to the sandwich estimate's (draws shrunk back
about the estimate by each parameter's widening factor): the widening's effect on the same fits.
A method name ending ``@ensK`` (e.g. ``grad@ens8``) fits with ``likelihood.ensemble: K``
(``fit --ensemble K``: each simulated profile the mean of K rollouts from starts shifted within
one physics step).

    python benchmarks/coverage.py [--videos 100] [--methods grad,mh,cnn,grad+cnn,grad@ens8] [--work DIR]
        [--rerun [--rerun-only grad/world,...]] [--families world,...] [--records-only mh,...]
    python benchmarks/coverage.py --methods grad,grad@ens8,mh --records-only grad@ens8,mh --rerun \
        --rerun-only grad/ramp_10,grad/ramp_20   # refit one method on some families, keep every row

Writes ``benchmarks/results/coverage.{md,json}``; videos and per-video records go under
``--work`` (default ``benchmarks/results/coverage/``; videos not kept in git). Resumable: a video
with a record is not fitted again (``--rerun`` fits again; ``--rerun-only`` limits that to the
named method/family pairs, the others' records are read as they are; ``--keep-since`` keeps the
records fitted since a time, to resume an interrupted rerun; ``--families`` fits only the named
families' videos; ``--records-only`` reads the named methods' records and never fits them, so a
rerun of one method keeps the others' rows).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from world import Condition, render_world  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
NAMES = ("k1", "k2", "phi")
FAMILIES = ("ramp_10", "ramp_20", "world")
LEVELS = (0.5, 0.9)
#: Goals of the coverage (issue): 90% intervals 85-95%, 50% intervals 40-60%.
GOALS = {0.5: (0.40, 0.60), 0.9: (0.85, 0.95)}
RANK_BINS = 10


def render(j: int, work: Path, seed: int) -> Path:
    """Render (once) video ``j`` (its family by ``j % 3``, module docstring); its path."""
    from galileo_jax.scene import load_scene

    family = FAMILIES[j % len(FAMILIES)]
    video = work / f"{family}_{j}.mp4"
    if family == "world":
        render_world(video, Condition("plain", "perspective", "960x540", blur=(j // 3) % 2 == 1),
                     hand=(j // 3) % 2 == 0, seed=seed * 10_000 + j)
        return video
    from _common import rendered

    if not rendered(video):
        from cnn_videos import render_informative

        stream = np.random.SeedSequence([seed, j])
        render_informative(load_scene(ROOT / "scenes" / f"{family}.yaml"), video, np.random.default_rng(stream),
                           int(stream.generate_state(1)[0] % 2**31))
    return video


def interval(draws: np.ndarray, level: float) -> tuple[float, float]:
    """The central ``level`` interval of ``draws`` (any shape, flattened)."""
    x = np.asarray(draws, np.float64).ravel()
    return float(np.quantile(x, 0.5 - level / 2)), float(np.quantile(x, 0.5 + level / 2))


def truth_record(draws: np.ndarray, truth: float) -> dict:
    """Where ``truth`` falls in the posterior ``draws``: rank (share of draws below it) and,
    per level of :data:`LEVELS`, the interval and whether it holds the truth."""
    x = np.asarray(draws, np.float64).ravel()
    rec = {"rank": float(np.mean(x < truth)), "median": float(np.median(x))}
    for level in LEVELS:
        lo, hi = interval(x, level)
        rec[f"interval{int(level * 100)}"] = [lo, hi]
        rec[f"covered{int(level * 100)}"] = bool(lo <= truth <= hi)
    return rec


def fit_one(video: Path, method: str) -> dict:
    """Fit ``video`` as ``fit --method METHOD --init prior`` does (``grad+cnn``: ``--method grad --init cnn``;
    ``grad@ens8``: ``--method grad --ensemble 8``);
    its record (an ``error`` if it failed)."""
    from galileo_jax.config import FitConfig
    from galileo_jax.pipeline import run_fit
    from galileo_jax.scene import load_scene

    truth = json.loads(video.with_suffix(".truth.json").read_text())
    rec = {"video": video.name, "method": method, "truth": {n: truth[n] for n in NAMES},
           "fitted_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}
    t = time.perf_counter()
    try:
        base, _, ensemble = method.partition("@ens")
        name, _, init = base.partition("+")
        cfg = FitConfig()
        if ensemble:  # else the method's own default (fit's: mh 2, the others 1)
            cfg.likelihood.ensemble = int(ensemble)
        rep = run_fit(video, load_scene(video.with_suffix(".yaml")), cfg, method=name,
                      out=video.parent / f"{video.stem}_{method}", overlay=False, progress=False,
                      init=init or "prior")
    except Exception as err:  # noqa: BLE001 - a failure is a result here
        rec["error"] = f"{type(err).__name__}: {err}"
        return rec
    rec["wall_s"] = time.perf_counter() - t
    for n in NAMES:
        draws = rep.posterior.draws[n]
        rec[n] = {"estimate": rep.parameters[n]["estimate"], **truth_record(draws, truth[n])}
        rec[n]["error"] = abs(rec[n]["estimate"] - truth[n])
        lo, hi = rep.parameters[n]["interval90"]  # the interval the summary reports (grad: profile-checked)
        rec[n]["reported90"] = [lo, hi]
        rec[n]["covered90_reported"] = bool(lo <= truth[n] <= hi)
        rec[n]["interval_method"] = rep.parameters[n].get("interval_method")
    rec["rmse_over_noise"] = max(v["ratio"] for v in rep.rmse.values() if "ratio" in v)
    rec["adequate"] = bool((rep.adequacy or {}).get("adequate", True))
    rec["competing_optima"] = len(rep.diagnostics.get("competing_optima", []))
    rec["rhat_max"] = max((rep.parameters[n].get("rhat") or 0.0) for n in NAMES) or None
    widening = rep.diagnostics.get("interval_widening")
    if widening:  # grad: the same fit's intervals before the sandwich widening (draws shrunk back
        # about the estimate by each parameter's factor; the factor is in z, locally linear)
        rec["interval_widening"] = {n: widening.get(n, 1.0) for n in NAMES}
        rec["plain"] = {}
        for n in NAMES:
            e, f = rec[n]["estimate"], widening.get(n, 1.0)
            rec["plain"][n] = {"estimate": e, **truth_record(e + (np.asarray(rep.posterior.draws[n]) - e) / f,
                                                             truth[n]), "error": rec[n]["error"]}
    return rec


def plain_records(records: list[dict]) -> list[dict]:
    """For each grad record with an ``interval_widening``, the same fit without it (method
    ``grad-plain``: the Gauss-Newton intervals), to compare on the same fits."""
    out = []
    for r in records:
        if "plain" in r:
            out.append({**{k: v for k, v in r.items() if k not in ("plain", *NAMES)}, **r["plain"],
                        "method": r["method"] + "-plain"})
    return out


def summarise(records: list[dict]) -> dict:
    """Per method, family ("all" too) and parameter: videos, median |error|, coverage of each
    level, rank histogram (:data:`RANK_BINS` bins)."""
    out: dict = {}
    for method in sorted({r["method"] for r in records}):
        mine = [r for r in records if r["method"] == method and "error" not in r]
        out[method] = {}
        for family in (*FAMILIES, "all"):
            rows = [r for r in mine if family == "all" or r["video"].startswith(family + "_")]
            if not rows:
                continue
            fam = {"videos": len(rows), "failed": sum(1 for r in records if r["method"] == method and "error" in r
                                                      and (family == "all" or r["video"].startswith(family + "_")))}
            for n in NAMES:
                ranks = np.array([r[n]["rank"] for r in rows])
                fam[n] = {"median_error": float(np.median([r[n]["error"] for r in rows])),
                          **{f"coverage{int(lv * 100)}": float(np.mean([r[n][f"covered{int(lv * 100)}"] for r in rows]))
                             for lv in LEVELS},
                          "rank_histogram": np.histogram(ranks, bins=RANK_BINS, range=(0.0, 1.0))[0].tolist()}
            out[method][family] = fam
    return out


def _flag(value: float, level: float) -> str:
    lo, hi = GOALS[level]
    return f"{value:.2f}" if lo <= value <= hi else f"**{value:.2f}**"


def tables(summary: dict, records: list[dict]) -> list[str]:
    """Markdown: coverage per method, family and parameter (outside the goal in bold), rank
    histograms, and the videos whose 90% interval missed a truth."""
    lines = ["| method | videos | family | parameter | median abs error | 50% coverage | 90% coverage | "
             f"rank histogram ({RANK_BINS} bins, truth below all draws -> above all) |", "|" + "---|" * 8]
    for method, fams in summary.items():
        for family, fam in fams.items():
            for n in NAMES:
                s = fam[n]
                lines.append(f"| {method} | {fam['videos']} ({fam['failed']} failed) | {family} | {n} | "
                             f"{s['median_error']:.4f} | {_flag(s['coverage50'], 0.5)} | {_flag(s['coverage90'], 0.9)} | "
                             f"{' '.join(map(str, s['rank_histogram']))} |")
    missed = [r for r in records if "error" not in r and not r["method"].endswith("-plain")
              and not all(r[n]["covered90"] for n in NAMES)]
    lines += ["", f"Videos whose 90% interval missed a truth ({len(missed)}; RMSE / noise is the worst trace's, "
              "'optima' the competing optima `fit` warned of):", "",
              "| video | method | k1 true / est | k2 true / est | phi true / est | missed | RMSE / noise | optima |",
              "|---|---|---|---|---|---|---|---|"]
    for r in missed:
        miss = ", ".join(n for n in NAMES if not r[n]["covered90"])
        lines.append(f"| {r['video']} | {r['method']} | "
                     + " | ".join(f"{r['truth'][n]:.3f} / {r[n]['estimate']:.3f}" for n in NAMES)
                     + f" | {miss} | {r['rmse_over_noise']:.1f} | {r['competing_optima']} |")
    lines += ["", "Time and convergence per method (wall time of one fit, tracking included; mh's largest "
              "R-hat over k1, k2, phi, rank-normalised split R-hat, Vehtari et al. 2021):", ""]
    for method in (m for m in summary if not m.endswith("-plain")):
        ok = [r for r in records if r["method"] == method and "error" not in r]
        wall = np.array([r["wall_s"] for r in ok])
        line = f"- {method}: median {np.median(wall):.1f} s, 90th percentile {np.percentile(wall, 90):.1f} s"
        rhat = np.array([r["rhat_max"] for r in ok if r.get("rhat_max")])
        if len(rhat):
            line += (f"; R-hat median {np.median(rhat):.3f}, at most 1.01 in {int((rhat <= 1.01).sum())}, at most "
                     f"1.05 in {int((rhat <= 1.05).sum())}, at most 1.1 in {int((rhat <= 1.1).sum())} of {len(rhat)}, "
                     f"largest {rhat.max():.2f}")
        lines.append(line)
    checked = [r for r in records if "error" not in r and any(r[n].get("interval_method") for n in NAMES)]
    if checked:  # grad's reported intervals, checked against the profile likelihood (the draws stay Gauss-Newton)
        lines += ["", "90% coverage of the intervals the summary reports, where grad checked them against the profile "
                  "likelihood (the coverage above is that of the Gauss-Newton draws; k1 / k2 / phi, and how many "
                  "intervals the profile widened):", ""]
        for method in sorted({r["method"] for r in checked}):
            for family in (*FAMILIES, "all"):
                rows = [r for r in checked if r["method"] == method and (family == "all" or r["video"].startswith(family + "_"))]
                if rows:
                    cov = " / ".join(f"{np.mean([r[n]['covered90_reported'] for r in rows]):.2f}" for n in NAMES)
                    wid = sum(r[n].get("interval_method") == "profile likelihood" for r in rows for n in NAMES)
                    lines.append(f"- {method}, {family} ({len(rows)} videos): {cov}; widened {wid} of {3 * len(rows)}")
    lines += adequacy_lines(records)
    failed = [r for r in records if "error" in r]
    if failed:  # one line per method and message (a CNN missing for a scene stops every video of it)
        groups: dict = {}
        for r in failed:
            groups.setdefault((r["method"], r["error"][:200]), []).append(r["video"])
        lines += ["", "Videos the fit stopped on:", ""] + [
            f"- {m} on {len(v)} video{'s' if len(v) > 1 else ''} ({', '.join(v[:4])}{', ...' if len(v) > 4 else ''}): {e}"
            for (m, e), v in groups.items()]
    return lines


def record_dates(records: list[dict]) -> list[str]:
    """Markdown: when each method's records of each family were fitted (their ``fitted_utc``
    dates): a run with ``--rerun-only`` refits some and keeps the others' earlier records."""
    out = ["Records fitted on (UTC dates; records from before the benchmark stamped them are 'undated'; "
           "rows fitted by different versions of the code are not comparable):", ""]
    for method in sorted({r["method"] for r in records if not r["method"].endswith("-plain")}):
        for family in FAMILIES:
            mine = [r for r in records if r["method"] == method and r["video"].startswith(family + "_")]
            if mine:
                days = sorted({r.get("fitted_utc", "undated")[:10] for r in mine})
                out.append(f"- {method}, {family}: {', '.join(days)} ({len(mine)} records)")
    return out


def adequacy_lines(records: list[dict]) -> list[str]:
    """Markdown: per method, the 90% coverage (k1 / k2 / phi) and median RMSE over the noise floor
    of the fits the report called adequate and of those it called inadequate (``result.json``'s
    ``adequacy``): how far a user can trust the intervals of a fit that says it is adequate."""
    out = ["", "90% coverage by the fit's own adequacy verdict (the residual tests of `result.json`'s "
           "`adequacy`; k1 / k2 / phi, the draws' intervals; median RMSE over the noise floor):", ""]
    for method in sorted({r["method"] for r in records if "error" not in r and not r["method"].endswith("-plain")}):
        for verdict in (True, False):
            rows = [r for r in records if r["method"] == method and "error" not in r and r.get("adequate") == verdict]
            if rows:
                cov = " / ".join(f"{np.mean([r[n]['covered90'] for r in rows]):.2f}" for n in NAMES)
                ratio = np.median([r["rmse_over_noise"] for r in rows])
                out.append(f"- {method}, {'adequate' if verdict else 'inadequate'} ({len(rows)} videos): {cov}; "
                           f"RMSE / noise {ratio:.1f}")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--videos", type=int, default=100)
    ap.add_argument("--methods", default="grad",
                    help="comma-separated fit methods (grad, mh, cnn; grad+cnn: grad started from the CNN; "
                         "grad@ens8: grad with a rollout ensemble of 8)")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--work", type=Path, default=RESULTS / "coverage")
    ap.add_argument("--rerun", action="store_true", help="fit again videos that have a record")
    ap.add_argument("--rerun-only", default="", metavar="M/F,...",
                    help="with --rerun, fit again only these method/family pairs (e.g. grad/world,mh/world)")
    ap.add_argument("--families", default="", metavar="F,...",
                    help="fit only videos of these families (e.g. world); the others' records are read where "
                         "they exist")
    ap.add_argument("--records-only", default="", metavar="M,...",
                    help="methods whose existing records are read but that are never fitted here (e.g. "
                         "grad@ens8,mh beside a grad rerun: the table keeps their rows)")
    ap.add_argument("--keep-since", default="", metavar="DATE",
                    help="with --rerun, keep records fitted on or after this UTC date or time (ISO, e.g. "
                         "2026-11-26T23:00): resumes an interrupted rerun")
    args = ap.parse_args(argv)
    only = {tuple(x.strip().split("/", 1)) for x in args.rerun_only.split(",") if x.strip()}
    families = {x.strip() for x in args.families.split(",") if x.strip()}
    read_only = {x.strip() for x in args.records_only.split(",") if x.strip()}
    from tqdm import tqdm

    from galileo_jax.jaxcache import enable_compilation_cache
    from galileo_jax.report.results import atomic_path
    from _common import docstring_markdown, machine_line

    enable_compilation_cache()
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    args.work.mkdir(parents=True, exist_ok=True)
    records = []
    for j in tqdm(range(args.videos), desc="coverage benchmark", unit="video"):
        family = FAMILIES[j % len(FAMILIES)]
        video = args.work / f"{family}_{j}.mp4"
        for method in methods:
            path = args.work / f"{video.stem}_{method}.json"
            refit = args.rerun and (not only or (method, family) in only)
            if refit and args.keep_since and path.exists():  # ISO strings of one form sort as times
                refit = json.loads(path.read_text()).get("fitted_utc", "") < args.keep_since
            if (path.exists() and not refit) or (families and family not in families) or method in read_only:
                if path.exists():
                    records.append(json.loads(path.read_text()))
                continue
            render(j, args.work, args.seed)  # renders only where the video is not there yet
            rec = fit_one(video, method)
            with atomic_path(path) as tmp:
                tmp.write_text(json.dumps(rec))
            records.append(rec)
    records += plain_records(records)
    summary = summarise(records)
    command = "python benchmarks/coverage.py " + " ".join(argv if argv is not None else sys.argv[1:])
    doc = {"machine": machine_line(), "command": command, "summary": summary, "records": records}
    with atomic_path(RESULTS / "coverage.json") as tmp:
        tmp.write_text(json.dumps(doc, indent=1))
    paragraphs = docstring_markdown(__doc__, 1, 5)  # the description; a list keeps its items
    lines = ["# Coverage of the fit's intervals on rendered videos", "", f"machine: {doc['machine']}", "",
             f"command: `{command}`", "", *paragraphs,
             "Goal: 90% intervals cover 85-95% and 50% intervals 40-60% of the truths, per method and "
             "parameter (bold: outside). A calibrated method's rank histogram is flat; a U shape means "
             "intervals too narrow, a hump too wide, a slope a bias.", "", *tables(summary, records), "",
             *record_dates(records), ""]
    with atomic_path(RESULTS / "coverage.md") as tmp:
        tmp.write_text("\n".join(lines))
    print("\n".join(lines[:40]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
