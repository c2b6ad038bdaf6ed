"""The criticism stage: where does the fitted model fail, and which physics is missing?

* :mod:`.residuals`: the fitted simulation against the video: the residual table per motion
  phase and trace, the one-line verdict, the adequacy check; from :mod:`.phases` (which samples
  are ramp, floor, collision, rest), :mod:`.noise` (each sample's SD, the noise floor, the
  tracking noise measured again) and :mod:`.structure` (tests for structure: runs, lag-1
  correlation, CUSUM drift, chi-square spread).
* :mod:`.diagnosis`: :func:`~galileo_jax.criticism.diagnosis.diagnose`, the loop that fits,
  criticises, screens candidate effects, refits and decides (its docstring: why each step);
  its steps: :mod:`.nested` (adequacy, likelihood-ratio tests of nested models, the null at its
  maximum), :mod:`.screening` (the candidates ranked at the current fit), :mod:`.models` (the
  models compared and their fits), :mod:`.settings` (:class:`DiagnoseSettings`, with what each
  default was measured on).
"""
