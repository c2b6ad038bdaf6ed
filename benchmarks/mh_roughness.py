"""Why mh mixes slowly: the sampler on a video's posterior, and on Gaussians of its covariance, smooth or rough.

``run_mh`` at ``fit``'s defaults (16 chains, 300 annealed warm-up + 400 kept steps, jumps 0.5) is
run on four targets, same PRNG key:

* ``video``: the posterior of one rendered video (default: the coverage benchmark's
  ``ramp_20_1``, tracked as a user's video), C MuJoCo rollouts;
* ``gaussian``: a Gaussian in the sampler's coordinates z with the mean and covariance of the
  ``video`` run's draws (the log-likelihood handed to the sampler is that Gaussian minus the log
  prior, so the posterior is exactly Gaussian): how well the sampler does on this posterior's
  size and correlations alone;
* ``gaussian + rough 1`` and ``+ rough 2``: the same with a pseudo-random field added to the
  log-likelihood, of SD 1 and 2 nats and correlation length a tenth of the posterior SD (64
  random Fourier features in whitened coordinates), the size the simulator's roughness has along
  k1 (third part).

Then, along k1 through the truth (121 points 5e-5 apart, the other parameters at the truth), the
log-likelihood's deviation from a fitted quadratic (SD, nats) and the velocity samples that carry
it (the same deviation of each sample's log-likelihood term, summed over traces).

Last, the physics step: the same deviation along k1 and along the release time (121 points 2e-4 s
apart) with 8 (the scene's), 16 and 32 physics steps a frame, and mh on the video with 16
(``video, 16 steps a frame``): a finer step moves the impact in finer increments.

Per target: acceptance, largest R-hat and smallest bulk ESS over k1, k2, phi (ArviZ), lag-1
autocorrelation of k1 within chains, wall time. Writes ``benchmarks/results/mh_roughness.{md,json}``.

    python benchmarks/mh_roughness.py [--video PATH]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
sys.path.insert(0, str(ROOT / "benchmarks"))
from _common import docstring_markdown, machine_line, with_substeps, write_atomic  # noqa: E402

NAMES = ("k1", "k2", "phi")
#: Synthetic roughness: SDs (nats) and correlation length (posterior SDs, whitened coordinates).
ROUGH_SDS = (1.0, 2.0)
ROUGH_LENGTH = 0.1
N_FEATURES = 64
#: Physics steps a video frame compared (the scene's first), and the one mh is also run with.
SUBSTEPS = (8, 16, 32)
MH_SUBSTEPS = 16


class GaussianTarget:
    """A stand-in for a Problem (what ``run_mh`` reads): an exactly Gaussian posterior in z, mean
    ``mu`` (d,) and covariance ``cov`` (d, d), plus a pseudo-random field of SD ``rough`` nats."""

    def __init__(self, space, mu: np.ndarray, cov: np.ndarray, rough: float, seed: int = 1):
        import jax.numpy as jnp

        rng = np.random.default_rng(seed)
        d = len(mu)
        self.space, self.max_batch, self.data = space, 64, jnp.zeros(())
        prec = jnp.asarray(np.linalg.inv(cov))
        white = jnp.asarray(np.linalg.inv(np.linalg.cholesky(cov)).T)
        omega = jnp.asarray(rng.normal(size=(d, N_FEATURES)) / ROUGH_LENGTH)
        phase = jnp.asarray(rng.uniform(0.0, 2 * math.pi, N_FEATURES))
        amp = math.sqrt(2.0 / N_FEATURES) * rough
        mu = jnp.asarray(mu)

        def loglik_fn(z, data):
            dz = z - mu
            field = amp * jnp.sum(jnp.sin((dz @ white) @ omega + phase))
            return -0.5 * dz @ prec @ dz - space.log_prior(z) + field

        self.loglik_fn = loglik_fn

    @staticmethod
    def jitted(key, fn):
        import jax

        return jax.jit(fn)


def sampler_record(name: str, res, seconds: float) -> dict:
    """Acceptance, R-hat, bulk ESS and k1's lag-1 autocorrelation of one ``run_mh`` result."""
    import arviz as az

    idx = [list(res.names).index(n) for n in NAMES]
    rhat = {n: float(az.rhat(res.theta[:, :, j])) for n, j in zip(NAMES, idx)}
    ess = {n: float(az.ess(res.theta[:, :, j], method="bulk")) for n, j in zip(NAMES, idx)}
    x = res.theta[:, :, idx[0]] - res.theta[:, :, idx[0]].mean(axis=1, keepdims=True)
    acf = float(np.mean(x[:, 1:] * x[:, :-1]) / np.mean(x * x))
    rec = {"target": name, "acceptance": float(np.mean(res.acceptance)), "rhat": rhat, "ess_bulk": ess,
           "acf1_k1": acf, "seconds": seconds}
    print(f"{name}: acceptance {rec['acceptance']:.2f}, max R-hat {max(rhat.values()):.3f}, "
          f"min ESS {min(ess.values()):.0f}, lag-1 acf {acf:.3f}, {seconds:.0f} s", flush=True)
    return rec


def roughness_along(problem, theta0: np.ndarray, name: str = "k1", step: float = 5e-5, half: int = 60) -> dict:
    """The log-likelihood's deviation from a quadratic along parameter ``name`` through ``theta0``
    (nats SD) and the velocity samples that carry most of it."""
    import jax.numpy as jnp

    lik = problem.likelihood
    i = list(problem.space.names).index(name)
    x = np.arange(-half, half + 1) * step
    th = np.repeat(theta0[None], len(x), axis=0)
    th[:, i] += x
    sim = np.asarray(problem.simulate(jnp.asarray(th)))  # (J, T, N)
    n = sim.shape[2]
    w, obs = np.asarray(lik.whiten)[:, :n], np.asarray(lik.obs)[:, :n]
    terms = -0.5 * (w * (obs[None] - sim)) ** 2  # (J, T, N) each sample's log-likelihood term (up to a constant)
    total = terms.sum(axis=(1, 2))

    def off_quadratic(y):
        return float(np.std(y - np.polyval(np.polyfit(x, y, 2), x)))

    per_sample = np.array([[off_quadratic(terms[:, t, k]) for k in range(n)] for t in range(terms.shape[1])]).sum(0)
    top = np.argsort(per_sample)[::-1][:6]
    return {"name": name, "step": step, "points": len(x), "sd_nats": off_quadratic(total),
            "samples": [{"sample": int(k), "time_s": float(problem.observation.frame_times[k]),
                         "sd_nats": float(per_sample[k])} for k in top]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--video", type=Path, default=RESULTS / "coverage" / "ramp_20_1.mp4",
                    help="a rendered video with its .yaml and .truth.json (coverage.py renders ramp_20_1)")
    args = ap.parse_args(argv)
    import jax

    from galileo_jax.config import FitConfig, resolve_engine
    from galileo_jax.inference import Problem, run_mh
    from galileo_jax.jaxcache import enable_compilation_cache
    from galileo_jax.observe import observe
    from galileo_jax.scene import load_scene

    enable_compilation_cache()
    if not args.video.exists():
        print(f"error: {args.video} not found; render it with python benchmarks/coverage.py --videos 2",
              file=sys.stderr)
        return 2
    cfg = FitConfig()
    scene = load_scene(args.video.with_suffix(".yaml"))
    truth = json.loads(args.video.with_suffix(".truth.json").read_text())
    obs = observe(args.video, scene, progress=False)
    problem = Problem(scene, obs, likelihood=cfg.likelihood.kind, sd_model=cfg.likelihood.sd_model,
                      engine=resolve_engine(cfg))
    kw = dict(n_chains=cfg.mh.chains, n_warmup=cfg.mh.warmup, n_samples=cfg.mh.samples, jump=cfg.mh.jump,
              independent=cfg.mh.independent,
              progress=False)
    records = []
    t = time.perf_counter()
    res = run_mh(problem, jax.random.PRNGKey(2), **kw)
    records.append(sampler_record("video", res, time.perf_counter() - t))
    z = res.z.reshape(-1, res.z.shape[-1])
    mu, cov = z.mean(axis=0), np.cov(z, rowvar=False)
    for rough in (0.0, *ROUGH_SDS):
        name = "gaussian" if rough == 0 else f"gaussian + rough {rough:g}"
        t = time.perf_counter()
        res_g = run_mh(GaussianTarget(problem.space, mu, cov, rough), jax.random.PRNGKey(2), **kw)
        records.append(sampler_record(name, res_g, time.perf_counter() - t))
    theta0 = np.array([truth.get(n, 0.0) for n in problem.space.names], float)
    rough = roughness_along(problem, theta0)
    steps = []
    for sub in SUBSTEPS:
        p_sub = problem if sub == scene.simulation.substeps else Problem(
            with_substeps(scene, sub), obs, likelihood=cfg.likelihood.kind, sd_model=cfg.likelihood.sd_model,
            engine=resolve_engine(cfg))
        steps.append({"substeps": sub, "k1": roughness_along(p_sub, theta0)["sd_nats"],
                      "dt_release": roughness_along(p_sub, theta0, "dt_release", 2e-4)["sd_nats"]})
        if sub == MH_SUBSTEPS:
            t = time.perf_counter()
            res_s = run_mh(p_sub, jax.random.PRNGKey(2), **kw)
            records.append(sampler_record(f"video, {sub} steps a frame", res_s, time.perf_counter() - t))
    corr = np.corrcoef(z, rowvar=False)
    doc = {"machine": machine_line(), "video": str(args.video.relative_to(ROOT)) if args.video.is_relative_to(ROOT)
           else str(args.video), "names": list(problem.space.names), "posterior_corr_z": np.round(corr, 3).tolist(),
           "records": records, "roughness_k1": rough, "physics_step": steps}
    write_atomic(RESULTS / "mh_roughness.json", json.dumps(doc, indent=1))
    lines = ["# Why mh mixes slowly: the sampler against Gaussians of the same covariance", "",
             f"machine: {doc['machine']}", "",
             f"command: `python benchmarks/mh_roughness.py` (video `{doc['video']}`)", "",
             *docstring_markdown(__doc__, 1, 5),
             "| target | acceptance | max R-hat | min bulk ESS | lag-1 autocorrelation of k1 | time (s) |",
             "|---|---|---|---|---|---|"]
    for r in records:
        lines.append(f"| {r['target']} | {r['acceptance']:.2f} | {max(r['rhat'].values()):.3f} | "
                     f"{min(r['ess_bulk'].values()):.0f} | {r['acf1_k1']:.3f} | {r['seconds']:.0f} |")
    lines += ["", f"Posterior correlations in z ({', '.join(doc['names'])}): "
              + "; ".join(" ".join(f"{c:+.2f}" for c in row) for row in doc["posterior_corr_z"]) + ".", "",
              f"Along k1 through the truth ({rough['points']} points {rough['step']:g} apart): the log-likelihood "
              f"deviates from a quadratic by {rough['sd_nats']:.2f} nats (SD). The velocity samples that carry it "
              "(the same SD of each sample's term, summed over traces): "
              + ", ".join(f"{s['sample']} (t = {s['time_s']:.2f} s) {s['sd_nats']:.2f}"
                          for s in rough["samples"]) + ".", "",
              "| physics steps a frame | off-quadratic SD along k1 (nats) | along the release time (nats) |",
              "|---|---|---|"]
    lines += [f"| {r['substeps']} | {r['k1']:.2f} | {r['dt_release']:.2f} |" for r in steps]
    write_atomic(RESULTS / "mh_roughness.md", "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
