"""Privileged-observation PointNav: the goal vector plus range readings instead of pixels.

Used to show that the task, reward and episode set are learnable at CPU budgets before
spending pixel-SAC compute (docs/studies/privileged_agent.md). Same scenes, episodes, dynamics,
reward and metrics as `vid2sim/PointNav-v0` (it subclasses `NavEnv`); only the observation differs and the camera is
not rendered. Observation (float32, flat):
  [distance / 30, heading / pi,
   N mesh ranges / R  (pybullet `rayTestBatch` from the robot centre at 0.3 m height against the
                       collision mesh and obstacles, rays over [-fov/2, fov/2] around the heading),
   N walkable ranges / R (the same rays marched over the walkable map in 0.1 m steps: distance to
                          the first non-walkable cell, since leaving the map also ends an episode)]
with R = `max_range` metres (readings saturate at 1).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Optional

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from vid2sim.envs.nav_env import NavEnv
from vid2sim.envs.sensing import RAY_HEIGHT, mesh_ranges, ray_angles, walkable_ranges, world_grid

PRIVILEGED_ID = "vid2sim/PointNavPrivileged-v0"


class PrivilegedNavEnv(NavEnv):
    def __init__(self, *args: Any, n_rays: int = 11, fov_deg: float = 200.0, max_range: float = 5.0,
                 ray_height: float = RAY_HEIGHT, max_steps: Optional[int] = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if max_steps:  # a shorter training horizon (truncation, bootstrapped); evaluation keeps 3000
            self.config = replace(self.config, reward=replace(self.config.reward, max_steps=max_steps))
        self.n_rays, self.max_range, self.ray_height = n_rays, max_range, ray_height
        self.angles = ray_angles(n_rays, fov_deg)
        self.observation_space = spaces.Box(-1.0, 1e3, (2 + 2 * n_rays,), np.float32)

    def _frame(self) -> np.ndarray:
        """No camera: the privileged agent does not see pixels (saves the render)."""
        return np.zeros((1, 1, 1), np.uint8)

    def render(self) -> Optional[np.ndarray]:
        """rgb_array: the camera view at the current pose [H, W, 3] (for videos; the agent never sees it)."""
        if self.render_mode != "rgb_array" or self.episode is None:
            return None
        return NavEnv._frame(self).transpose(1, 2, 0)

    def ranges(self) -> tuple[np.ndarray, np.ndarray]:
        """(mesh ranges, walkable ranges) in metres, one per ray (`envs/sensing.py`)."""
        x, y, yaw = self.state.x, self.state.y, self.state.yaw
        mesh = mesh_ranges(self.world.physics, x, y, yaw, self.angles, self.max_range, self.ray_height)
        return mesh, walkable_ranges(world_grid(self.world), x, y, yaw, self.angles, self.max_range)

    def _obs(self) -> np.ndarray:  # type: ignore[override]
        dist_heading = self._goal_vector()
        mesh, walk = self.ranges()
        return np.concatenate([[dist_heading[0] / 30.0, dist_heading[1]], mesh / self.max_range,
                               walk / self.max_range]).astype(np.float32)


def register() -> None:
    if PRIVILEGED_ID not in gym.registry:
        gym.register(PRIVILEGED_ID, entry_point="vid2sim.training.privileged:PrivilegedNavEnv",
                     kwargs={"task": "pointnav"})


register()


def make(registry: str, scenes: Any, **kwargs: Any) -> gym.Env:
    return gym.make(PRIVILEGED_ID, registry=registry, scenes=scenes, **kwargs)

