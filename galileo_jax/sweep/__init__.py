"""Config-driven sweeps: fit many videos x methods x settings with Hydra multirun.

``python -m galileo_jax.sweep dataset=DIR method=grad,mh grad.starts=1,4`` launches one job
per (video, method, settings) combination (:mod:`galileo_jax.sweep.app`, config
``configs/sweep.yaml``); the same config runs locally in one process (Hydra's basic
launcher), in parallel processes (``hydra/launcher=joblib``), or on a Slurm cluster
(``hydra/launcher=submitit_slurm``; ``submitit_local`` is submitit's local mode). Each job
fits one video with :func:`galileo_jax.pipeline.run_fit` and writes ``job.json`` into its
folder; ``python -m galileo_jax.sweep.gather SWEEP_DIR`` collects them into one table
(:mod:`galileo_jax.sweep.gather`). Which videos a sweep covers, and each one's scene file,
comes from :mod:`galileo_jax.sweep.inputs`.
"""

from galileo_jax.sweep.inputs import METHODS, VideoItem, check_method, enumerate_dataset, explicit_videos, sweep_inputs

__all__ = ["METHODS", "VideoItem", "check_method", "enumerate_dataset", "explicit_videos", "sweep_inputs"]
