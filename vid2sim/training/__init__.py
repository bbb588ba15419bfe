"""Training: rollouts, SAC, evaluation, study and policy export (built on `vid2sim.envs`)."""
