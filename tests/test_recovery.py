"""Inference against ground truth on rendered video (issue 2, "What it must show" 3).

Five videos with random parameters are rendered with MuJoCo (C engine, image noise, a hand
in half of them), tracked with automatic object finding, and fitted as ``fit`` fits them (on
the engine ``fit`` picks: C MuJoCo's batched rollouts on a CPU, MJX on a GPU):

* ``grad`` must get k1 within 0.02, k2 within 0.03 and phi within 0.1 on at least 4 of 5;
* ``mh``'s 90% interval must contain the true k1 and phi.

No result is hard-coded: the parameters are drawn here, the truth comes from the renderer.
The draws are conditioned on a video that shows the collision: object 2 must travel at least
5 cm. When object 1 barely reaches object 2, the video says little about k2 and phi; grad
then reports wide intervals (e.g. k2 +- 0.07, phi +- 0.16 at 1 sd, measured), and this
accuracy test does not apply.
"""

from __future__ import annotations

import math

import jax
import numpy as np
import pytest

from galileo_jax.config import FitConfig, resolve_engine
from galileo_jax.inference import Problem, fit_grad, run_mh, summarize_mh
from galileo_jax.observe import observe
from galileo_jax.scene import load_scene
from galileo_jax.synth import render_video

N_VIDEOS = 5
MIN_TRAVEL_2 = 0.05  # m: object 2 must visibly slide (see module docstring)
CFG = FitConfig()


def _draw(rng: np.random.Generator, theta_deg: float) -> dict:
    tan = math.tan(math.radians(theta_deg))
    return {"m1": float(rng.uniform(0.15, 1.0)), "k1": float(rng.uniform(0.05, tan - 0.08)),
            "m2": float(rng.uniform(0.15, 1.0)), "k2": float(rng.uniform(0.1, 0.5))}


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rendered")
    scene = load_scene("scenes/ramp_20.yaml")
    rng = np.random.default_rng(20261121)
    out = []
    for i in range(N_VIDEOS):
        path = folder / f"video{i}.mp4"
        while True:
            params = _draw(rng, scene.ramp.angle_deg)
            truth = render_video(scene, params, path, width=480, height=270, noise_sd=2.0, hand=(i % 2 == 0),
                                 seed=i, progress=False)
            world = np.asarray(truth["positions"], float)  # (N, n_objects, 2) world x, up in m
            if abs(world[-1, 1, 0] - world[0, 1, 0]) >= MIN_TRAVEL_2:
                break
        fitted_scene = load_scene(path.with_suffix(".yaml"))
        obs = observe(path, fitted_scene)
        out.append((fitted_scene, obs, truth))
    return out


def _problem(scene, obs) -> Problem:
    return Problem(scene, obs, likelihood=CFG.likelihood.kind, sd_model=CFG.likelihood.sd_model,
                   engine=resolve_engine(CFG))  # the engine fit runs on: C MuJoCo on a CPU


@pytest.mark.slow
def test_grad_recovers_parameters_from_rendered_video(rendered):
    errors = []
    for i, (scene, obs, truth) in enumerate(rendered):
        problem = _problem(scene, obs)
        res = fit_grad(problem, jax.random.PRNGKey(i), n_starts=CFG.grad.starts, n_screen=CFG.grad.screen,
                       max_steps=CFG.grad.max_steps)
        est = dict(zip(res.names, res.theta))
        errors.append((abs(est["k1"] - truth["k1"]), abs(est["k2"] - truth["k2"]), abs(est["phi"] - truth["phi"])))
    errors = np.array(errors)
    ok = (errors[:, 0] <= 0.02) & (errors[:, 1] <= 0.03) & (errors[:, 2] <= 0.1)
    print("grad |error| (k1, k2, phi) per video:\n", np.round(errors, 4))
    assert ok.sum() >= 4, errors


def test_mh_interval_contains_truth(rendered):
    scene, obs, truth = rendered[0]
    problem = _problem(scene, obs)
    res = run_mh(problem, jax.random.PRNGKey(7), n_chains=16, n_warmup=150, n_samples=150, progress=False)
    summary = summarize_mh(res, problem.space)["parameters"]
    for name in ("k1", "phi"):
        lo, hi = summary[name]["interval90"]
        assert lo <= truth[name] <= hi, (name, lo, hi, truth[name])


def test_cnn_and_grad_started_from_it_on_rendered_video(rendered):
    """The shipped CNN (issue 4) on the same tracked videos: one forward pass gets k1 within
    0.03 on at least 4 of 5; grad started from it (``fit --init cnn``: one start plus a screen
    as wide as the CNN's intervals) then gets k1, k2, phi within 0.02, 0.05, 0.1 on video 0."""
    from galileo_jax.inference import cnn
    from galileo_jax.inference import cnn_files
    from galileo_jax.pipeline import grad_start_from_cnn

    errors = []
    for i, (scene, obs, truth) in enumerate(rendered):
        problem = _problem(scene, obs)
        model = cnn_files.find_model(scene, obs.fps)
        est = cnn.estimate(model, obs, problem.space, jax.random.PRNGKey(i))
        d = dict(zip(est.names, est.theta))
        errors.append([abs(d[n] - truth[n]) for n in ("k1", "k2", "phi")])
        if i == 0:
            res = fit_grad(problem, jax.random.PRNGKey(0), **grad_start_from_cnn(est, problem.space, CFG),
                           max_steps=CFG.grad.max_steps)
            g = dict(zip(res.names, res.theta))
            # One start near the CNN is cheaper than grad's 4 global starts but lands in a
            # slightly worse optimum now and then (benchmarks/results/cnn_videos.md: mean k2
            # error 0.049 vs 0.039 on 6 videos); it must still improve on the CNN's k2 and phi.
            assert abs(g["k1"] - truth["k1"]) <= 0.02 and abs(g["k2"] - truth["k2"]) <= 0.05
            assert abs(g["phi"] - truth["phi"]) <= 0.1
            assert abs(g["k2"] - truth["k2"]) < max(abs(d["k2"] - truth["k2"]), 0.02)
    errors = np.array(errors)
    print("cnn |error| (k1, k2, phi) per video:\n", np.round(errors, 4))
    assert (errors[:, 0] <= 0.03).sum() >= 4, errors
