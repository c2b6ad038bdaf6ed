"""Inference: the posterior over the scene's identifiable parameters given an observed profile.

* :class:`Problem` (problem.py): simulator + observation + parameter space + likelihood,
  batched and jitted (one vmapped MJX rollout per density call); the observation is data
  passed into the compiled functions, which every video of a scene shares.
* :class:`JointProblem` (joint.py): several videos with shared and per-video parameters.
* :class:`FixedProblem` (fixed.py): some parameters held at given values (``fit_grad(..., fixed=)``).
* :func:`run_mh` (mh.py): adaptive random-walk Metropolis-Hastings, many chains at once,
  BlackJAX-style kernel (:class:`RWState`, :class:`RWInfo`, :func:`build_kernel`).
* :func:`run_seed_mh` (seed_mh.py): the seed's coin-toss sampler, as a baseline.
* :func:`fit_grad` (grad.py): multi-start Levenberg-Marquardt with a Gauss-Newton uncertainty,
  each interval checked against the profile likelihood (:func:`profile_check`, profile.py);
  a fit that the check shows stopped short is fitted again from the better point.
* :func:`summarize_mh`, :func:`summarize_grad` (summary.py): one JSON-ready dict shape.

Typical use::

    problem = Problem(scene, observation)                # likelihood="gaussian_iid", sd_model=0.05
    mh = run_mh(problem, jax.random.key(0))               # 16 chains, 200 warm-up + 200 draws
    report = summarize_mh(mh, problem.space)
    fit = fit_grad(problem, jax.random.key(1))            # FD Jacobian, 4 screened starts
    report = summarize_grad(fit, problem.space)
    seed = run_seed_mh(problem, jax.random.key(2))        # seed baseline: 16 x 75, coin toss
"""

from galileo_jax.inference.fixed import FixedProblem
from galileo_jax.inference.grad import GradResult, fit_grad
from galileo_jax.inference.joint import JointProblem
from galileo_jax.inference.mh import MHResult, RWInfo, RWState, build_kernel, random_walk, run_mh
from galileo_jax.inference.problem import Problem, fd_jacobian_fn, simulated_observation
from galileo_jax.inference.profile import ProfileCheck, profile_check
from galileo_jax.inference.seed_mh import SeedResult, run_seed_mh
from galileo_jax.inference.summary import summarize_grad, summarize_mh

__all__ = ["Problem", "ProfileCheck", "profile_check", "JointProblem", "FixedProblem", "fd_jacobian_fn", "simulated_observation", "run_mh", "MHResult", "RWState", "RWInfo",
           "build_kernel", "random_walk", "run_seed_mh", "SeedResult", "fit_grad", "GradResult",
           "summarize_mh", "summarize_grad"]
