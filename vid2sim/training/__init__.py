"""Rollouts on Ray actors, SAC training, held-out evaluation, scene-count studies, policy export."""
