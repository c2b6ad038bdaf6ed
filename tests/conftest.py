"""Test configuration: JAX on CPU with the persistent compilation cache."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("JAX_PLATFORMS", "cpu")

from galileo_jax.jaxcache import enable_compilation_cache  # noqa: E402

enable_compilation_cache()


import pytest  # noqa: E402


@pytest.fixture(autouse=True, scope="module")
def _free_compiled_programs():
    """Drop the compiled programs after each test module: every XLA:CPU executable holds
    hundreds of memory mappings, and a whole session's worth exceeds Linux's default
    vm.max_map_count (65530), which aborts the process (galileo_jax.inference.problem.clear_caches)."""
    yield
    from galileo_jax.inference.problem import clear_caches

    clear_caches()
