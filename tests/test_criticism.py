"""Model criticism (galileo_jax.criticism.residuals) and its figures, on synthetic arrays (no MuJoCo).

The synthetic "fit": a hand-made two-box trajectory (object 1 accelerates down a 20 degree
ramp, crosses the foot at x = 0, hits object 2 on the floor; object 2 slides and stops). The
observation is that trajectory plus noise drawn exactly from the likelihood's noise model:
independent position errors (SD sd_p, differenced -> MA(1)) plus a white velocity floor
(SD sd_model), i.e. Cov = sd_p^2 D D^T + sd_model^2 I.
"""

from __future__ import annotations

import itertools
import json
import math
import re

import numpy as np
import pytest

from galileo_jax.criticism import noise as CN
from galileo_jax.criticism import phases as CP
from galileo_jax.criticism import adequacy as A
from galileo_jax.criticism import residuals as C
from galileo_jax.criticism import structure as CS
from galileo_jax.observation import Observation, profile_from_positions
from galileo_jax.report.figures import model_comparison_figure, residual_figure

THETA = math.radians(20.0)
FPS = 30.0
RELEASE = 0.2
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def poses_at(t: np.ndarray, scale2: float = 1.0) -> np.ndarray:
    """(N, 2, 3) poses (x, z, pitch) of the hand-made trajectory; object 2's slide scaled by ``scale2``."""
    a, x0, c, dec, x_hit = 2.0, -0.6, 0.05, 3.0, 0.1
    t_foot = math.sqrt(2 * (-x0 / math.cos(THETA)) / a)
    v_foot = a * t_foot
    t_hit = t_foot + (v_foot - math.sqrt(v_foot**2 - 2 * dec * x_hit)) / dec
    v_hit = v_foot - dec * (t_hit - t_foot)
    out = np.zeros((t.size, 2, 3))
    for k, tk in enumerate(np.asarray(t) - RELEASE):
        if tk <= 0:
            x1 = x0
        elif tk <= t_foot:
            x1 = x0 + 0.5 * a * tk**2 * math.cos(THETA)
        elif tk <= t_hit:
            x1 = v_foot * (tk - t_foot) - 0.5 * dec * (tk - t_foot) ** 2
        else:
            x1 = x_hit
        u = min(max(tk - t_hit, 0.0), v_hit / dec)
        x2 = 0.2 + scale2 * (v_hit * u - 0.5 * dec * u**2)
        out[k, 0] = (x1, c + max(0.0, -x1) * math.tan(THETA), -THETA if x1 < 0 else 0.0)
        out[k, 1] = (x2, c, 0.0)
    return out


def synthetic(seed: int, sd_p: float = 0.001, sd_model: float = 0.05, scale2: float = 1.0, n_frames: int = 61):
    """(observation, simulated profile, simulated poses) with noise from the model's covariance."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames) / FPS
    sim_poses = poses_at(t)
    true_pos = poses_at(t, scale2)[..., :2]
    sim = profile_from_positions(sim_poses[..., :2], t)
    pos = true_pos + rng.normal(0.0, sd_p, true_pos.shape)
    profile = profile_from_positions(pos, t) + rng.normal(0.0, sd_model, sim.shape)
    mask = t[1:] > 0.1
    obs = Observation(t, pos, np.zeros_like(pos), profile, np.full(4, sd_p), mask, RELEASE, FPS, np.ones(2, bool))
    return obs, sim, sim_poses


# ---------------------------------------------------------------------------- calibration
N_SEEDS = 200


@pytest.fixture(scope="module")
def noise_runs():
    """Criticism of N_SEEDS pure-noise observations with strongly correlated residuals.

    sd_p = 2 mm at 30 fps gives a velocity SD of 0.085 m/s from tracking, so with the 0.05 m/s
    floor the expected lag-1 correlation is -0.37: plain iid formulas would be off.
    """
    out = []
    for seed in range(N_SEEDS):
        obs, sim, poses = synthetic(seed, sd_p=0.002, sd_model=0.05)
        out.append(C.summarize(obs, sim, poses, sd_model=0.05))
    return out


def test_pure_noise_is_called_noise(noise_runs):
    structured = [not s["looks_like_noise"] for s in noise_runs]
    rate = float(np.mean(structured))
    print(f"false-positive rate of the verdict over {N_SEEDS} noise seeds: {rate:.3f}")
    assert rate <= 0.05
    for s, flag in zip(noise_runs, structured):
        assert ("look like noise" in s["verdict"]) == (not flag)
        assert flag == any(r["structured"] for r in s["table"])


def test_each_test_is_calibrated_under_the_noise_model(noise_runs):
    """Raw p-values of every test: P(p < 0.05) about 0.05 or less (runs test: conservative).

    Using the Kolmogorov law (kstwobign) for the undemeaned CUSUM would give ~0.27 here and a
    47% false-alarm rate of the verdict.
    """
    rhos = {r["rho_expected"] for s in noise_runs for r in s["table"] if not r["noise_reestimated"]}
    assert all(-0.40 < rho < -0.33 for rho in rhos)  # the strongly correlated regime
    # the tracker's (here: the true) noise SD is replaced in about NOISE_LEVEL of the traces
    reest = [v["reestimated"] for s in noise_runs for v in s["tracking_noise_m"].values()]
    assert len(reest) == 4 * N_SEEDS and np.mean(reest) <= 2.5 * CN.NOISE_LEVEL
    for test in CS.TESTS:
        p = np.array([r[f"p_{test}"] for s in noise_runs for r in s["table"] if r[f"p_{test}"] is not None])
        assert p.size > 1000
        frac = float(np.mean(p < 0.05))
        print(f"{test}: P(p < 0.05) = {frac:.3f} over {p.size} rows")
        # at most nominal (+ ~3 binomial SDs); plain chi2(n) ignoring rho gives ~0.067 here
        assert frac <= 0.06, (test, frac)
        # the approximate tests are not grossly conservative either (lag-1 with sqrt(n) gives ~0.024)
        low = {"runs": 0.0, "lag1": 0.035, "cusum": 0.02, "chi2": 0.035}[test]
        assert frac >= low, (test, frac)
    # the rows of the table are those promised: every phase with >= 3 samples and "all"
    phases = {(r["trace"], r["phase"]) for r in noise_runs[0]["table"]}
    assert ("object 1 x", "ramp") in phases and ("object 2 x", "floor") in phases
    assert ("object 2 x", "all") in phases and ("object 1 x", "floor") not in phases  # 2 samples only


# ---------------------------------------------------------------------------- detection
@pytest.mark.parametrize("seed", [0, 1])
def test_object_2_travelling_three_times_farther_is_found(seed):
    obs, sim, poses = synthetic(seed, scale2=3.0)
    out = C.summarize(obs, sim, poses, sd_model=0.05)
    rows = {(r["trace"], r["phase"]): r for r in out["table"]}
    floor = rows[("object 2 x", "floor")]
    assert floor["structured"] and not out["looks_like_noise"]
    assert 2.6 < floor["obs_displacement"] / floor["sim_displacement"] < 3.4
    assert not rows[("object 1 x", "ramp")]["structured"]  # the verdict must not blame the ramp
    v = out["verdict"]
    assert v.startswith("The model fails on the floor: object 2 travels ") and "farther" in v
    ratio = float(re.search(r"travels ([0-9.]+)x farther", v).group(1))
    assert 2.6 < ratio < 3.4
    assert "residuals are structured" in v and "\n" not in v


def test_smooth_unbiased_residuals_are_found_by_the_autocorrelation_test():
    """A slow wiggle with zero mean and about the noise's size: the lag-1 test sees it.

    (The runs test does not here: with sd_model = 0 the residuals have lag-1 correlation -1/2,
    which makes runs frequent, so that test is very conservative; see the module docstring.)
    """
    obs, sim, _ = synthetic(3, sd_p=0.001, sd_model=0.0)
    k = np.arange(obs.profile.shape[1])
    wiggle = 0.03 * np.sin(2 * np.pi * k / 12.0)  # m/s, about the noise SD
    obs = obs._replace(profile=obs.profile + wiggle[None, :])
    table = C.residual_table(obs, sim, sd_model=0.0)
    row = next(r for r in table if r.trace == "object 1 x" and r.phase == CP.ALL)
    assert row.structured and row.p_lag1 < 1e-3 and row.rho_hat > row.rho_expected + 0.3
    assert row.p_cusum > 0.01  # no bias to find


# ---------------------------------------------------------------------------- phases
def test_phases_of_a_hand_made_trajectory():
    """10 fps, release at 0.25 s, object 1 at 0.5 m/s from x = -0.52 (foot at t = 1.29 s) to
    x = 0.3 (t = 1.89 s); object 2 pushed from x = 0.4 at 0.5 m/s until t = 2.49 s."""
    t = np.arange(31) / 10.0
    poses = np.zeros((31, 2, 3))
    x1 = np.clip(-0.52 + 0.5 * (t - 0.25), -0.52, 0.3)
    x2 = np.clip(0.4 + 0.5 * (t - 1.89), 0.4, 0.7)
    poses[:, 0, 0], poses[:, 0, 1] = x1, 0.05 + np.maximum(-x1, 0) * math.tan(THETA)
    poses[:, 1, 0], poses[:, 1, 1] = x2, 0.05
    ph = CP.motion_phases(poses, t, 0.25, 2, rest_speed=0.02, collision_halfwidth=1)
    assert ph.shape == (2, 30)
    expect1 = ["before_release"] * 2 + ["ramp"] * 11 + ["floor"] * 4 + ["collision"] * 3 + ["rest"] * 10
    expect2 = ["before_release"] * 2 + ["rest"] * 15 + ["collision"] * 3 + ["floor"] * 5 + ["rest"] * 5
    assert ph[0].tolist() == expect1
    assert ph[1].tolist() == expect2
    assert CP.impact_sample(poses, t, 0.25) == 18
    # default half-width 2: five collision samples, centred on the impact, for both objects
    ph2 = CP.motion_phases(poses, t, 0.25, 2)
    assert np.flatnonzero(ph2[0] == "collision").tolist() == [16, 17, 18, 19, 20]
    assert (ph2[0] == "collision").tolist() == (ph2[1] == "collision").tolist()
    # one object: no collision phase
    ph1 = CP.motion_phases(poses[:, :1], t, 0.25, 1)
    assert "collision" not in ph1 and ph1[0, 17] == "floor" and ph1[0, 25] == "rest"
    # slow creep below rest_speed is "rest"
    creep = poses.copy()
    creep[:, 0, 0] = -0.52 + 0.01 * np.maximum(t - 0.25, 0)
    creep[:, 0, 1] = 0.05 - creep[:, 0, 0] * math.tan(THETA)
    assert set(CP.motion_phases(creep[:, :1], t, 0.25, 1)[0, 2:]) == {"rest"}
    assert set(CP.PHASES) >= set(ph.ravel()) and CP.PHASES[0] == "before_release"
    spans = CP.phase_spans(ph, (t[1:] + t[:-1]) / 2)
    assert [s["phase"] for s in spans[0]] == ["before_release", "ramp", "floor", "collision", "rest"]
    assert spans[0][1]["first"] == 2 and spans[0][1]["last"] == 12
    assert spans[0][1]["start"] == pytest.approx(0.2) and spans[0][1]["end"] == pytest.approx(1.3)


def test_phases_reject_bad_shapes():
    with pytest.raises(ValueError, match="poses"):
        CP.motion_phases(np.zeros((5, 2, 3)), np.arange(5.0), 0.0, 1)
    with pytest.raises(ValueError, match="frame_times"):
        CP.motion_phases(np.zeros((5, 1, 3)), np.arange(4.0), 0.0, 1)


# ---------------------------------------------------------------------------- building blocks
def test_noise_model_numbers():
    obs, sim, _ = synthetic(0, sd_p=0.001, sd_model=0.05)
    vsd = math.sqrt(2) * 0.001 * FPS
    assert CN.residual_sd(obs, 0.05) == pytest.approx(np.full(4, math.hypot(vsd, 0.05)))
    assert CN.expected_lag1(obs, 0.05) == pytest.approx(np.full(4, -0.001**2 * FPS**2 / (vsd**2 + 0.05**2)))
    assert CN.expected_lag1(obs, 0.0) == pytest.approx(np.full(4, -0.5))
    z = CN.standardised_residuals(obs, sim, 0.05)
    assert z == pytest.approx((obs.profile - sim) / math.hypot(vsd, 0.05))
    assert CN.noise_floor(obs) == pytest.approx(vsd)


def test_runs_test_matches_enumeration():
    signs = np.array([1, 1, -1, 1, -1, -1, -1, 1, 1, -1.0])
    r_obs = 1 + int(np.sum(signs[1:] != signs[:-1]))
    counts = []
    for pos in itertools.combinations(range(10), 5):
        s = -np.ones(10)
        s[list(pos)] = 1
        counts.append(1 + int(np.sum(s[1:] != s[:-1])) <= r_obs)
    assert CS.runs_test(signs * 0.7) == pytest.approx(np.mean(counts))
    assert CS.runs_test(np.array([1.0, 1, 1, -1, -1, -1])) == pytest.approx(2 / 20)  # 2 of C(6,3) have 2 runs
    assert CS.runs_test(np.ones(8)) == 1.0
    assert CS.runs_test(np.r_[np.ones(10), -np.ones(10)]) == pytest.approx(2 / math.comb(20, 10))


def test_sup_brownian_tail():
    # 95% quantile of sup_[0,1] |W| is 2.2414 (e.g. Borodin & Salminen); the two series agree at x = 1
    assert CS.sup_brownian_sf(2.2414) == pytest.approx(0.05, abs=2e-4)
    assert CS.sup_brownian_sf(1.0 - 1e-9) == pytest.approx(CS.sup_brownian_sf(1.0 + 1e-9), abs=1e-6)
    assert CS.sup_brownian_sf(0.0) == 1.0 and CS.sup_brownian_sf(8.0) < 1e-14


def glitchy(seed: int, scale2: float = 1.0, n_glitches: int = 5, size: float = 6.0):
    """``synthetic`` with ``n_glitches`` single-frame tracking glitches of +-``size`` x sd_p on
    object 1's x track while it slides (frames 8-40), the tracker's SD still the Gaussian core's."""
    obs, sim, poses = synthetic(seed, sd_p=0.001, sd_model=0.05, scale2=scale2)
    rng = np.random.default_rng(100 + seed)
    frames = rng.choice(np.arange(8, 41, 3), n_glitches, replace=False)  # isolated frames
    pos = obs.positions.copy()
    pos[frames, 0, 0] += rng.choice([-1.0, 1.0], n_glitches) * size * 0.001
    profile = obs.profile.copy()
    profile[0] += profile_from_positions(pos, obs.frame_times)[0] - profile_from_positions(obs.positions, obs.frame_times)[0]
    return obs._replace(positions=pos, profile=profile), sim, poses


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_tracking_glitches_are_measured_as_noise_not_blamed_on_the_model(seed):
    """The right model, a tracker whose noise has heavy tails (five 6-SD glitches in 61 frames)
    and whose SD is the Gaussian core's (as the robust tracker estimate is): the size test
    against that SD calls the residuals structured; against the SD measured from the residual
    track (:func:`tracking_noise`) they look like noise, and the verdict says which SD it used.
    With the same glitches a wrong model (object 2 slides 3x farther) is still found."""
    obs, sim, poses = glitchy(seed)
    kw = dict(sd_model=0.05, phases=CP.motion_phases(poses, obs.frame_times, obs.release_time, 2))
    plain = C.residual_table(obs, sim, reestimate_noise=False, **kw)
    assert any(r.structured for r in plain if r.trace == "object 1 x")
    noise = CN.tracking_noise(obs, sim, 0.05)
    assert noise["reestimated"][0] and not noise["reestimated"][1:].any()
    assert 1.5 < noise["used"][0] / obs.position_sd[0] < 3.5  # sqrt(1 + 5 * 36 / 61) ~ 2 in expectation
    out = C.summarize(obs, sim, poses, sd_model=0.05)
    assert out["looks_like_noise"], out["verdict"]
    assert "measured from the residual track" in out["verdict"] and "object 1 x" in out["verdict"]
    assert out["tracking_noise_m"]["object 1 x"]["reestimated"]
    assert out["tracking_noise_m"]["object 1 x"]["tracker"] == pytest.approx(0.001)
    np.testing.assert_allclose(C.tested_position_sd(out, obs), noise["used"])  # what the report's figure uses

    wrong = C.summarize(*glitchy(seed, scale2=3.0), sd_model=0.05)
    assert not wrong["looks_like_noise"]
    assert wrong["verdict"].startswith("The model fails on the floor: object 2 travels ")
    # a smooth misfit does not pass for tracking noise: object 2's SD is the tracker's
    assert not wrong["tracking_noise_m"]["object 2 x"]["reestimated"]


def test_a_mistimed_impact_does_not_pass_for_tracking_noise(monkeypatch):
    """The simulation one frame early (release, ramp's foot and impact): the third differences
    near its changes of motion are left out of the residual track (SIM_EVENT_JUMP), so every
    trace keeps the tracker's SD and the verdict blames the model; with them kept, the kinks
    would pass for tracking noise of 2-4x the tracker's SD."""
    obs, _, _ = synthetic(0)
    t = obs.frame_times
    poses = poses_at(t + 1.0 / FPS)
    early = profile_from_positions(poses[..., :2], t)
    noise = CN.tracking_noise(obs, early, 0.05)
    assert not noise["reestimated"].any()
    out = C.summarize(obs, early, poses, sd_model=0.05)
    assert not out["looks_like_noise"] and "measured from the residual track" not in out["verdict"]
    monkeypatch.setattr(CN, "SIM_EVENT_JUMP", 1e9)
    assert CN.tracking_noise(obs, early, 0.05)["reestimated"][[0, 2]].all()


def row(**kw) -> C.ResidualRow:
    base = {"trace": "object 1 x", "object": 1, "axis": "x", "phase": "ramp", "n": 20, "rms_z": 1.0, "mean_z": 0.0,
            "rmse": 0.05, "rmse_expected": 0.05, "mean_offset": 0.0, "sim_mean_velocity": 1.0,
            "obs_displacement": 0.5, "sim_displacement": 0.5, "rho_expected": -0.2, "rho_hat": -0.2, "cusum": 0.5,
            "chi2": 20.0, "p_runs": 0.5, "p_lag1": 0.5, "p_cusum": 0.5, "p_chi2": 0.5, "p_min": 0.5,
            "p_adjusted": 1.0, "structured": False}
    base.update(kw)
    return C.ResidualRow(**base)


def test_verdict_phrasing():
    noise = [row(p_adjusted=0.2), row(phase="all", p_adjusted=0.9)]
    assert C.verdict(noise) == "The residuals look like noise: no phase shows structure (smallest adjusted p = 0.2)."
    fast = row(structured=True, p_adjusted=1e-6, p_cusum=1e-9, p_min=1e-9, obs_displacement=0.105,
               sim_displacement=0.1, mean_offset=0.12)
    assert C.verdict(noise + [fast]) == ("The model fails on the ramp: object 1 is faster than simulated by 0.12 m/s "
                                         "on average; residuals are structured (CUSUM p = 1e-9).")
    coll = row(trace="object 2 x", object=2, phase="collision", structured=True, p_adjusted=1e-3, p_chi2=1e-5,
               p_min=1e-5, obs_displacement=0.06, sim_displacement=0.02)
    v = C.verdict([coll])
    assert v.startswith("The model fails after the collision: object 2 travels 3.0x farther than simulated "
                        "(0.06 m vs 0.02 m)") and "chi-square p = 1e-5" in v
    short = row(structured=True, p_adjusted=1e-3, p_min=1e-5, p_runs=1e-5, obs_displacement=0.2, sim_displacement=0.8)
    assert "travels only 0.25x as far as simulated" in C.verdict([short])
    # near 1 the ratio is said in percent (a foreign render's base fit: "1.0x farther" hid 2.3%)
    near = row(structured=True, p_adjusted=1e-3, p_min=1e-5, p_runs=1e-5, obs_displacement=1.33, sim_displacement=1.30)
    assert "object 1 travels 2.3% farther than simulated (1.33 m vs 1.30 m)" in C.verdict([near])
    under = row(structured=True, p_adjusted=1e-3, p_min=1e-5, p_runs=1e-5, obs_displacement=1.2, sim_displacement=1.3)
    assert "object 1 falls 7.7% short of the simulated distance (1.20 m vs 1.30 m)" in C.verdict([under])
    # an x-trace phase row is preferred to a y trace or "all", even with a larger p
    y_row = row(trace="object 1 y", axis="y", structured=True, p_min=1e-30, p_adjusted=1e-28, p_chi2=1e-30)
    all_row = row(phase="all", structured=True, p_min=1e-30, p_adjusted=1e-28, p_chi2=1e-30)
    assert C.worst_row([y_row, all_row, coll]) is coll
    assert C.worst_row([y_row, all_row]) is all_row
    assert C.verdict([]).startswith("No residuals")


def test_summary_is_json_ready():
    obs, sim, poses = synthetic(5, scale2=2.0)
    out = C.summarize(obs, sim, poses)
    text = json.dumps(out, allow_nan=False)
    back = json.loads(text)
    assert set(back) >= {"phases", "table", "verdict", "looks_like_noise"}
    assert back["looks_like_noise"] is False and isinstance(back["verdict"], str)
    assert len(back["phases"]["labels"]) == 2 and len(back["phases"]["labels"][0]) == obs.profile.shape[1]
    assert back["phases"]["impact_time"] == pytest.approx(back["phases"]["spans"][1][2]["start"] + 2.5 / FPS)


# ---------------------------------------------------------------------------- figures
def test_residual_figure(tmp_path):
    obs, sim, poses = synthetic(0, scale2=3.0)
    t = obs.frame_times
    times = 0.5 * (t[1:] + t[:-1])
    z = CN.standardised_residuals(obs, sim)
    ph = CP.motion_phases(poses, t, obs.release_time, 2)
    table = C.residual_table(obs, sim, phases=ph)
    flags = C.flagged(table)
    assert ("object 2 x", "floor") in flags
    path = tmp_path / "fig" / "residuals.png"
    drawn = residual_figure(path, times, z, ph, obs.mask, title="test", flagged=flags)
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC and len(data) > 10_000
    assert [p.name for p in path.parent.iterdir()] == ["residuals.png"]  # no temporary file left
    import matplotlib.image
    img = matplotlib.image.imread(path)
    assert img.ndim == 3 and img.shape[0] > 200 and img.shape[1] > 500
    assert len(drawn["panels"]) == 2
    for j, panel in enumerate(drawn["panels"]):
        np.testing.assert_allclose(panel["x"][0], times[obs.mask])
        np.testing.assert_allclose(panel["x"][1], z[2 * j, obs.mask])
        np.testing.assert_allclose(panel["y"][1], z[2 * j + 1, obs.mask])
        expect = [(s["phase"], s["start"], s["end"]) for s in CP.phase_spans(ph, times)[j]]
        assert [s[0] for s in panel["spans"]] == [e[0] for e in expect]
        np.testing.assert_allclose([s[1:] for s in panel["spans"]], [e[1:] for e in expect])
    assert "structured: object 2 x" in drawn["panels"][1]["marked"]
    assert not any("object 2" in m for m in drawn["panels"][0]["marked"])
    with pytest.raises(ValueError, match="shapes"):
        residual_figure(tmp_path / "bad.png", times[:-1], z, ph, obs.mask)
    assert not (tmp_path / "bad.png").exists()


def test_model_comparison_figure(tmp_path):
    models = [{"name": "base", "rmse": 0.12, "loglik": -400.0, "noise_floor": 0.042},
              {"name": "+ rolling", "rmse": 0.07, "loglik": -250.5, "noise_floor": 0.042},
              {"name": "+ drag", "rmse": 0.11, "loglik": None, "noise_floor": 0.05}]
    path = tmp_path / "models.png"
    drawn = model_comparison_figure(path, models, title="models")
    assert path.read_bytes()[:8] == PNG_MAGIC
    assert drawn["names"] == ["base", "+ rolling", "+ drag"]
    np.testing.assert_allclose(drawn["rmse"], [0.12, 0.07, 0.11])
    np.testing.assert_allclose(drawn["noise_floor"], [0.042, 0.042, 0.05])
    np.testing.assert_allclose(drawn["delta_loglik"][:2], [0.0, 149.5])
    assert np.isnan(drawn["delta_loglik"][2])
    with pytest.raises(ValueError):
        model_comparison_figure(tmp_path / "none.png", [])
    # a model on another engine is measured from the base model refitted on that engine
    models[2] = {"name": "+ drag (MJX)", "rmse": 0.11, "loglik": -300.0, "noise_floor": 0.05,
                 "loglik_reference": -380.0}
    drawn = model_comparison_figure(tmp_path / "engines.png", models)
    np.testing.assert_allclose(drawn["delta_loglik"], [0.0, 149.5, 80.0])


def test_base_loglik_by_engine():
    """The reference of each engine: the base fit's own engine, else the base refitted on the
    other engine in round 1, after its null refit where that improved it."""
    from types import SimpleNamespace

    from galileo_jax.criticism.diagnosis import base_loglik_by_engine
    from galileo_jax.criticism.models import Round

    base = SimpleNamespace(name="base", loglik=-245.7, union=SimpleNamespace(engine="mujoco"))
    transfers = [{"model": "base", "engine": "mjx", "loglik": -2385.2}]
    nulls = [{"model": "base", "engine": "mjx", "loglik_after": -254.8},
             {"model": "base", "engine": "mujoco", "loglik_after": -245.7}]
    diag = SimpleNamespace(fits=[base], rounds=[Round(1, "base", 0.05, transfers=transfers, null_refit=nulls)])
    assert base_loglik_by_engine(diag) == {"mujoco": -245.7, "mjx": -254.8}
    diag.rounds[0].null_refit = []
    assert base_loglik_by_engine(diag) == {"mujoco": -245.7, "mjx": -2385.2}
    assert base_loglik_by_engine(SimpleNamespace(fits=[base], rounds=[])) == {"mujoco": -245.7}


def test_fit_adequacy_verdict():
    """criticism.adequacy.adequacy, the verdict every fit report carries: tracking noise alone is adequate
    (RMSE near the noise floor); object 2 sliding three times farther than simulated is not,
    and the verdict names the floor phase; an impact mistimed by one frame, the simulator's own
    inexactness, is left out of the calm RMSE (within one sample of a velocity jump)."""
    obs, sim, poses = synthetic(0, sd_p=0.001, sd_model=0.0)
    ok = A.adequacy(obs, sim, poses)
    assert ok["adequate"] and ok["verdict"].startswith("The model describes the video")
    assert ok["calm_rmse_over_floor"] <= A.ADEQUATE_RATIO and ok["rmse_over_floor"] <= A.ADEQUATE_RATIO_ALL
    assert 0.5 < ok["calm_fraction"] < 1.0  # the samples next to the release, foot and impact are left out
    json.dumps(ok)
    obs, sim, poses = synthetic(0, sd_p=0.001, sd_model=0.0, scale2=3.0)
    bad = A.adequacy(obs, sim, poses)
    assert not bad["adequate"] and not bad["looks_like_noise"]
    assert {"trace": "object 2 x", "phase": "floor"} in bad["flagged"]
    assert bad["verdict"].startswith("The model fails on the floor: object 2 travels")
    assert bad["rmse_over_floor"] > A.ADEQUATE_RATIO_ALL
    # the calm mask leaves out only samples next to a velocity jump of GATE_JUMP or more
    calm = A.calm_mask(obs, sim)
    out = np.asarray(obs.mask, bool)[None] & ~calm
    assert out.any() and calm.any()
    jump = np.zeros(sim.shape[1], bool)
    jump[1:] = (np.abs(np.diff(sim, axis=1)) >= A.GATE_JUMP).any(axis=0)
    near = np.convolve(jump.astype(float), np.ones(5), mode="same") > 0  # within 2 samples of a jump
    assert near[out.any(axis=0)].all()
