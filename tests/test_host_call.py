"""Host calls through XLA's FFI (galileo_jax.physics.host_call): the values of jax.pure_callback,
errors that surface, and programs that JAX's persistent compilation cache keeps."""

import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from galileo_jax.physics.host_call import host_call, stable_name


def test_a_host_call_computes_what_numpy_does_under_jit_and_vmap_in_one_batched_call():
    calls = []

    def fn(x, y):
        calls.append(x.shape)
        return x * 2.0 + y

    def one(x, y):
        return host_call(stable_name("test_affine", 1), fn, jax.ShapeDtypeStruct(x.shape, jnp.float64), x, y)

    xs = np.arange(12.0).reshape(4, 3)
    y = np.array([1.0, -2.0, 0.5])
    got = jax.jit(jax.vmap(one, in_axes=(0, None)))(jnp.asarray(xs), jnp.asarray(y))
    np.testing.assert_array_equal(np.asarray(got), xs * 2.0 + y)
    assert calls == [(4, 3)]  # the batch reaches the host as one call
    lowered = jax.jit(one).lower(xs[0], y).as_text()
    assert stable_name("test_affine", 1) in lowered and "callback" not in lowered  # an FFI call by name


def test_an_error_in_the_host_function_is_raised_with_its_message():
    def fn(x):
        raise ValueError("the rollout blew up")

    f = jax.jit(lambda x: host_call("test_failing_host", fn, jax.ShapeDtypeStruct((2,), jnp.float64), x))
    with pytest.raises(Exception, match="the rollout blew up"):
        np.asarray(f(jnp.zeros(2)))


def test_a_wrong_result_shape_is_an_error_not_a_silent_copy():
    shape = jax.ShapeDtypeStruct((2,), jnp.float64)
    f = jax.jit(lambda x: host_call("test_wrong_shape", lambda a: np.zeros(3), shape, x))
    with pytest.raises(Exception, match="returned shape"):
        np.asarray(f(jnp.zeros(2)))


def test_on_another_backend_a_host_call_is_a_pure_callback_with_the_same_values(monkeypatch):
    # a GPU program cannot call the CPU target: it falls back to jax.pure_callback
    import galileo_jax.physics.host_call as host_call_module

    monkeypatch.setattr(host_call_module.jax, "default_backend", lambda: "gpu")
    shape = jax.ShapeDtypeStruct((3,), jnp.float64)
    f = jax.jit(lambda x: host_call("test_other_backend", np.square, shape, x))
    assert "test_other_backend" not in str(jax.jit(f).lower(np.arange(3.0)).as_text())
    np.testing.assert_array_equal(np.asarray(f(np.arange(3.0))), np.arange(3.0) ** 2)


def test_stable_names_depend_on_every_part_and_nothing_else():
    assert stable_name("p", "scene", 0.01, ("drag",)) == stable_name("p", "scene", 0.01, ("drag",))
    assert stable_name("p", "scene", 0.01, ("drag",)) != stable_name("p", "scene", 0.02, ("drag",))
    assert stable_name("p", "scene", 0.01, ("drag",)) != stable_name("q", "scene", 0.01, ("drag",))


_PROGRAM = textwrap.dedent("""
    import sys
    import jax, jax.numpy as jnp, numpy as np
    from jax import monitoring
    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_compilation_cache_dir", sys.argv[1])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    from galileo_jax.physics.host_call import host_call
    hits = []
    monitoring.register_event_listener(lambda event, **kw: hits.append(event)
                                       if event == "/jax/compilation_cache/cache_hits" else None)
    shape = jax.ShapeDtypeStruct((3,), jnp.float64)
    if sys.argv[2] == "ffi":
        f = jax.jit(lambda x: jnp.sum(host_call("test_cached_square", np.square, shape, x) + 1.0))
    else:
        f = jax.jit(lambda x: jnp.sum(jax.pure_callback(np.square, shape, x) + 1.0))
    value = float(f(np.arange(3.0)))  # a NumPy input: no other program is compiled
    print(value, len(hits))
""")


@pytest.mark.parametrize("kind, cached", [("ffi", True), ("pure_callback", False)])
def test_a_program_with_a_host_call_comes_from_the_persistent_cache_in_the_next_process(tmp_path, kind, cached):
    # pure_callback is the control: JAX never writes its programs to the cache, so every
    # process compiled every C MuJoCo program again
    script = tmp_path / "program.py"
    script.write_text(_PROGRAM)
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    runs = [subprocess.run([sys.executable, str(script), str(tmp_path / "cache"), kind], capture_output=True,
                           text=True, env=env, timeout=300) for _ in range(2)]
    for r in runs:
        assert r.returncode == 0, r.stderr[-2000:]
    (first_value, first_hits), (second_value, second_hits) = (r.stdout.split() for r in runs)
    assert float(first_value) == float(second_value) == 8.0  # 0 + 1 + 4, plus 1 three times
    assert int(first_hits) == 0
    assert (int(second_hits) >= 1) == cached
