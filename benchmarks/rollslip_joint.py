"""Joint fits of the four real roll-slip clips: sliding block vs rolling cylinder, one friction.

Usage: MUJOCO_GL=egl python benchmarks/rollslip_joint.py [--starts 3] [--screen 64] [--no-fine]

A PVC pipe (outer radius 5.63 cm, inner 4.85 cm, 437 g) is released on one wooden board tilted
10.3, 28.3, 42.4 and 65.1 degrees (../shared/data/real/rollslip_*.mp4, scenes/rollslip_*.yaml).
Every clip is observed as ``fit`` does (``read_video(path, fps_override=scene.video.fps)``,
``observe(clip, scene)``), then all four are fitted JOINTLY (one shared friction k1,
:class:`~galileo_jax.inference.joint.JointProblem` + ``fit_grad``) with

* (a) the base sliding-block model: k1 is an "apparent" sliding friction;
* (b) ``effects=("rolling",)``: the pipe is a cylinder with I = 0.871 m r^2 and k1 = mu is the
  pipe-board friction coefficient;
* (c) as (b), with 32 physics substeps per frame (1/959 s) instead of 8 in the two steep clips:
  a slipping cylinder hops off the board by up to ~6 mm at 8 substeps (MuJoCo contact
  artefact, 1 mm at 32), which makes log L rough in mu at 65.1 degrees;
* (d) diagnostic: as (c) plus a resistance force c_rr m g cos(theta) against the motion at the
  centre (an :class:`~galileo_jax.effects.Effect` defined here, not in the library): does the
  rolling model's remaining misfit (the pipe accelerates a little less than ideal rolling at
  the low angles) look like rolling resistance? Shared (mu, c_rr).

Reported per model: the shared k1 with the Gauss-Newton 90% interval and the profile-likelihood
set from a grid over k1, the joint log-likelihood, per-video RMSE against the tracking noise
(velocity_sd), chi-square goodness of fit of the standardised residuals (sum r^2 against
chi2(n), under the fit's likelihood = tracking noise + the 0.05 m/s model floor, and under the
tracking noise alone), Delta log L between the models and Vuong's test for non-nested models;
and single-video fits (per-angle k1 / mu) for both models. Writes
benchmarks/results/rollslip_joint.{md,json}.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402

from _common import with_substeps  # noqa: E402

from galileo_jax.effects import Effect, EffectParam  # noqa: E402
from galileo_jax.inference.grad import fit_grad  # noqa: E402
from galileo_jax.inference.joint import JointProblem  # noqa: E402
from galileo_jax.inference.problem import Problem, clear_caches  # noqa: E402
from galileo_jax.jaxcache import enable_compilation_cache  # noqa: E402
from galileo_jax.likelihood import make_likelihood  # noqa: E402
from galileo_jax.report.results import package_versions, to_jsonable  # noqa: E402
from galileo_jax.scene import load_scene  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
ANGLES = ("10.3", "28.3", "42.4", "65.1")
VIDEO_DIR = ROOT.parent / "shared" / "data" / "real"
ALPHA = 0.871  # I / (m r^2) of the pipe
PUBLISHED = (0.25, 0.30)
GRID_STEP = 0.01
HALF_CHI2_90 = 0.5 * stats.chi2.ppf(0.90, 1)  # profile-likelihood 90% set: log L >= max - 1.353


def _resistance_force(state, values, ctx):
    v = jnp.asarray(state.vel)
    speed = jnp.sqrt(jnp.sum(v**2, axis=-1, keepdims=True) + 1e-4)  # smooth at rest (1 cm/s)
    normal = ctx.gravity * math.cos(ctx.ramp_angle)
    return -values[0] * normal * jnp.asarray(state.mass)[:, None] * v / speed


#: Diagnostic effect (model d): a resistance force c_rr N against the motion, at the centre.
#: For a cylinder rolling without slipping it lowers the acceleration by c_rr g cos / (1 + alpha);
#: while slipping by c_rr g cos (then only mu + c_rr is determined).
RESISTANCE = Effect(
    name="resistance_bench",
    summary="resistance force c_rr m g cos(theta) against the motion (rolling-resistance-like)",
    params=(EffectParam("c_rr", "", 0.0, 0.0, 0.1, 0.01, (0.01, 0.05), "resistance force per unit normal force"),),
    force=_resistance_force,
)


def machine_info() -> dict:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "system": f"{platform.system()} {platform.release()}",
            "jax_backend": jax.default_backend(), "versions": package_versions()}


def observe_all() -> tuple[dict, dict, float]:
    from galileo_jax.observe import observe, read_video

    t0 = time.perf_counter()
    scenes, obs = {}, {}
    for a in ANGLES:
        scene = load_scene(ROOT / "scenes" / f"rollslip_{a}.yaml")
        clip = read_video(VIDEO_DIR / f"rollslip_{a}.mp4", fps_override=scene.video.fps)
        scenes[a], obs[a] = scene, observe(clip, scene, progress=False)
    return scenes, obs, time.perf_counter() - t0


def problems_for(scenes, obs, effects, fine_steep: bool = False) -> list[Problem]:
    out = []
    for a in ANGLES:
        scene = with_substeps(scenes[a], 32) if fine_steep and a in ("42.4", "65.1") else scenes[a]
        out.append(Problem(scene, obs[a], effects=effects))
    return out


def gof(jp: JointProblem, theta: np.ndarray) -> dict:
    """Goodness of fit of a joint estimate: per-video and overall chi-square, RMSE, log L."""
    r_pad = np.asarray(jp.residuals(jnp.asarray(theta)), np.float64)
    # residuals are padded to fixed length (zeros outside the mask): keep the used samples only
    blocks = [lik.used(b) for lik, b in zip(jp.likelihood.likelihoods, jp.split_residuals(r_pad))]
    r_all = np.concatenate(blocks)
    sims = [np.asarray(s, np.float64) for s in jp.simulate(jnp.asarray(theta))]
    ll_video = jp.video_log_likelihoods(jnp.asarray(theta))
    videos = []
    ss_noise_total, n_total = 0.0, 0
    for a, p, r, sim, ll in zip(ANGLES, jp.problems, blocks, sims, ll_video):
        o = p.observation
        m = np.asarray(o.mask, bool)
        diff = (np.asarray(o.profile) - sim)[:, m]
        rmse = np.sqrt(np.mean(diff**2, axis=1))
        # tracking noise alone: exact MA(1) whitening, no model floor
        lik0 = make_likelihood(o, "gaussian_ma1", 0.0)
        r0 = lik0.used_residuals(sim)
        ss, n = float(np.sum(r**2)), int(r.size)
        ss0 = float(np.sum(r0**2))
        # along-slope acceleration, observed vs simulated (least-squares slope over the moving samples)
        th = p.scene.ramp.angle
        t_mid = (0.5 * (o.frame_times[:-1] + o.frame_times[1:]))[m]
        v_obs = (np.asarray(o.profile)[0] * math.cos(th) - np.asarray(o.profile)[1] * math.sin(th))[m]
        v_sim = (sim[0] * math.cos(th) - sim[1] * math.sin(th))[m]
        sel = (v_obs > 0.05) | (v_sim > 0.05)
        a_obs = float(np.polyfit(t_mid[sel], v_obs[sel], 1)[0]) if sel.sum() > 2 else float("nan")
        a_sim = float(np.polyfit(t_mid[sel], v_sim[sel], 1)[0]) if sel.sum() > 2 else float("nan")
        ss_noise_total += ss0
        n_total += n
        videos.append({
            "angle_deg": float(a), "loglik": float(ll), "n": n, "sum_r2": ss, "chi2_p": float(stats.chi2.sf(ss, n)),
            "sum_r2_noise_only": ss0, "chi2_p_noise_only": float(stats.chi2.sf(ss0, n)),
            "rmse_x": float(rmse[0]), "rmse_y": float(rmse[1]),
            "velocity_sd_x": float(o.velocity_sd[0]), "velocity_sd_y": float(o.velocity_sd[1]),
            "rmse_over_sd": float(np.sqrt(np.mean((rmse / o.velocity_sd) ** 2))),
            "accel_obs": a_obs, "accel_sim": a_sim,
        })
    ss = float(np.sum(r_all**2))
    df = int(r_all.size - jp.dim)
    return {"videos": videos, "residuals": r_all, "overall": {
        "n": int(r_all.size), "df": df, "sum_r2": ss, "chi2_p": float(stats.chi2.sf(ss, df)),
        "sum_r2_noise_only": ss_noise_total, "chi2_p_noise_only": float(stats.chi2.sf(ss_noise_total, n_total - jp.dim)),
        "loglik": float(np.sum(ll_video))}}


def vuong(r_a: np.ndarray, r_b: np.ndarray) -> dict:
    """Vuong (1989) test of model a against model b from pointwise log-likelihood ratios.

    With the same Gaussian noise model the pointwise log-likelihood ratio is
    l_i = (r_b,i^2 - r_a,i^2) / 2; Z = sum l / (sqrt(n) sd(l)) ~ N(0, 1) if the models fit
    equally well; same number of parameters, so no correction term.
    """
    lr = 0.5 * (np.asarray(r_b) ** 2 - np.asarray(r_a) ** 2)
    n = lr.size
    z = float(lr.sum() / (math.sqrt(n) * lr.std(ddof=1)))
    return {"sum_lr": float(lr.sum()), "n": int(n), "z": z, "p_one_sided": float(stats.norm.sf(z))}


def profile_set(grid: np.ndarray, ll: np.ndarray) -> dict:
    """Best grid value and the range of grid values with log L >= max - 1.353 (90% profile-likelihood set)."""
    ok = np.flatnonzero(ll >= ll.max() - HALF_CHI2_90)
    return {"best": float(grid[int(np.argmax(ll))]), "loglik_max": float(ll.max()),
            "set90": [float(grid[ok].min()), float(grid[ok].max())]}


def result_dict(res) -> dict:
    return {"names": list(res.names), "theta": res.theta, "sd": res.sd, "interval90": res.interval90,
            "loglik": res.loglik, "cost": res.cost, "iterations": res.iterations, "converged": res.converged,
            "result": res.result, "starts_theta": res.starts_theta, "starts_cost": res.starts_cost,
            "time_s": res.time_s}


def run_model(label: str, probs: list[Problem], args, grid: np.ndarray) -> dict:
    jp = JointProblem(probs)
    t0 = time.perf_counter()
    res = fit_grad(jp, jax.random.key(args.seed), n_starts=args.starts, n_screen=args.screen, max_steps=args.max_steps)
    t_fit = time.perf_counter() - t0
    g = gof(jp, res.theta)
    t0 = time.perf_counter()
    thetas = np.tile(res.theta, (grid.size, 1))
    k1 = list(jp.names).index("k1")
    thetas[:, k1] = grid  # d > 1: a slice through the estimate along k1 (the others fixed), not a profile
    grid_ll = jp.video_log_likelihoods(jnp.asarray(thetas))  # (G, 4)
    t_grid = time.perf_counter() - t0
    n_res = g["overall"]["n"]
    scale = math.sqrt(max(2.0 * res.cost / max(n_res - jp.dim, 1), 1.0))
    out = {"label": label, "fit": result_dict(res), "gof": {k: v for k, v in g.items() if k != "residuals"},
           "misfit_scale": scale, "grid": {"k1": grid, "video_loglik": grid_ll,
                                           "profile": profile_set(grid, grid_ll.sum(1))},
           "time_fit_s": t_fit, "time_grid_s": t_grid}
    print(f"[{label}] k1 = {res.theta[0]:.4f} [{res.interval90[0, 0]:.4f}, {res.interval90[0, 1]:.4f}]  "
          f"log L = {res.loglik:.1f}  chi2/df = {g['overall']['sum_r2'] / g['overall']['df']:.2f}  "
          f"fit {t_fit:.0f} s, grid {t_grid:.0f} s", flush=True)
    return out, g["residuals"]


def single_fits(label: str, items, args, grid: np.ndarray) -> list[dict]:
    """Single-video fits; ``items``: (video index, Problem, per-video log L on the grid)."""
    rows = []
    for j, p, grid_ll in items:
        a = ANGLES[j]
        t0 = time.perf_counter()
        res = fit_grad(p, jax.random.key(args.seed + 1 + j), n_starts=args.single_starts, n_screen=args.screen,
                       max_steps=args.max_steps)
        rows.append({"angle_deg": float(a), "k1": float(res.theta[0]), "interval90": res.interval90[0],
                     "loglik": res.loglik, "converged": res.converged, "time_s": time.perf_counter() - t0,
                     "profile": profile_set(grid, np.asarray(grid_ll))})
        print(f"[{label} single {a}] k1 = {res.theta[0]:.4f} [{res.interval90[0, 0]:.4f}, {res.interval90[0, 1]:.4f}] "
              f"log L = {res.loglik:.1f} profile set {rows[-1]['profile']['set90']} ({rows[-1]['time_s']:.0f} s)", flush=True)
    return rows


def fmt_p(p: float) -> str:
    return "<1e-300" if p == 0 else (f"{p:.2g}" if p < 0.01 else f"{p:.2f}")


def write_md(path: Path, rep: dict) -> None:
    models = rep["models"]
    L = ["# Joint fit of the four real roll-slip clips: sliding block vs rolling cylinder", "",
         f"Machine: {rep['machine']['cpu']}, {rep['machine']['cores']} cores (shared), {rep['machine']['system']}, "
         f"JAX {rep['machine']['versions'].get('jax')} on {rep['machine']['jax_backend']}, "
         f"MuJoCo {rep['machine']['versions'].get('mujoco')}, mujoco-mjx {rep['machine']['versions'].get('mujoco-mjx')}.",
         f"Command: `MUJOCO_GL=egl python benchmarks/rollslip_joint.py {rep['argv']}`; total wall time "
         f"{rep['time_total_s']:.0f} s (observing the clips {rep['time_observe_s']:.1f} s).", "",
         "Clips ../shared/data/real/rollslip_*.mp4 (PVC pipe, r = 5.63 cm, I = 0.871 m r^2, on one board), "
         "likelihood gaussian_iid with the 0.05 m/s model floor (the default), joint `fit_grad` "
         f"({rep['settings']['starts']} screened starts of {rep['settings']['screen']}, FD Jacobian). "
         "One shared k1 in every model.", "",
         "## Joint fits", "",
         "| model | shared k1 | GN 90% interval | profile-L 90% set (grid step 0.01) | log L | chi2 / df (p) | "
         "chi2 noise-only / n (p) | fit time |",
         "|---|---|---|---|---|---|---|---|"]
    for m in models:
        f, o = m["fit"], m["gof"]["overall"]
        extra = "".join(f"; {n} = {t:.3f} [{i[0]:.3f}, {i[1]:.3f}]" for n, t, i in
                        zip(f["names"][1:], f["theta"][1:], f["interval90"][1:]) if "@" not in n)
        L.append(f"| {m['label']} | {f['theta'][0]:.3f}{extra} | [{f['interval90'][0][0]:.3f}, {f['interval90'][0][1]:.3f}] | "
                 f"{_set_text(m['grid']['profile'])} | {f['loglik']:.1f} | "
                 f"{o['sum_r2']:.0f} / {o['df']} ({fmt_p(o['chi2_p'])}) | "
                 f"{o['sum_r2_noise_only']:.0f} / {o['n']} ({fmt_p(o['chi2_p_noise_only'])}) | {m['time_fit_s']:.0f} s |")
    L += ["", "Per video at the joint estimate (RMSE in m/s of the x / y velocity traces against the tracking "
          "noise velocity_sd; chi2 = sum of squared standardised residuals under the fit's likelihood, n samples):", "",
          "| model | angle | log L | RMSE x / y | noise sd x / y | RMSE/sd | chi2 / n (p) | chi2 noise-only (p) | "
          "accel. along slope obs / sim (m/s^2) |",
          "|---|---|---|---|---|---|---|---|---|"]
    for m in models:
        for v in m["gof"]["videos"]:
            L.append(f"| {m['label']} | {v['angle_deg']:g} | {v['loglik']:.1f} | {v['rmse_x']:.3f} / {v['rmse_y']:.3f} | "
                     f"{v['velocity_sd_x']:.3f} / {v['velocity_sd_y']:.3f} | {v['rmse_over_sd']:.2f} | "
                     f"{v['sum_r2']:.0f} / {v['n']} ({fmt_p(v['chi2_p'])}) | {v['sum_r2_noise_only']:.0f} ({fmt_p(v['chi2_p_noise_only'])}) | "
                     f"{v['accel_obs']:.2f} / {v['accel_sim']:.2f} |")
    vu = rep["comparison"]
    L += ["", "## Sliding vs rolling", "",
          f"Delta log L (rolling - sliding, same data, one parameter each) = {vu['delta_loglik']:.1f} nats "
          f"(per video: {', '.join(f'{d:+.1f}' for d in vu['delta_loglik_per_video'])}). "
          f"Vuong test (non-nested, pointwise log-likelihood ratios, n = {vu['vuong']['n']}): Z = {vu['vuong']['z']:.1f}, "
          f"one-sided p = {fmt_p(vu['vuong']['p_one_sided'])}. The residuals are serially correlated (the misfit is a "
          "smooth curve), so the effective n is smaller than the sample count and Z is optimistic; the per-video "
          "log L differences tell the same story without that assumption.", "",
          "## Single-video fits", ""]
    if not rep["single"].get("sliding"):
        L.append("Not run (`--no-single`).")
    else:
        L += ["| angle | sliding: apparent k1 (GN 90%) | rolling: mu (GN 90%) | rolling: profile-L 90% set | "
              "rolling without slipping needs mu >= tan / (1 + 1/alpha) | log L sliding / rolling |",
              "|---|---|---|---|---|---|"]
    for s, r in zip(rep["single"].get("sliding", []), rep["single"].get("rolling", [])):
        bound = math.tan(math.radians(s["angle_deg"])) / (1 + 1 / ALPHA)
        L.append(f"| {s['angle_deg']:g} | {s['k1']:.3f} [{s['interval90'][0]:.3f}, {s['interval90'][1]:.3f}] | "
                 f"{r['k1']:.3f} [{r['interval90'][0]:.3f}, {r['interval90'][1]:.3f}] | "
                 f"{_set_text(r['profile'])} | {bound:.3f} | "
                 f"{s['loglik']:.1f} / {r['loglik']:.1f} |")
    if rep["single"].get("rolling_fine"):
        L += ["", "Rolling, 32 substeps in the steep clips (model c):", ""]
        for r in rep["single"]["rolling_fine"]:
            L.append(f"- {r['angle_deg']:g} deg: mu = {r['k1']:.3f} [{r['interval90'][0]:.3f}, {r['interval90'][1]:.3f}], "
                     f"profile-L set {_set_text(r['profile'])}")
    L += ["", "## Log-likelihood against the shared friction (grid)", "",
          "Joint log L minus its grid maximum, per model, at a few values (full per-video curves in the JSON; "
          "for (d) a slice along mu at the estimated c_rr):", "",
          "| k1 | " + " | ".join(m["label"] for m in models) + " |", "|---|" + "---|" * len(models)]
    for k in rep["grid_rows"]:
        cells = []
        for m in models:
            g = np.asarray(m["grid"]["k1"])
            ll = np.asarray(m["grid"]["video_loglik"]).sum(1)
            i = int(np.argmin(np.abs(g - k)))
            cells.append(f"{ll[i] - ll.max():.1f}")
        L.append(f"| {k:.3f} | " + " | ".join(cells) + " |")
    L += ["", "## Verdict", "", *rep["verdict"], "",
          "## Notes", "",
          "- chi2 under the fit's likelihood uses sd^2 = velocity_sd^2 + 0.05^2 per sample (the default gaussian_iid "
          "likelihood that the fit maximises). The 'noise-only' column drops the 0.05 m/s floor and whitens with the "
          "exact MA(1) covariance of the tracking noise: every model fails it by orders of magnitude, because the "
          "tracker's velocity_sd (e.g. 0.019 / 0.007 m/s at 65.1 deg) is far below the scatter of the observed "
          "velocities (RMSE 0.04-0.1 m/s even where the rolling fit is good): the tracking noise estimate is too small "
          "for these clips, so only the floor-inclusive test is informative.",
          "- GN intervals assume the model is right and log L is smooth; at 8 substeps log L is rough in mu at 65.1 deg "
          "(the slipping cylinder hops), so the grid rows and the substep comparison are the honest uncertainty.",
          "- Single-video rolling fits at 10.3 and 28.3 deg: the pipe rolls without slipping for every mu above "
          "tan(theta) / (1 + 1/alpha), so those clips only bound mu from below; their GN 'interval' covers the prior.",
          "- Times: wall time per fit including tracing and compilation (JAX's persistent compilation cache as "
          "left by earlier runs); each joint fit also fits one release-time correction dt_release per clip.",
          "- Acceleration column: least-squares slope of the along-slope velocity over the moving samples; a deficit at "
          "low angles that ideal rolling cannot produce is what model (d) tests.", ""]
    path.write_text("\n".join(L) + "\n")


def _set_text(prof: dict) -> str:
    lo, hi = prof["set90"]
    if lo == hi:
        return f"{lo:.2f} only"
    return f"[{lo:.2f}, {hi:.2f}]" + (" (to the grid's end: unbounded above)" if hi >= 0.6 - 1e-9 else "")


def verdict_lines(rep: dict) -> list[str]:
    """The plain-language conclusions, from the (JSON) report."""
    models, comparison = rep["models"], rep["comparison"]
    slid, roll = models[0], models[1]
    mu = roll["fit"]["theta"][0]
    o_s, o_r = slid["gof"]["overall"], roll["gof"]["overall"]
    g = np.asarray(roll["grid"]["k1"])
    llg = np.asarray(roll["grid"]["video_loglik"]).sum(1)
    pub_ll = [float(llg[int(np.argmin(np.abs(g - k)))] - llg.max()) for k in PUBLISHED]
    per_video = ", ".join(f"{v['angle_deg']:g} deg p = {fmt_p(v['chi2_p'])}" for v in roll["gof"]["videos"])
    rejected = [v for v in roll["gof"]["videos"] if v["chi2_p"] < 0.05]
    trend = [v for v in rejected if abs(v["accel_obs"] - v["accel_sim"]) > 0.05 * abs(v["accel_sim"])]
    acc = "; ".join(f"{v['angle_deg']:g} deg {v['accel_obs']:.2f} observed vs {v['accel_sim']:.2f} simulated"
                    for v in rejected)
    misfit = (f"Where it is rejected the slope acceleration misses by more than 5% ({acc} m/s^2): a trend the "
              "model lacks" if trend else
              f"Where it is rejected the slope acceleration still matches within 5% ({acc} m/s^2), so the excess "
              "chi-square is not a missing trend but a few large residuals (look at the residual figure of "
              "`diagnose` on these clips)")
    bounds = [math.tan(math.radians(float(a))) / (1 + 1 / ALPHA) for a in ANGLES]  # rolls without slipping above
    v42 = roll["gof"]["videos"][ANGLES.index("42.4")]
    acc42 = v42["accel_obs"]
    roll42 = 9.81 * math.sin(math.radians(42.4)) / (1 + ALPHA)  # a = g sin / (1 + I / (m r^2))
    bounds_slide = [math.tan(math.radians(float(a))) for a in ANGLES]  # a block slides only if k1 < tan
    chi65 = [m["gof"]["videos"][ANGLES.index("65.1")]["sum_r2"] for m in models[1:3]]
    out = [
        f"- Sliding block, one k1 for all four clips: k1 = {slid['fit']['theta'][0]:.3f}, chi2 = {o_s['sum_r2']:.0f} on "
        f"{o_s['df']} df (p = {fmt_p(o_s['chi2_p'])}): REJECTED. "
        + ("The per-angle apparent frictions (single-video table) differ by far more than their intervals. "
           if rep["single"].get("sliding") else "")
        + ("The best compromise leaves the 10.3 deg pipe at rest (k1 > tan 10.3 = 0.18)."
           if slid["fit"]["theta"][0] > bounds_slide[0] else "The best compromise misfits every clip."),
        f"- Rolling cylinder, one mu: mu = {mu:.3f} (GN 90% [{roll['fit']['interval90'][0][0]:.3f}, "
        f"{roll['fit']['interval90'][0][1]:.3f}]), log L higher by {comparison['delta_loglik']:.0f} nats with the same "
        f"single parameter (Vuong Z = {comparison['vuong']['z']:.1f}), chi2 = {o_r['sum_r2']:.0f} on {o_r['df']} df "
        f"(p = {fmt_p(o_r['chi2_p'])}). "
        + ("Not rejected at the 5% level." if o_r["chi2_p"] > 0.05 else
           "So the rolling fit is NOT rejected in comparison (it is overwhelmingly preferred and fits the 42.4 deg "
           "clip within noise), but in absolute terms it is still rejected at the 5% level under the fit's noise "
           f"model: per video {per_video}. {misfit}" + (f"; at 65.1 deg chi2 is {chi65[0]:.0f} at 8 substeps and {chi65[1]:.0f} at 32 "
                                    "(model c)." if len(chi65) > 1 else ".")),
        f"- Published pipe-on-board mu 0.25-0.30: the data say mu ~ {mu:.2f}, above that range. At mu = 0.25 / 0.30 the "
        f"joint log L is {pub_ll[0]:.0f} / {pub_ll[1]:.0f} nats below the best: the 42.4 deg clip would then roll AND "
        f"slip (it slips once tan(theta) > mu (1 + 1/alpha), i.e. mu < {bounds[2]:.3f} at 42.4 deg) and accelerate "
        f"faster than observed ({acc42:.2f} m/s^2 observed; rolling without slipping gives {roll42:.2f}). The 10.3 and "
        f"28.3 deg clips roll without slipping for any mu above {bounds[0]:.3f} / {bounds[1]:.3f} and say nothing more "
        f"about mu; mu comes from 42.4 deg (a lower bound, mu >= {bounds[2]:.3f}) and 65.1 deg (rolls and slips).",
    ]
    if len(models) > 2:
        f = models[2]
        out.append(f"- With 32 substeps in the steep clips (model c): mu = {f['fit']['theta'][0]:.3f} "
                   f"(GN 90% [{f['fit']['interval90'][0][0]:.3f}, {f['fit']['interval90'][0][1]:.3f}]), log L "
                   f"{f['fit']['loglik']:.1f}. The timestep moves mu by {f['fit']['theta'][0] - mu:+.3f}, more than "
                   f"the GN interval at 8 substeps: treat mu = {min(mu, f['fit']['theta'][0]):.2f}-"
                   f"{max(mu, f['fit']['theta'][0]):.2f} as the answer, its uncertainty dominated by "
                   "the simulator (the slipping cylinder hops at 8 substeps), not by the data.")
    if len(models) > 3:
        d = models[3]
        c = dict(zip(d["fit"]["names"], d["fit"]["theta"]))
        ci = dict(zip(d["fit"]["names"], d["fit"]["interval90"]))
        pv = ", ".join(f"{v['angle_deg']:g} deg p = {fmt_p(v['chi2_p'])}" for v in d["gof"]["videos"])
        out.append(f"- Diagnostic (d), adding a resistance force c_rr m g cos(theta) at the centre: mu = {c['k1']:.3f}, "
                   f"c_rr = {c['c_rr']:.4f} [{ci['c_rr'][0]:.4f}, {ci['c_rr'][1]:.4f}], log L {d['fit']['loglik']:.1f} "
                   f"(2 Delta log L = {comparison['resistance_lr']['lr']:.1f} against (c), boundary p = "
                   f"{fmt_p(comparison['resistance_lr']['p'])}); chi2 = {d['gof']['overall']['sum_r2']:.0f} on "
                   f"{d['gof']['overall']['df']} df (p = {fmt_p(d['gof']['overall']['chi2_p'])}; {pv}). A small "
                   "rolling-resistance-like loss explains most of the low-angle deficit and leaves mu where it was. "
                   "Not a library effect: a pointer, not a result.")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--starts", type=int, default=3, help="LM starts of the joint fits")
    ap.add_argument("--single-starts", type=int, default=2, help="LM starts of the single-video fits")
    ap.add_argument("--screen", type=int, default=64, help="screened Latin-hypercube points")
    ap.add_argument("--max-steps", type=int, default=40)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-fine", action="store_true", help="skip model (c) (32 substeps in the steep clips)")
    ap.add_argument("--no-resistance", action="store_true", help="skip the diagnostic model (d)")
    ap.add_argument("--no-single", action="store_true", help="skip the single-video fits")
    ap.add_argument("--render-only", action="store_true", help="rewrite the .md from the saved .json (no fits)")
    args = ap.parse_args()
    import sys

    res_json = ROOT / "benchmarks" / "results" / "rollslip_joint.json"
    if args.render_only:
        rep = json.loads(res_json.read_text())
        rep["verdict"] = verdict_lines(rep)
        res_json.write_text(json.dumps(rep, indent=1))
        write_md(res_json.with_suffix(".md"), rep)
        print(res_json.with_suffix(".md").read_text())
        return

    enable_compilation_cache()
    t_start = time.perf_counter()
    scenes, obs, t_obs = observe_all()
    for a in ANGLES:
        o = obs[a]
        print(f"clip {a}: {len(o.frame_times)} frames, release {o.release_time:.3f} s, {int(o.mask.sum())} samples, "
              f"velocity_sd {np.round(o.velocity_sd, 3)} m/s", flush=True)
    grid = np.round(np.arange(0.05, 0.6001, GRID_STEP), 4)  # 56 points: one vmapped batch
    specs = [("sliding", (), False), ("rolling", ("rolling",), False)]
    if not args.no_fine:
        specs.append(("rolling, 32 substeps at 42.4/65.1", ("rolling",), True))
    if not args.no_resistance:
        specs.append(("rolling + resistance, 32 substeps at 42.4/65.1", ("rolling", RESISTANCE), True))
    models, residuals, probs_by = [], {}, {}
    for label, eff, fine in specs:
        probs = problems_for(scenes, obs, eff, fine)
        probs_by[label] = probs
        m, r = run_model(label, probs, args, grid)
        models.append(m)
        residuals[label] = r
        clear_caches()  # free the compiled programs (each holds memory maps; see tests/conftest.py)

    ll_s = np.asarray([v["loglik"] for v in models[0]["gof"]["videos"]])
    ll_r = np.asarray([v["loglik"] for v in models[1]["gof"]["videos"]])
    comparison = {"delta_loglik": float(models[1]["fit"]["loglik"] - models[0]["fit"]["loglik"]),
                  "delta_loglik_per_video": ll_r - ll_s, "vuong": vuong(residuals["rolling"], residuals["sliding"])}
    labels = [m["label"] for m in models]
    if len(models) > 3:
        lr = 2.0 * (models[3]["fit"]["loglik"] - models[2]["fit"]["loglik"])
        comparison["resistance_lr"] = {"lr": lr, "p": float(0.5 * stats.chi2.sf(max(lr, 0.0), 1)),
                                       "test": f"{labels[3]} vs {labels[2]}: 2 Delta log L against the boundary "
                                               "null c_rr = 0, p = chi2_1.sf / 2"}
    print(f"Delta log L (rolling - sliding) = {comparison['delta_loglik']:.1f}; Vuong Z = {comparison['vuong']['z']:.1f}",
          flush=True)

    single = {}
    if not args.no_single:
        for m, key in zip(models[:3], ("sliding", "rolling", "rolling_fine")):
            probs = probs_by[m["label"]]
            gl = np.asarray(m["grid"]["video_loglik"])
            idx = [ANGLES.index("42.4"), ANGLES.index("65.1")] if key == "rolling_fine" else range(len(ANGLES))
            single[key] = single_fits(m["label"], [(j, probs[j], gl[:, j]) for j in idx], args, grid)

    rep = {"machine": machine_info(), "argv": " ".join(sys.argv[1:]),
           "settings": {"starts": args.starts, "single_starts": args.single_starts, "screen": args.screen,
                        "max_steps": args.max_steps, "seed": args.seed, "likelihood": "gaussian_iid",
                        "sd_model": 0.05, "alpha": ALPHA},
           "observations": {a: {"n_frames": len(obs[a].frame_times), "release_time_s": obs[a].release_time,
                                "fit_samples": int(obs[a].mask.sum()), "velocity_sd": obs[a].velocity_sd}
                            for a in ANGLES},
           "models": models, "comparison": comparison, "single": single,
           "grid_rows": [0.25, 0.30, 0.35, 0.40, 0.42, 0.43, 0.44, 0.45, 0.46, 0.48, 0.50],
           "time_observe_s": t_obs, "time_total_s": time.perf_counter() - t_start}
    res_dir = ROOT / "benchmarks" / "results"
    res_dir.mkdir(parents=True, exist_ok=True)
    rep = json.loads(json.dumps(to_jsonable(rep)))
    rep["verdict"] = verdict_lines(rep)
    (res_dir / "rollslip_joint.json").write_text(json.dumps(rep, indent=1))
    write_md(res_dir / "rollslip_joint.md", rep)
    print()
    print((res_dir / "rollslip_joint.md").read_text())


if __name__ == "__main__":
    main()
