"""What every benchmark script shares: where results go, the machine line and code version each
table records, atomic writes (several runs may write the same table), and whether a video was
already rendered (runs resume).

Scripts run as ``python benchmarks/NAME.py``, so this folder is on ``sys.path`` and they
``from _common import ...``.
"""

from __future__ import annotations

import os
import platform
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def machine_line() -> str:
    """One line naming the machine and software a measurement ran on, e.g. ``x86_64, AMD EPYC,
    2 CPU cores, Python 3.11.7, JAX 0.10.2 (cpu), MuJoCo 3.3.7`` (timings differ 2x between
    machines: compare only rows measured on the same line)."""
    import jax
    import mujoco

    cpu = ""
    try:
        cpu = next(ln.split(":", 1)[1].strip() for ln in Path("/proc/cpuinfo").read_text().splitlines()
                   if ln.startswith("model name")) + ", "
    except (OSError, StopIteration):
        pass
    backend = jax.default_backend()
    if backend != "cpu":
        backend += ": " + jax.devices()[0].device_kind
    return (f"{platform.machine()}, {cpu}{os.cpu_count()} CPU cores, Python {platform.python_version()}, "
            f"JAX {jax.__version__} ({backend}), MuJoCo {mujoco.__version__}")


def code_version(*paths: str) -> str:
    """Commit of the checkout, with ``-modified`` if the package (or one of ``paths``, relative
    to the repository) differs from it, so a record says which code made it; "unknown" outside git."""

    def git(*args) -> subprocess.CompletedProcess:
        return subprocess.run(["git", "-C", str(ROOT), *args], capture_output=True, text=True, timeout=10)

    try:
        out = git("rev-parse", "--short", "HEAD").stdout.strip()
        if out and git("diff", "--quiet", "HEAD", "--", "galileo_jax", *paths).returncode:
            out += "-modified"
    except (OSError, subprocess.SubprocessError):
        out = ""
    return out or "unknown"


def rendered(video: Path, sidecars: tuple[str, ...] = (".truth.json",)) -> bool:
    """True when ``video`` and its ``sidecars`` (suffixes replacing ``.mp4``: the truth JSON, the
    scene file) all exist, i.e. an earlier run rendered it (the renderer writes each file
    atomically, so a render stopped half-way does not count)."""
    return video.exists() and all(video.with_suffix(s).exists() for s in sidecars)


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically (a temporary file in the same folder, then renamed)."""
    from galileo_jax.report.results import atomic_path

    with atomic_path(Path(path)) as tmp:
        tmp.write_text(text)


def with_substeps(scene, substeps: int):
    """``scene`` (a :class:`galileo_jax.scene.Scene`) with ``substeps`` physics steps a video frame."""
    return scene.model_copy(update={"simulation": scene.simulation.model_copy(update={"substeps": substeps})})


def docstring_markdown(doc: str, first: int, stop: int) -> list[str]:
    """Paragraphs ``first`` to ``stop`` - 1 of a module docstring as Markdown lines, each followed by
    an empty line; a paragraph's ``* `` list items stay items, one a line."""
    lines = []
    for p in doc.split("\n\n")[first:stop]:
        items = p.strip().split("\n* ")
        lines += [" ".join(items[0].split())] + ["* " + " ".join(i.split()) for i in items[1:]] + [""]
    return lines
