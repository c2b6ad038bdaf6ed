"""``python -m galileo_jax.sweep.gather SWEEP_DIR [--out BASE]``: one table of a sweep's jobs.

Reads every job record (``job.json``, :func:`galileo_jax.sweep.app.run_job`) under a multirun
folder and writes ``BASE.md`` and ``BASE.json`` atomically (default ``SWEEP_DIR/summary``):

* one row per job (video, method, settings variant): status, estimates of k1, k2, phi with
  their 90% intervals (where the method gives them), |error| against the truth (where
  ``<video stem>.truth.json`` exists), profile RMSE (m/s) and wall time (s, compilation
  included); a failed job keeps its one-line message, a job that never finished (killed,
  timed out, still running) says so;
* per method and settings variant: jobs, failed, mean |error| of k1, k2, phi over the jobs
  with a truth, and the median wall time of the successful jobs.
"""

from __future__ import annotations

import json
import math
import os
import platform
import sys
from pathlib import Path
from typing import Any

import numpy as np

from galileo_jax.errors import GalileoError, cli_entry

NAMES = ("k1", "k2", "phi")
RECORD = "job.json"
UNFINISHED = "did not finish (killed, timed out or still running); see sweep.log and .submitit/ in the sweep folder"


def load_records(sweep_dir: Path) -> list[dict]:
    """Every job record under ``sweep_dir``, sorted by (video id, method, variant); unfinished
    jobs marked failed.

    Raises:
        GalileoError: the folder is missing or holds no job record.
    """
    sweep_dir = Path(sweep_dir)
    if not sweep_dir.is_dir():
        raise GalileoError(f"sweep folder {sweep_dir} not found; give the folder a sweep wrote (sweeps/<date>_<time>)")
    records = []
    for path in sorted(sweep_dir.rglob(RECORD)):
        try:
            rec = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError):
            rec = {"status": "failed", "message": f"unreadable job record {path}"}
        if rec.get("status") == "running":
            rec = {**rec, "status": "failed", "message": UNFINISHED}
        rec["job_dir"] = str(path.parent.relative_to(sweep_dir))
        records.append(rec)
    if not records:
        raise GalileoError(f"no job records ({RECORD}) under {sweep_dir}; give the folder of a sweep run by "
                           f"python -m galileo_jax.sweep")
    return sorted(records, key=lambda r: (str(r.get("id") or r.get("video")), str(r.get("method")),
                                          str(r.get("variant")), r["job_dir"]))


def _row(rec: dict) -> dict[str, Any]:
    """The table row of one job record (plain values; None where absent)."""
    params = rec.get("parameters") or {}
    errs = rec.get("abs_error") or {}
    scene = rec.get("scene") or {}
    row = {"video": rec.get("id") or rec.get("video"), "scene": scene.get("name"), "scene_file": scene.get("file"),
           "scene_from": scene.get("from"), "method": rec.get("method"), "variant": rec.get("variant") or "",
           "status": rec.get("status"), "message": rec.get("message"), "rmse_m_per_s": rec.get("rmse_m_per_s"),
           "wall_s": rec.get("wall_s"), "job_dir": rec["job_dir"]}
    for n in NAMES:
        p = params.get(n) or {}
        row[n] = p.get("estimate")
        row[f"{n}_interval90"] = p.get("interval90")
        row[f"abs_error_{n}"] = errs.get(n)
    return row


def _mean(values: list) -> float | None:
    vals = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(vals)) if vals else None


def summarize(rows: list[dict]) -> list[dict]:
    """Per (method, variant): jobs, failed, mean |error| of k1, k2, phi, median wall time (s) of the ok jobs."""
    out = []
    for key in dict.fromkeys((r["method"], r["variant"]) for r in rows):
        rs = [r for r in rows if (r["method"], r["variant"]) == key]
        ok = [r for r in rs if r["status"] == "ok"]
        times = [r["wall_s"] for r in ok if r["wall_s"] is not None]
        out.append({"method": key[0], "variant": key[1], "jobs": len(rs), "failed": len(rs) - len(ok),
                    **{f"mae_{n}": _mean([r[f"abs_error_{n}"] for r in ok]) for n in NAMES},
                    "median_wall_s": float(np.median(times)) if times else None})
    return out


def _f(x: Any, fmt: str = ".3f") -> str:
    return "-" if x is None else format(x, fmt)


def _cell(row: dict, n: str) -> str:
    iv = row[f"{n}_interval90"]
    return _f(row[n]) + ("" if not iv or None in iv else f" [{iv[0]:.3f}, {iv[1]:.3f}]")


def markdown(sweep_dir: Path, rows: list[dict], summary: list[dict]) -> str:
    """The Markdown report: summary table, then one row per job."""
    lines = [f"# Sweep {sweep_dir}", "",
             f"{len(rows)} jobs, {sum(r['status'] != 'ok' for r in rows)} failed "
             f"(`python -m galileo_jax.sweep.gather {sweep_dir}`). |error| against each video's "
             "`.truth.json`; time: the job's wall time, compilation included.", "",
             "| method | settings | jobs | failed | mean abs err k1 | k2 | phi | median time (s) |",
             "|---|---|---|---|---|---|---|---|"]
    for s in summary:
        maes = " | ".join(_f(s[f"mae_{n}"], ".4f") for n in NAMES)
        lines.append(f"| {s['method']} | {s['variant'] or '-'} | {s['jobs']} | {s['failed']} | {maes} | "
                     f"{_f(s['median_wall_s'], '.1f')} |")
    lines += ["", "| video | scene | method | settings | status | k1 [90%] | k2 [90%] | phi [90%] | "
              "abs err k1 / k2 / phi | RMSE (m/s) | time (s) | job |", "|---" * 12 + "|"]
    for r in rows:
        status = r["status"] if r["status"] == "ok" else f"failed: {r['message']}"
        errs = " / ".join(_f(r[f"abs_error_{n}"], ".4f") for n in NAMES)
        lines.append(f"| {r['video']} | {r['scene'] or '-'} | {r['method']} | {r['variant'] or '-'} | "
                     f"{status.replace('|', '/')} | {_cell(r, 'k1')} | {_cell(r, 'k2')} | {_cell(r, 'phi')} | "
                     f"{errs} | {_f(r['rmse_m_per_s'], '.4f')} | {_f(r['wall_s'], '.1f')} | {r['job_dir']} |")
    return "\n".join(lines) + "\n"


def gather(sweep_dir: str | Path, out: str | Path | None = None) -> dict:
    """Collect a sweep's job records into ``out.md`` and ``out.json`` (default ``sweep_dir/summary``).

    Returns:
        ``{"sweep_dir", "machine", "summary": [...], "rows": [...], "outputs": {...}}`` as written.

    Raises:
        GalileoError: see :func:`load_records`.
    """
    from galileo_jax.report.results import atomic_path, write_json

    sweep_dir = Path(sweep_dir)
    rows = [_row(r) for r in load_records(sweep_dir)]
    summary = summarize(rows)
    base = Path(out) if out is not None else sweep_dir / "summary"
    md, js = base.with_name(base.name + ".md"), base.with_name(base.name + ".json")
    result = {"sweep_dir": str(sweep_dir),
              "machine": f"{platform.machine()}, {os.cpu_count()} CPU cores, Python {platform.python_version()}",
              "summary": summary, "rows": rows, "outputs": {"markdown": str(md), "json": str(js)}}
    write_json(js, result)
    with atomic_path(md) as tmp:
        tmp.write_text(markdown(sweep_dir, rows, summary))
    return result


@cli_entry
def main(argv: list[str] | None = None) -> int:
    from galileo_jax.cli import OneLineParser

    p = OneLineParser(prog="python -m galileo_jax.sweep.gather", description=__doc__.splitlines()[0])
    p.add_argument("sweep_dir", metavar="SWEEP_DIR", help="folder of a sweep (hydra.sweep.dir, e.g. sweeps/<date>)")
    p.add_argument("--out", help="write OUT.md and OUT.json (default: SWEEP_DIR/summary)")
    args = p.parse_args(argv)
    result = gather(args.sweep_dir, args.out)
    failed = sum(s["failed"] for s in result["summary"])
    print(f"{len(result['rows'])} jobs ({failed} failed) -> {result['outputs']['markdown']}, "
          f"{result['outputs']['json']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
