"""Test configuration: JAX on CPU with the persistent compilation cache."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("JAX_PLATFORMS", "cpu")

from galileo_jax.jaxcache import enable_compilation_cache  # noqa: E402

enable_compilation_cache()
