"""The physics stage: scene -> MuJoCo model -> simulated trajectories and velocity profiles.

* :mod:`.model`: :func:`~galileo_jax.physics.model.build_model`, the scene as a MuJoCo model
  (MjSpec), and the world's physics a renderer may differ in (:class:`WorldPhysics`).
* :mod:`.simulate`: the simulator as pure JAX functions of explicit state (physical parameters
  -> trajectories and velocity profiles), on either engine.
* :mod:`.simulate_c`: the C MuJoCo engine (batched ``mujoco.rollout``).

Physical effects that extend the model live in :mod:`galileo_jax.effects` (a public plugin API).
"""
