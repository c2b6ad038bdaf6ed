"""The criticism stage: where does the fitted model fail, and which physics is missing?

* :mod:`.residuals`: the fitted simulation against the video: residuals per motion phase and
  trace, the noise floor, tests for structure, and a one-line verdict.
* :mod:`.diagnosis`: :func:`~galileo_jax.criticism.diagnosis.diagnose`, the loop that fits,
  criticises, screens candidate effects, refits and decides.
"""
