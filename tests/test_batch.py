"""Batched fits of several videos of one scene (galileo_jax.inference.batch).

Three short simulated two-box videos (1.5, 1.2 and 1.5 s at 30 fps, 1 mm position noise,
different truths and lengths, so the padding and mask are exercised) on the C MuJoCo engine
(it compiles in seconds; the batched code is the same for MJX), with a small fit (2 of 32
screened starts, 20 LM steps, one polish round):

* the batched fit gives each video the estimate its own ``fit_grad`` gives with the same key;
* in a subprocess with two forced host devices the batched screen, LM and Jacobian
  (:func:`solve_batch`) run sharded over both (the outputs' sharding spans 2 devices) and every
  start's end point agrees with the one-device batched fit's.
"""

import json
import os
import pickle
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from galileo_jax.inference.batch import batch_problems, fit_grad_batch, stack_data
from galileo_jax.inference.grad import fit_grad
from galileo_jax.inference.problem import Problem, simulated_observation
from galileo_jax.physics.simulate import PhysParams
from galileo_jax.scene import scene_from_dict

ROOT = Path(__file__).resolve().parents[1]
SCENE = {
    "name": "ramp_20", "ramp": {"angle_deg": 20, "length": 0.6},
    "objects": [{"shape": "box", "size": [0.08, 0.06, 0.04], "start": 0.45},
                {"shape": "box", "size": [0.08, 0.06, 0.04], "start": 0.15}],
    "camera": {"pixels_per_metre": 1692.9},
    "simulation": {"fit_release": False}}
#: (m1, m2, k1, k2) and duration (s) of each video.
VIDEOS = [((0.6, 0.3, 0.2, 0.25), 1.5), ((0.4, 0.4, 0.15, 0.3), 1.2), ((0.5, 0.2, 0.25, 0.2), 1.5)]
FIT = dict(n_starts=2, n_screen=32, max_steps=20, polish_rounds=1, polish_points=16)

#: Run in a subprocess with two forced CPU devices: the batched screen + LM + Jacobian, sharded.
SHARDED = textwrap.dedent("""
    import json, pickle, sys
    import jax, numpy as np
    sys.path.insert(0, {tests!r})
    from galileo_jax.jaxcache import enable_compilation_cache
    enable_compilation_cache()
    from test_batch import FIT, scene
    from galileo_jax.inference.batch import _pad_videos, batch_problems, solve_batch, stack_data, video_mesh
    from galileo_jax.inference.starts import latin_hypercube_starts
    with open({observations!r}, "rb") as f:  # the parent's videos (simulating them again compiles MJX anew)
        observations = pickle.load(f)
    problems = batch_problems(scene(), observations, engine="mujoco")
    engine, data = stack_data(problems)
    mesh = video_mesh()
    z_cand = engine.space.to_unconstrained(latin_hypercube_starts(problems[0], jax.random.key(0), FIT["n_screen"]))
    out = solve_batch(engine, z_cand, _pad_videos(data, 4), n_starts=FIT["n_starts"], max_steps=FIT["max_steps"],
                      mesh=mesh)
    theta = np.asarray(engine.space.from_unconstrained(out.z_end))
    print(json.dumps({{"devices": len(jax.local_devices()), "mesh": int(mesh.size),
                      "sharding_devices": len(out.cost.sharding.device_set), "spec": str(out.cost.sharding.spec),
                      "theta": theta[:3].tolist(), "cost": np.asarray(out.cost)[:3].tolist()}}))
""")


def scene():
    return scene_from_dict(SCENE)


def observations():
    return [simulated_observation(scene(), PhysParams(jnp.array([m1, m2]), jnp.array([k1, k2])), duration=dur,
                                  position_sd=1e-3, seed=i)
            for i, ((m1, m2, k1, k2), dur) in enumerate(VIDEOS)]


@pytest.fixture(scope="module")
def batched():
    problems = batch_problems(scene(), observations(), engine="mujoco")
    return problems, fit_grad_batch(problems, jax.random.key(0), **FIT)


def test_batched_fit_matches_single_fits(batched):
    problems, results = batched
    assert len(results) == len(VIDEOS) and len({p.likelihood.obs.shape for p in problems}) == 1  # padded to one length
    for obs, res, ((_, _, k1, k2), _) in zip(observations(), results, VIDEOS):
        alone = fit_grad(Problem(scene(), obs, engine="mujoco"), jax.random.key(0), **FIT)
        assert res.names == alone.names
        assert np.allclose(res.theta, alone.theta, atol=1e-4), (res.theta, alone.theta)
        assert res.cost == pytest.approx(alone.cost, rel=1e-6)
        assert np.allclose(res.sd, alone.sd, rtol=1e-3, atol=1e-6)
        assert np.allclose(res.starts_theta0, alone.starts_theta0)  # the same screened starts
        assert abs(res.theta[0] - k1) < 0.01 and abs(res.theta[1] - k2) < 0.05


def test_sharded_over_two_devices_agrees(batched, tmp_path):
    problems, results = batched
    env = dict(os.environ, JAX_PLATFORMS="cpu", XLA_FLAGS="--xla_force_host_platform_device_count=2")
    path = tmp_path / "observations.pkl"
    path.write_bytes(pickle.dumps([p.observation for p in problems]))
    code = SHARDED.format(tests=str(ROOT / "tests"), observations=str(path))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300,
                          cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["devices"] == 2 and out["mesh"] == 2
    assert out["sharding_devices"] == 2 and "videos" in out["spec"]
    for theta, cost, res in zip(out["theta"], out["cost"], results):  # every start's LM end point
        assert np.allclose(theta, res.starts_theta, atol=1e-4) and np.allclose(cost, res.starts_cost, rtol=1e-6)


def test_batch_rejects_mixed_videos(batched):
    problems, _ = batched
    with pytest.raises(ValueError, match="padded length"):
        stack_data([Problem(scene(), o, engine="mujoco") for o in observations()[:2]])  # 1.5 s and 1.2 s, unpadded
    other = scene_from_dict({**SCENE, "ramp": {"angle_deg": 10, "length": 0.6}})
    with pytest.raises(ValueError, match="one scene"):
        stack_data([problems[0], Problem(other, observations()[0], engine="mujoco")])
    with pytest.raises(ValueError, match="at least one video"):
        fit_grad_batch([], jax.random.key(0))
    with pytest.raises(ValueError, match="n_starts"):
        fit_grad_batch(problems, jax.random.key(0), n_starts=0)
