"""Writing results: atomic files, package versions, JSON encoding of numpy values."""

from __future__ import annotations

import contextlib
import json
import math
import os
import platform
import tempfile
from importlib import metadata
from pathlib import Path
from typing import Any, Iterator

import numpy as np

#: Packages whose versions go into every result file.
VERSIONED = ("galileo_jax", "jax", "jaxlib", "mujoco", "mujoco-mjx", "optimistix", "numpy", "orbax-checkpoint",
             "opencv-python-headless", "arviz", "flax", "optax")


def package_versions() -> dict[str, str]:
    """Installed versions of the packages that determine a result (plus Python's)."""
    out = {"python": platform.python_version()}
    for name in VERSIONED:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def to_jsonable(obj: Any) -> Any:
    """Convert numpy / JAX scalars and arrays (recursively) to plain JSON values; NaN -> None."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if hasattr(obj, "__array__") and not isinstance(obj, (str, bytes)):
        arr = np.asarray(obj)
        if arr.ndim == 0:
            return to_jsonable(arr.item())
        return [to_jsonable(v) for v in arr.tolist()]
    if isinstance(obj, float):
        return None if math.isnan(obj) or math.isinf(obj) else obj
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    return obj


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path in the same folder; on success it replaces ``path`` atomically.

    If the block raises, the temporary file is removed and an existing ``path`` is untouched.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix, dir=path.parent)
    os.close(fd)
    tmp = Path(tmp)
    try:
        yield tmp
        # mkstemp makes the file private (0600); give the result the user's usual permissions.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_json(path: str | Path, data: dict) -> None:
    """Write ``data`` as indented JSON, atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(to_jsonable(data), indent=2) + "\n")


def write_netcdf(path: str | Path, idata) -> None:
    """Write an ArviZ ``InferenceData`` to ``path`` (netCDF4/HDF5, ``az.from_netcdf`` reads it)
    atomically: an existing file is replaced only once the new one is complete."""
    with atomic_path(path) as tmp:
        idata.to_netcdf(str(tmp))
