"""A small real gymnasium env for testing env wrappers without a registry scene.

A point robot drives on a hand-made walkable grid (GridPlanner), sees a ground plane and
procedural obstacles (real pybullet bodies) through the env rasteriser, and exposes
`topdown_state()` like vid2sim.envs.nav_env.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pybullet as pb

from vid2sim.envs.compositing import composite
from vid2sim.envs.obstacles import ObstacleSet, Placement, make_obstacle
from vid2sim.envs.planning import GridPlanner
from vid2sim.formats.walkable import WalkableGrid
from vid2sim.envs.raster import rasterize

W, H = 128, 72
K = np.array([[64.0, 0.0, 64.0], [0.0, 64.0, 36.0], [0.0, 0.0, 1.0]])
GROUND = (np.array([[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]], np.float32),
          np.array([[0, 1, 2], [0, 2, 3]], np.int32), np.array([[90, 110, 90]] * 2, np.uint8))


def camera(x: float, y: float, yaw: float, height: float = 0.6) -> np.ndarray:
    """World -> OpenCV camera [4, 4] for a camera at (x, y, height) looking along yaw."""
    fwd = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    R = np.stack([np.array([np.sin(yaw), -np.cos(yaw), 0.0]), [0.0, 0.0, -1.0], fwd])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, -R @ np.array([x, y, height])
    return T


class GridNavEnv(gym.Env):
    """Point robot on a 10 x 6 m grid with a blocked strip; episodes end after max_steps."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 5}

    def __init__(self, max_steps: int = 12, render_mode: str | None = "rgb_array") -> None:
        grid = np.ones((60, 100), np.uint8)
        grid[25:35, 40:60] = 0
        self.grid = WalkableGrid(grid, np.array([0.0, 0.0]), 0.1)
        self.planner = GridPlanner(self.grid)
        self.max_steps, self.render_mode = max_steps, render_mode
        self.observation_space = gym.spaces.Dict({
            "image": gym.spaces.Box(0, 255, (1, 3, H, W), np.uint8),
            "vector": gym.spaces.Box(-np.inf, np.inf, (2,), np.float32)})
        self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.client = pb.connect(pb.DIRECT)
        self.obstacles: ObstacleSet | None = None

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        if self.obstacles is not None:
            self.obstacles.remove()
        self.xy, self.yaw, self.t = np.array([1.0, 3.0]), 0.0, 0
        self.goal = np.array([9.0, 3.0])
        self.planned = self.planner.plan(tuple(self.xy), tuple(self.goal))
        self.trace = [self.xy.copy()]
        kinds = ("traffic_cone", "trash_bin")
        self.obstacles = ObstacleSet(self.client, [
            Placement(make_obstacle(k, self.np_random), (3.0 + 2 * i, 2.2)) for i, k in enumerate(kinds)])
        return self._obs(), {}

    def step(self, action):
        a = np.clip(np.asarray(action, np.float64), -1, 1)
        self.yaw += 0.3 * a[1]
        self.xy = self.xy + 0.3 * max(a[0], 0.0) * np.array([np.cos(self.yaw), np.sin(self.yaw)])
        self.trace.append(self.xy.copy())
        self.t += 1
        dist = float(np.linalg.norm(self.goal - self.xy))
        return self._obs(), -0.1, dist < 0.5, self.t >= self.max_steps, {}

    def _view(self) -> np.ndarray:
        w2c = camera(*self.xy, self.yaw)
        ground = rasterize(*GROUND, K, w2c, W, H)
        return composite(*ground, *self.obstacles.draw(K, w2c, W, H))[0]

    def _obs(self):
        self._last = self._view()
        d = self.goal - self.xy
        return {"image": self._last.transpose(2, 0, 1)[None].copy(),
                "vector": np.array([np.hypot(*d), np.arctan2(d[1], d[0]) - self.yaw], np.float32)}

    def render(self):
        return self._last if self.render_mode == "rgb_array" else None

    def topdown_state(self) -> dict:
        return {"grid": self.grid.grid, "origin": self.grid.origin, "resolution": self.grid.resolution,
                "robot_xy": self.xy, "robot_yaw": self.yaw, "path": np.array(self.trace),
                "planned_path": self.planned, "goal": self.goal,
                "obstacles": self.obstacles.positions, "pedestrians": np.array([[5.0, 1.0]])}

    def close(self) -> None:
        if pb.isConnected(self.client):
            pb.disconnect(self.client)
