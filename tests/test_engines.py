"""The C MuJoCo engine (``mujoco.rollout`` through a host callback) against the MJX engine.

Same scene, same parameters: the velocity profiles agree to 1e-5 m/s while object 1 slides
alone (both integrate the same model; the closed form of the slide is checked on MJX in
test_physics), and to a few mm/s RMS after the impact, where contact resolution differs
slightly between the two solvers (per-rollout RMS difference, 2 s at 30 fps: median 0.0006 m/s,
max 0.027 m/s over 64 draws of one seed; median 0.0043 m/s, max 0.018 m/s over the 16 here;
the tracker's noise is 0.003-0.008 m/s; benchmarks/results/engines.md gives positions).
"""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from galileo_jax.config import ConfigError, FitConfig, resolve_engine
from galileo_jax.effects import resolve_effects
from galileo_jax.errors import GalileoError
from galileo_jax.inference.grad import fit_grad
from galileo_jax.inference.problem import Problem, simulated_observation
from galileo_jax.physics.simulate import PhysParams, make_simulator, steps_needed, velocity_profile
from galileo_jax.scene import load_scene

SCENE = load_scene("scenes/ramp_20.yaml")
FRAMES = jnp.arange(61) / 30.0


def _profiles(engine: str, mass: np.ndarray, friction: np.ndarray) -> np.ndarray:
    sim = make_simulator(SCENE, 30.0, (), engine)
    n = steps_needed(sim, 2.0)
    f = jax.jit(jax.vmap(lambda m, k: velocity_profile(sim, PhysParams(m, k), FRAMES, 0.0, n)))
    return np.asarray(f(mass, friction))


def test_engines_give_the_same_profiles():
    rng = np.random.default_rng(3)
    b = 16
    mass = rng.uniform(0.1, 1.0, (b, 2))
    friction = np.c_[rng.uniform(0.02, 0.3, b), rng.uniform(0.05, 0.8, b)]
    mjx_v, c_v = _profiles("mjx", mass, friction), _profiles("mujoco", mass, friction)
    assert mjx_v.shape == c_v.shape == (b, 4, 60)
    assert np.all(np.isfinite(c_v))
    # object 1 sliding alone (the first 10 frames, before any impact): the same integration
    assert np.max(np.abs(mjx_v[:, 0, :10] - c_v[:, 0, :10])) < 1e-5
    assert np.max(np.abs(c_v[:, 0, 5:10])) > 0.05  # ... and it does slide
    rms = np.sqrt(np.mean((mjx_v - c_v) ** 2, axis=(1, 2)))
    assert np.median(rms) < 0.01 and np.max(rms) < 0.05, rms


def test_c_engine_inside_jit_and_vmap_matches_host_batches():
    """The callback sees one batch per vmapped call, also nested (LM starts x FD points)."""
    truth = PhysParams(jnp.array([0.6, 0.3]), jnp.array([0.2, 0.25]))
    obs = simulated_observation(SCENE, truth, duration=1.5, position_sd=1e-3, seed=0, release_time=0.2)
    c, m = Problem(SCENE, obs, engine="mujoco"), Problem(SCENE, obs)
    assert (c.simulator_engine, m.simulator_engine) == ("mujoco", "mjx")
    z = jax.random.normal(jax.random.PRNGKey(0), (20, c.dim)) * 0.5
    ll_c, ll_m = np.asarray(c.log_likelihood(z)), np.asarray(m.log_likelihood(z))
    assert np.all(np.isfinite(ll_c))
    # MJX skips the steps after the fit window: the same values (one compiled program for both)
    assert int(m.data.live_steps) < m.n_steps
    assert np.array_equal(ll_m, np.asarray(m.jitted("log_likelihood", None)(z, m.whole_data)))
    assert np.median(np.abs(ll_c - ll_m) / np.abs(ll_m)) < 0.02
    res = fit_grad(c, jax.random.PRNGKey(1), n_starts=2, n_screen=32, max_steps=15)
    est = dict(zip(c.names, np.asarray(res.theta)))
    assert abs(est["k1"] - 0.2) < 0.01 and abs(est["k2"] - 0.25) < 0.05
    with pytest.raises(ValueError, match="MJX engine"):
        fit_grad(c, jax.random.PRNGKey(1), n_starts=1, n_screen=4, max_steps=2, jacobian="ad")


def test_c_engine_simulates_a_repeated_rollout_once(monkeypatch):
    """The callback's cache returns exactly the poses of a fresh simulation, simulates each distinct
    rollout of a batch once, and a rollout asked for again not at all (what a finished start of a
    vmapped LM asks for at every later step)."""
    from galileo_jax.physics import simulate_c

    sim = make_simulator(SCENE, 30.0, (), "mujoco")
    n = steps_needed(sim, 1.0)
    rng = np.random.default_rng(5)
    mass, friction = rng.uniform(0.1, 1.0, (3, 2)), np.c_[rng.uniform(0.05, 0.3, 3), rng.uniform(0.05, 0.6, 3)]
    ran = []
    real = simulate_c.rollout_poses_host

    def counting(sim_, m, *args):
        ran.append(len(m))
        return real(sim_, m, *args)

    monkeypatch.setattr(simulate_c, "rollout_poses_host", counting)
    simulate_c.clear_rollout_cache()
    fresh = real(sim, mass, friction, n)
    rows = [0, 1, 0, 2, 1]  # a batch with repeats
    first = simulate_c.cached_rollout_poses(sim, mass[rows], friction[rows], n)
    assert ran == [3] and np.array_equal(first, fresh[rows])
    again = simulate_c.cached_rollout_poses(sim, mass[[2, 0]], friction[[2, 0]], n)
    assert ran == [3] and np.array_equal(again, fresh[[2, 0]])
    other = simulate_c.cached_rollout_poses(sim, mass[:1], friction[:1] + 0.01, n)  # new inputs: simulated
    assert ran == [3, 1] and not np.array_equal(other[0], fresh[0])
    monkeypatch.setattr(simulate_c, "CACHE_ROLLOUTS", 0)  # off: nothing remembered, each distinct row once
    for _ in range(2):
        again = simulate_c.cached_rollout_poses(sim, mass[rows], friction[rows], n)
    assert ran == [3, 1, 3, 3] and np.array_equal(again, fresh[rows])


def test_c_engine_reuses_its_model_copies_with_bit_identical_rollouts(monkeypatch):
    """The models a batch ran on are reused by the next batch (no copy of the compiled model per
    rollout), and every field an earlier batch wrote is restored first: a batch on
    reused models gives exactly the poses of one on fresh copies, also after a batch that wrote
    an effect's field (pair_solref) which the next one leaves alone."""
    import copy as copy_module

    from galileo_jax.physics import simulate_c

    sim = make_simulator(SCENE, 30.0, (), "mujoco")
    n = steps_needed(sim, 1.2)
    rng = np.random.default_rng(11)
    mass, friction = rng.uniform(0.1, 1.0, (4, 2)), np.c_[rng.uniform(0.05, 0.3, 4), rng.uniform(0.05, 0.6, 4)]
    solref = np.repeat(np.asarray(sim.mj_model.pair_solref)[None], 4, axis=0)
    solref[:, :, 1] = 0.2  # bouncy contacts: another outcome at the impact
    copies = []
    real_copy = copy_module.copy
    monkeypatch.setattr(simulate_c.copy, "copy", lambda x: copies.append(1) or real_copy(x))
    simulate_c._POOL.clear()
    first = simulate_c.rollout_poses_host(sim, mass, friction, n)
    assert len(copies) == 4
    bouncy = simulate_c.rollout_poses_host(sim, mass, friction, n, {"pair_solref": solref})
    again = simulate_c.rollout_poses_host(sim, mass[::-1], friction[::-1], n)
    assert len(copies) == 4  # the first batch's models, reused twice
    assert not np.array_equal(bouncy, first)  # the field was written ...
    assert np.array_equal(again, first[::-1])  # ... and restored: as on fresh copies
    simulate_c._POOL.clear()
    assert np.array_equal(simulate_c.rollout_poses_host(sim, mass, friction, n, {"pair_solref": solref}), bouncy)


def test_c_engine_simulates_only_the_fit_window_and_the_whole_video_for_reports(monkeypatch):
    """The fit's rollouts stop at the last frame the likelihood uses (``ProblemData.live_steps``)
    and give the same log-likelihoods as whole rollouts; ``simulate`` still covers the whole video."""
    from galileo_jax.physics import simulate_c

    truth = PhysParams(jnp.array([0.6, 0.3]), jnp.array([0.05, 0.1]))  # still sliding at 2 s
    mask = np.arange(59) < 30  # 2 s at 30 fps; the fit window ends at 1 s
    obs = simulated_observation(SCENE, truth, duration=2.0 - 1 / 30, position_sd=1e-3, seed=2, release_time=0.2,
                                mask=mask)
    c = Problem(SCENE, obs, engine="mujoco")
    live = int(c.data.live_steps)
    need = steps_needed(c.sim, 1.0 - 0.2 + SCENE.simulation.release_window)  # to 1 s from the earliest release
    assert need <= live <= need + 3 and live < c.n_steps / 2
    ran = []
    real = simulate_c.rollout_poses_host

    def counting(sim_, m, f, n_steps, *args):
        ran.append(n_steps)
        return real(sim_, m, f, n_steps, *args)

    monkeypatch.setattr(simulate_c, "rollout_poses_host", counting)
    simulate_c.clear_rollout_cache()
    theta = jnp.array([[0.05, 0.1, 1 / 3, 0.0], [0.15, 0.4, 0.1, -0.03]])
    z = c.space.to_unconstrained(theta)
    ll = np.asarray(c.log_likelihood(z))
    assert ran == [live]
    f = c.jitted("log_likelihood", None)  # the same program on whole rollouts, the batch padded as
    padded = np.concatenate([np.asarray(z), np.repeat(np.asarray(z)[-1:], c.max_batch - 2, axis=0)])
    assert np.array_equal(ll, np.asarray(f(jnp.asarray(padded), c.whole_data))[:2]) and ran[-1] == c.n_steps
    simulate_c.clear_rollout_cache()
    whole = np.asarray(c.simulate(theta[0]))
    assert ran[-1] == c.n_steps and whole.shape == (4, 59)
    fit_window = np.asarray(jax.jit(c.engine.profile_theta)(theta[0], c.data))[:, :59]
    assert np.array_equal(whole[:, :30], fit_window[:, :30])  # the fit window: the same profile
    assert np.abs(whole[0, 45:]).min() > 0.05 and np.all(fit_window[:, 45:] == 0.0)  # after it: held


def test_engine_choice():
    assert resolve_engine(FitConfig()) == "mujoco"  # on a GPU too (engines.md: faster at a fit's batches)
    assert resolve_engine(FitConfig(engine="mjx")) == "mjx"
    assert resolve_engine(FitConfig.model_validate({"grad": {"jacobian": "ad"}})) == "mjx"
    stepped = resolve_effects("velocity_friction")  # friction changing every step: only MJX has it
    assert resolve_engine(FitConfig(), stepped) == "mjx"
    # a force every step with a C form (quadratic drag: MuJoCo's fluid model) stays on C
    assert resolve_engine(FitConfig(), resolve_effects("quadratic_drag")) == "mujoco"
    with pytest.raises(ConfigError, match="derivatives"):
        resolve_engine(FitConfig.model_validate({"engine": "mujoco", "grad": {"jacobian": "ad"}}))
    with pytest.raises(GalileoError, match="--engine mjx"):
        make_simulator(SCENE, 30.0, stepped, "mujoco")
    with pytest.raises(GalileoError, match="unknown engine"):
        make_simulator(SCENE, 30.0, (), "bullet")


def test_each_method_gets_its_own_ensemble_unless_the_settings_name_one():
    """mh smooths its likelihood with a rollout ensemble by default (a random walk mixes badly on
    the rough one), grad and the others do not; ``likelihood.ensemble`` (``fit --ensemble``)
    overrides both; the shipped settings file leaves it to the method."""
    from galileo_jax.config import MH_ENSEMBLE, ensemble_for, load_config

    assert MH_ENSEMBLE > 1
    for cfg in (FitConfig(), load_config(Path(__file__).resolve().parents[1] / "configs" / "fit.yaml")):
        assert [ensemble_for(cfg, m) for m in ("mh", "grad", "cnn", "seed")] == [MH_ENSEMBLE, 1, 1, 1]
    cfg = FitConfig.model_validate({"likelihood": {"ensemble": 2}})
    assert ensemble_for(cfg, "mh") == ensemble_for(cfg, "grad") == 2
    with pytest.raises(ValueError):
        FitConfig.model_validate({"likelihood": {"ensemble": 0}})


def test_c_engine_quadratic_drag_matches_mjx():
    """Quadratic drag is a force every step on MJX and MuJoCo's ellipsoid fluid model on C: the
    same profiles (to 1e-9 m/s while object 1 slides alone, to the engines' usual differences after
    the impact)."""
    drag = resolve_effects("quadratic_drag")
    rng = np.random.default_rng(3)
    b = 16
    mass = rng.uniform(0.1, 1.0, (b, 2))
    friction = np.c_[rng.uniform(0.02, 0.3, b), rng.uniform(0.05, 0.8, b)]
    c = rng.uniform(0.0, 3.0, (b, 1))
    out = {}
    for engine in ("mjx", "mujoco"):
        sim = make_simulator(SCENE, 30.0, drag, engine)
        n = steps_needed(sim, 2.0)
        f = jax.jit(jax.vmap(lambda m, k, e: velocity_profile(sim, PhysParams(m, k, e), FRAMES, 0.0, n)))
        out[engine] = np.asarray(f(mass, friction, c))
    base = _profiles("mujoco", mass, friction)
    assert np.max(np.abs(out["mjx"][:, 0, :10] - out["mujoco"][:, 0, :10])) < 1e-9
    assert np.max(np.abs(base[:, 0, :10] - out["mujoco"][:, 0, :10])) > 1e-3  # ... and the drag acts on C
    rms = np.sqrt(np.mean((out["mjx"] - out["mujoco"]) ** 2, axis=(1, 2)))
    assert np.median(rms) < 0.01 and np.max(rms) < 0.05, rms


def test_c_engine_with_effects_set_once():
    """Effects that change the model or the release velocity (not every step) run on C MuJoCo too."""
    effects = resolve_effects("restitution,initial_push")
    out = {}
    for engine in ("mjx", "mujoco"):
        sim = make_simulator(SCENE, 30.0, effects, engine)
        assert sim.effect_names == ("restitution", "v0")
        n = steps_needed(sim, 2.0)
        params = PhysParams(jnp.array([0.6, 0.3]), jnp.array([0.2, 0.25]), jnp.array([0.8, 0.4]))
        out[engine] = np.asarray(jax.jit(lambda p: velocity_profile(sim, p, FRAMES, 0.0, n))(params))
    assert abs(out["mujoco"][0, 0] - 0.4 * np.cos(SCENE.ramp.angle)) < 0.03  # released at v0 = 0.4 m/s downhill
    assert np.max(np.abs(out["mjx"][0, :10] - out["mujoco"][0, :10])) < 1e-5
    assert np.sqrt(np.mean((out["mjx"] - out["mujoco"]) ** 2)) < 0.01


def test_rollout_ensemble_shifts_object_1_along_its_path_and_smooths_the_profile():
    """``ensemble`` K: each rollout is the mean of K rollouts whose object 1 starts shifted along
    the ramp by offsets spread symmetrically over one physics step of travel at
    ``ENSEMBLE_SPEED``. While object 1 slides alone the ensemble's profile is the plain one
    (sliding is the same wherever it starts on the slope); across the impact it is smoother in
    the parameters: along k1 in steps of 0.0005 the summed SD of the profile's second
    differences falls by a third (measured on the C engine 1.53 -> 0.94 m/s, on MJX 1.57 ->
    1.03). MJX's ensemble agrees with C's as their plain rollouts do."""
    from galileo_jax.physics.simulate import ENSEMBLE_SPEED, ensemble_offsets

    def ensemble_profiles(engine, mass, friction):
        sim = make_simulator(SCENE, 30.0, (), engine, 8)
        n = steps_needed(sim, 2.0)
        f = jax.jit(jax.vmap(lambda m, k: velocity_profile(sim, PhysParams(m, k), FRAMES, 0.0, n)))
        return np.asarray(f(mass, friction)), sim

    k1 = 0.2 + 0.0005 * np.arange(41)
    mass, friction = np.tile([0.6, 0.3], (41, 1)), np.c_[k1, np.full(41, 0.25)]
    plain = _profiles("mujoco", mass, friction)
    ens, sim = ensemble_profiles("mujoco", mass, friction)
    off = np.asarray(ensemble_offsets(sim))
    assert off.shape == (8, 2, 3) and np.all(off[:, 1] == 0.0)
    np.testing.assert_allclose(off.mean(axis=0), 0.0, atol=1e-15)
    along = off[:, 0] @ np.asarray(sim.ctx.downhill)  # all of it along the slope
    np.testing.assert_allclose(np.linalg.norm(off[:, 0], axis=1), np.abs(along), rtol=1e-12)
    assert along.max() - along.min() == pytest.approx(7 / 8 * ENSEMBLE_SPEED * sim.dt)
    assert np.max(np.abs(ens[:, 0, :10] - plain[:, 0, :10])) < 1e-3
    rough = [np.std(np.diff(p, 2, axis=0), axis=0).sum() for p in (plain, ens)]
    assert rough[1] < 0.75 * rough[0], rough
    some = [0, 20, 40]
    ens_mjx, _ = ensemble_profiles("mjx", mass[some], friction[some])
    plain_mjx = _profiles("mjx", mass[some], friction[some])
    assert np.max(np.abs(ens_mjx[:, 0, :10] - plain_mjx[:, 0, :10])) < 1e-9
    assert np.sqrt(np.mean((ens_mjx - ens[some]) ** 2)) < 0.01
    with pytest.raises(GalileoError, match="at least 1"):
        make_simulator(SCENE, 30.0, (), "mujoco", 0)
