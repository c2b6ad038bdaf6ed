"""The simulator against closed forms (issue 2, "What it must show" 1).

* Sliding down a ramp: a = g (sin theta - k cos theta) along the slope (NOTES.md, dissertation
  3.1.1), for k in {0.1, 0.2, 0.3} on a 20 degree ramp, within 2%.
* No sliding when k > tan theta.
* On the floor an object decelerates at k g.
* Momentum is conserved across the collision within 5%.
* k is the *effective* friction: the ramp and floor geoms keep MuJoCo's default friction 1.0,
  which MuJoCo's default max-combination would use (then nothing slides at 20 degrees); the
  explicit contact pairs make the object's own k the sliding friction.
* Only the mass ratio matters: scaling both masses leaves the profile unchanged.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from galileo_jax.physics.simulate import PhysParams, make_simulator, rollout, steps_needed, velocity_profile
from galileo_jax.scene import scene_from_dict

G = 9.81
THETA = math.radians(20.0)


def _one_object_scene(angle_deg=20.0):
    return scene_from_dict({
        "ramp": {"angle_deg": angle_deg, "length": 2.0},
        "objects": [{"shape": "box", "size": [0.08, 0.06, 0.04], "start": 1.9}],
        "camera": {"pixels_per_metre": 500},
    })


def _two_object_scene():
    return scene_from_dict({
        "ramp": {"angle_deg": 20.0, "length": 0.6},
        "objects": [
            {"shape": "box", "size": [0.08, 0.06, 0.04], "start": 0.4},
            {"shape": "box", "size": [0.08, 0.06, 0.04], "start": 0.15},
        ],
        "camera": {"pixels_per_metre": 500},
    })


@pytest.fixture(scope="module")
def one_object():
    sim = make_simulator(_one_object_scene(), fps=30.0)
    n = steps_needed(sim, 1.0)
    fn = jax.jit(jax.vmap(lambda p: rollout(sim, p, n).pose))
    return sim, fn


@pytest.fixture(scope="module")
def two_object():
    sim = make_simulator(_two_object_scene(), fps=30.0)
    n = steps_needed(sim, 2.5)
    fn = jax.jit(jax.vmap(lambda p: rollout(sim, p, n).pose))
    return sim, fn


def _along_slope(pose):
    """Distance travelled down the slope (m) from (steps, 3) poses of one object."""
    d = pose[:, :2] - pose[0, :2]
    return d[:, 0] * math.cos(THETA) - d[:, 1] * math.sin(THETA)


def test_ramp_acceleration_matches_closed_form(one_object):
    sim, fn = one_object
    # The ramp and floor geoms keep MuJoCo's default friction 1.0; with MuJoCo's default
    # max-combination nothing would slide at 20 degrees (1.0 > tan 20 = 0.36). The contact
    # pairs carry the object's own k, so the closed form below holds only if k is effective.
    m = sim.mj_model
    for name in ("ramp", "floor"):
        assert m.geom_friction[m.geom(name).id, 0] == 1.0
    ks = np.array([0.1, 0.2, 0.3, 0.45])
    poses = np.asarray(fn(PhysParams(jnp.full((4, 1), 0.5), jnp.asarray(ks)[:, None])))
    t = np.arange(poses.shape[1]) * sim.dt
    sel = (t > 0.2) & (t < 0.9)
    for k, pose in zip(ks[:3], poses[:3]):
        s = _along_slope(pose[:, 0])
        a = 2 * np.polyfit(t[sel], s[sel], 2)[0]
        expected = G * (math.sin(THETA) - k * math.cos(THETA))
        assert abs(a / expected - 1) < 0.02, (k, a, expected)
    # k = 0.45 > tan(20 deg) = 0.364: the object must not slide. MuJoCo's soft friction
    # lets it creep (measured ~2 mm/s, the same at k = 1.0), against 0.6 m/s after 1 s of sliding at k = 0.3.
    s = _along_slope(poses[3, :, 0])
    creep = (s[-1] - s[len(s) // 2]) / (t[-1] - t[len(s) // 2])
    sliding = np.diff(_along_slope(poses[2, :, 0]))[-1] / sim.dt
    assert abs(creep) < 5e-3 and sliding > 0.5, (creep, sliding)


def test_mass_scale_does_not_change_profile(two_object):
    sim, fn = two_object
    k = jnp.array([[0.15, 0.25]] * 3)
    m = jnp.array([[0.6, 0.3], [0.06, 0.03], [0.3, 0.3]])
    poses = np.asarray(fn(PhysParams(m, k)))
    same = np.abs(poses[0, :, :, :2] - poses[1, :, :, :2]).max()
    different = np.abs(poses[0, :, 1, :2] - poses[2, :, 1, :2]).max()
    # equal phi: the same motion up to float64 rounding (measured 2.2e-8 m; float32 rollouts
    # break the invariance by millimetres, the reason the simulator runs in float64)
    assert same < 1e-6, same
    assert different > 2e-2, different  # different phi: object 2 moves differently


def _collision_step(pose2):
    moving = np.abs(pose2[:, 0] - pose2[0, 0]) > 1e-4
    assert moving.any(), "object 2 was never hit"
    return int(np.argmax(moving))


def test_collision_conserves_momentum_and_floor_deceleration(two_object):
    sim, fn = two_object
    m1, m2, k1, k2 = 0.6, 0.3, 0.15, 0.25
    pose = np.asarray(fn(PhysParams(jnp.array([[m1, m2]]), jnp.array([[k1, k2]]))))[0]
    v = np.diff(pose[:, :, 0], axis=0) / sim.dt  # (steps, 2) horizontal velocities
    i = _collision_step(pose[:, 1])
    before = m1 * v[i - 3, 0]
    after_idx = i + 12  # 50 ms later: the impact is over
    after = m1 * v[after_idx, 0] + m2 * v[after_idx, 1]
    # Floor friction acts on both objects during those 15 steps; add its impulse back.
    friction_impulse = G * (k1 * m1 + k2 * m2) * 15 * sim.dt
    assert abs((after + friction_impulse) / before - 1) < 0.05, (before, after, friction_impulse)
    assert v[after_idx, 1] > 0.2  # object 2 was really pushed
    # After the impact, object 2 slides on the floor and decelerates at k2 g.
    t = np.arange(len(v)) * sim.dt
    sel = (t > t[after_idx] + 0.02) & (v[:, 1] > 0.05)
    decel = -np.polyfit(t[sel], v[sel, 1], 1)[0]
    assert abs(decel / (k2 * G) - 1) < 0.05, decel


def test_velocity_profile_shape_and_forward_derivatives_are_finite(one_object):
    sim, _ = one_object
    frame_times = jnp.arange(16) / 30.0
    n = steps_needed(sim, 0.6)

    def f(k):
        return velocity_profile(sim, PhysParams(jnp.array([0.5]), k[None]), frame_times, 0.0, n)

    prof = f(jnp.array(0.2))
    assert prof.shape == (2, 15)
    jac = jax.jacfwd(f)(jnp.array(0.2))
    assert np.isfinite(np.asarray(jac)).all()
    # On the ramp, v_x(t) = a cos(theta) t with da/dk = -g cos(theta): check the slope of dV/dk.
    t_mid = (frame_times[:-1] + frame_times[1:]) / 2
    expected = -G * math.cos(THETA) ** 2 * np.asarray(t_mid)
    sel = np.asarray(t_mid) > 0.1
    rel = np.abs(np.asarray(jac[0])[sel] / expected[sel] - 1)
    assert rel.max() < 0.05, rel


def test_scenes_of_one_structure_share_compiled_programs():
    """A new ramp angle, ramp length, start position and box size (every user's video is its own
    scene) reuse the programs compiled for another scene, and each scene is still simulated with
    its own numbers: the slide on a 30 degree ramp through the 20 degree scene's program matches
    g (sin 30 - k cos 30), and the initial push (whose release delay reads the ramp angle) gives
    exactly what the new scene's own, separately compiled program gives."""
    from galileo_jax.inference.problem import Problem, simulated_observation

    a = _one_object_scene(20.0)
    b = scene_from_dict({"name": "another ramp", "ramp": {"angle_deg": 30.0, "length": 1.6},
                         "objects": [{"shape": "box", "size": [0.07, 0.06, 0.05], "start": 1.5}],
                         "camera": {"pixels_per_metre": 500}})
    truth = PhysParams(jnp.asarray([1.0]), jnp.asarray([0.2]))
    for effects in ((), ("initial_push",)):
        pa, pb = (Problem(s, simulated_observation(s, truth, duration=0.8, release_time=0.1, effects=()),
                          effects=effects) for s in (a, b))
        assert pa.static_key == pb.static_key and pa.sim is not pb.sim
        theta = np.array([0.2 if n == "k1" else 0.3 if n == "v0" else 0.0 for n in pb.names])
        pa.simulate(theta)
        prof = np.asarray(pb.simulate(theta))
        assert pb.jitted("simulate", None)._cache_size() == 1  # one program for both scenes
        eng, own = pb.engine, pb.whole_data._replace(physics=None)  # b's numbers as constants of its own program
        expected = np.asarray(jax.jit(lambda t: eng.profile_theta(t, own))(theta))[..., :pb.n_samples]
        np.testing.assert_allclose(prof, expected, rtol=0, atol=1e-10)
        if not effects:
            speed = np.hypot(prof[0], prof[1])
            t = pb.observation.frame_times[1:] - 0.5 / 30.0
            sel = (t > 0.2) & (t < 0.7)
            slope = np.polyfit(t[sel], speed[sel], 1)[0]
            expected_a = G * (math.sin(math.radians(30.0)) - 0.2 * math.cos(math.radians(30.0)))
            assert abs(slope / expected_a - 1) < 0.02, (slope, expected_a)


def _step_jaxprs(closed) -> list:
    """The jaxprs of every call of the jitted ``mjx.step`` (a ``jit`` equation named "step") in
    a traced program, nested programs (scan, cond, ...) included."""
    found = []

    def walk(jaxpr):
        for eqn in jaxpr.eqns:
            if eqn.primitive.name in ("pjit", "jit") and eqn.params.get("name") == "step":
                found.append(eqn.params["jaxpr"])
            for value in eqn.params.values():
                for sub in value if isinstance(value, (list, tuple)) else [value]:
                    inner = getattr(sub, "jaxpr", sub)
                    if hasattr(inner, "eqns"):
                        walk(inner)

    walk(closed.jaxpr)
    return found


def test_programs_reuse_the_traced_mjx_step(one_object):
    """Two different programs that roll out MJX with the same batching call ``mjx.step`` through
    ``simulate._step`` and share its traced form (the same jaxpr object): a process traces the
    step once per batching, not once per program (``docs/simulation.md``)."""
    sim, _ = one_object
    p = PhysParams(jnp.ones((2, 1)), jnp.full((2, 1), 0.2))
    a = _step_jaxprs(jax.make_jaxpr(jax.vmap(lambda q: rollout(sim, q, 5).pose))(p))
    b = _step_jaxprs(jax.make_jaxpr(jax.vmap(lambda q: 2.0 * rollout(sim, q, 5).pose[-1]))(p))
    assert len(a) == 1 and len(b) == 1
    assert a[0] is b[0]
