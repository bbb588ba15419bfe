"""Prioritised scenes for DAgger collection: more of the student's practice where it fails.

Each training env draws its episodes' scenes from its own group of scenes (`distill.scene_groups`).
With a priority share p > 0, an env's draw is (1 - p) uniform over its group plus p in proportion
to each scene's failure rate, the student's episodes there over the recent rounds (as prioritised
level replay scores levels, Jiang et al. 2021, with the failure rate as the score). The failure
rate is smoothed towards the pooled rate, so a scene with few episodes stays near the average, and
past rounds count with weight MEMORY per round. Reads the rounds' (scene, success) pairs; writes
each env's weights through `NavEnv.set_scene_weights`.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from stable_baselines3.common.vec_env import VecEnv

MEMORY = 0.9  # weight of a round's episodes one round later (~10 rounds in the estimate)


class ScenePriority:
    """Decayed per-scene episode counts -> each env's scene weights."""

    def __init__(self, scene_ids: Sequence[str], share: float) -> None:
        if not 0.0 <= share <= 1.0:
            raise ValueError(f"scene priority share {share} is not in [0, 1]")
        self.scene_ids = list(dict.fromkeys(scene_ids))
        self.index = {s: i for i, s in enumerate(self.scene_ids)}
        self.share = share
        self.episodes = np.zeros(len(self.scene_ids))  # [S] decayed episode counts
        self.failures = np.zeros(len(self.scene_ids))  # [S] decayed failed episodes

    def update(self, episodes: Sequence[tuple[str, bool]]) -> None:
        """Add one round's finished episodes (scene id, success); older rounds fade by MEMORY."""
        self.episodes *= MEMORY
        self.failures *= MEMORY
        for scene, success in episodes:
            if scene in self.index:
                self.episodes[self.index[scene]] += 1.0
                self.failures[self.index[scene]] += 0.0 if success else 1.0

    def failure_rates(self) -> np.ndarray:
        """[S] each scene's failure rate, smoothed by one episode at the pooled rate."""
        pooled = self.failures.sum() / self.episodes.sum() if self.episodes.sum() > 0 else 0.0
        return (self.failures + pooled) / (self.episodes + 1.0)

    def weights(self, group: Sequence[str]) -> np.ndarray:
        """[len(group)] an env's draw over its group: (1 - share) uniform + share by failure rate."""
        uniform = np.full(len(group), 1.0 / len(group))
        rates = self.failure_rates()[[self.index[s] for s in group]]
        if rates.sum() <= 0:
            return uniform
        return (1.0 - self.share) * uniform + self.share * rates / rates.sum()

    def apply(self, env: VecEnv, groups: Sequence[Sequence[str]]) -> float:
        """Send each env of `env` (env i has `groups[i]`) its weights; -> the largest weight sent."""
        largest = 0.0
        for i, group in enumerate(groups):
            if len(group) > 1:
                w = self.weights(group)
                env.env_method("set_scene_weights", w.tolist(), indices=[i])
                largest = max(largest, float(w.max()))
        return largest

    def state_dict(self) -> dict:
        return {"scene_ids": self.scene_ids, "episodes": self.episodes.tolist(), "failures": self.failures.tolist()}

    def load_state_dict(self, state: dict) -> None:
        if list(state["scene_ids"]) != self.scene_ids:
            raise ValueError("scene priority state is for other scenes than this run's")
        self.episodes = np.asarray(state["episodes"], float)
        self.failures = np.asarray(state["failures"], float)
