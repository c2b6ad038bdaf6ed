"""A sweep over rendered videos in the Physics 101 layout: one command, one config, one table.

Issue 5, "What it must show" 2. Renders ``--videos`` videos per ramp setting (10 and 20
degrees; as ``benchmarks/cnn_videos.py`` renders them: C MuJoCo renderer, 480x270, 2.5 s at
30 fps, pixel noise, random informative parameters as ``synth --random`` draws them) into
``<dataset>/scenarios/ramp/<setting>/box/t<i>/Camera_1.mp4``, each with its calibrated scene
``Camera_1.yaml`` and ground truth ``Camera_1.truth.json`` beside it (the sweep reads the scene
from the video's folder), then runs ONE sweep with ``configs/sweep.yaml``:

    python -m galileo_jax.sweep dataset=<dataset> method=grad,mh hydra.sweep.dir=<sweep>

(``--launcher joblib`` adds ``hydra/launcher=joblib``; the default, Hydra's basic launcher,
runs the jobs one after another in this process' child, sharing compiled programs), and
gathers it into ``benchmarks/results/sweep.{md,json}``
(``python -m galileo_jax.sweep.gather <sweep> --out benchmarks/results/sweep``).

    python benchmarks/sweep_rendered.py --videos 5 [--methods grad,mh]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

from _common import rendered  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
SETTINGS = {"10": ROOT / "scenes" / "ramp_10.yaml", "20": ROOT / "scenes" / "ramp_20.yaml"}


def render_dataset(dataset: Path, n: int, seed: int) -> list[Path]:
    """Render (once) n videos per setting into the Physics 101 layout; returns their paths."""
    from cnn_videos import render_informative

    from galileo_jax.scene import load_scene

    out = []
    for s, (setting, scene_path) in enumerate(SETTINGS.items()):
        scene = load_scene(scene_path)
        for i in range(n):
            video = dataset / "scenarios" / "ramp" / setting / "box" / f"t{i}" / "Camera_1.mp4"
            out.append(video)
            if rendered(video):
                continue
            video.parent.mkdir(parents=True, exist_ok=True)
            render_informative(scene, video, np.random.default_rng([seed, s, i]), seed * 100 + s * 10 + i)
            print(f"rendered {video.relative_to(dataset)}", flush=True)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--videos", type=int, default=5, help="videos per setting (10 and 20 degrees)")
    ap.add_argument("--methods", default="grad,mh")
    ap.add_argument("--dataset", default=str(ROOT / "sweeps" / "rendered_dataset"))
    ap.add_argument("--sweep-dir", default=str(ROOT / "sweeps" / "rendered"))
    ap.add_argument("--launcher", default=None, help="a Hydra launcher, e.g. joblib (default: basic)")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--out", default=str(RESULTS / "sweep"), help="table base name (OUT.md, OUT.json)")
    args = ap.parse_args(argv)
    dataset = Path(args.dataset)
    render_dataset(dataset, args.videos, args.seed)
    cmd = [sys.executable, "-m", "galileo_jax.sweep", f"dataset={dataset}", f"method={args.methods}",
           f"hydra.sweep.dir={args.sweep_dir}"]
    if args.launcher:
        cmd.append(f"hydra/launcher={args.launcher}")
    print(" ".join(cmd), flush=True)
    subprocess.run(cmd, check=True, cwd=ROOT)
    subprocess.run([sys.executable, "-m", "galileo_jax.sweep.gather", args.sweep_dir, "--out", args.out], check=True,
                   cwd=ROOT)
    return 0


if __name__ == "__main__":
    sys.exit(main())
