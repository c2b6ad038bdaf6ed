"""JAX's persistent compilation cache, so a second run does not recompile.

The cache lives in ``$GALILEO_JAX_CACHE`` or ``~/.cache/galileo_jax/jax``. Measured on the
issue-2 machine: the persistent cache cut a whole second ``fit`` process' compile time
(see the issue note for the numbers).
"""

from __future__ import annotations

import os
from pathlib import Path

import jax


def cache_dir() -> Path:
    """Directory of the persistent compilation cache."""
    default = Path.home() / ".cache" / "galileo_jax" / "jax"
    return Path(os.environ.get("GALILEO_JAX_CACHE", default))


def enable_compilation_cache() -> Path:
    """Turn on JAX's persistent compilation cache (idempotent); returns its directory."""
    path = cache_dir()
    path.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(path))
    # Every program, however fast to compile: README command 1 compiles ~150 small programs
    # (0.03 s each, 4 s in all) besides its big ones; stored, its warm inference took 16 s
    # instead of 21-24 s (cache 0.8 MB). The C MuJoCo engine's programs are stored too: their
    # rollouts are an FFI call, not a Python host callback, which JAX never stores
    # (galileo_jax.physics.host_call).
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path
