"""A small real Gymnasium env with the Vid2Sim observation layout, for the training-layer tests.

`GoalSeek-v0`: a bicycle-model robot on an empty plane must reach a goal; the observation is
a Dict of `image` (the last 6 egocentric frames, uint8 [6, 3, H, W], the goal drawn as a red
column when it is in the field of view) and `vector` (distance and heading to the goal per
stacked step), the same keys, dtypes and action semantics as `vid2sim/PointNav-v0`.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

STACK = 6


class GoalSeekEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 5}

    def __init__(self, height: int = 36, width: int = 64, arena: float = 4.0, dt: float = 0.2,
                 render_mode: str | None = None):
        self.h, self.w, self.arena, self.dt = height, width, arena, dt
        self.render_mode = render_mode
        self.observation_space = spaces.Dict({
            "image": spaces.Box(0, 255, (STACK, 3, height, width), np.uint8),
            "vector": spaces.Box(-np.inf, np.inf, (STACK, 2), np.float32)})
        self.action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)

    def _goal_polar(self) -> tuple[float, float]:
        d = self.goal - self.pos
        heading = np.arctan2(d[1], d[0]) - self.yaw
        return float(np.hypot(*d)), float((heading + np.pi) % (2 * np.pi) - np.pi)

    def _frame(self) -> np.ndarray:
        img = np.full((3, self.h, self.w), 90, np.uint8)
        img[:, self.h // 2:] = 60  # ground
        dist, heading = self._goal_polar()
        u = int(round((0.5 - heading / np.radians(90)) * (self.w - 1)))
        if 0 <= u < self.w:
            half = max(1, int(self.h / (1 + dist)))
            img[0, max(0, self.h // 2 - half):self.h // 2 + half, max(0, u - 1):u + 2] = 230
        return img

    def _push(self) -> dict:
        self.frames = np.roll(self.frames, -1, axis=0)
        self.vectors = np.roll(self.vectors, -1, axis=0)
        self.frames[-1] = self._frame()
        self.vectors[-1] = self._goal_polar()
        return {"image": self.frames.copy(), "vector": self.vectors.copy()}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self.pos = self.np_random.uniform(-self.arena, self.arena, 2)
        self.goal = self.np_random.uniform(-self.arena, self.arena, 2)
        self.yaw = float(self.np_random.uniform(-np.pi, np.pi))
        self.frames = np.zeros((STACK, 3, self.h, self.w), np.uint8)
        self.vectors = np.zeros((STACK, 2), np.float32)
        obs = self._push()
        return obs, {"distance": self._goal_polar()[0]}

    def step(self, action):
        a = np.clip(np.asarray(action, np.float64), -1, 1)
        speed, steer = (a[0] + 1) / 2 * 1.0, a[1] * np.radians(30)
        before = self._goal_polar()[0]
        self.yaw += speed / 0.8 * np.tan(steer) * self.dt
        self.pos = self.pos + speed * self.dt * np.array([np.cos(self.yaw), np.sin(self.yaw)])
        dist = self._goal_polar()[0]
        success = dist < 0.5
        out = bool(np.abs(self.pos).max() > 2 * self.arena)
        reward = (before - dist) - 0.1 + (10.0 if success else 0.0) - (10.0 if out else 0.0)
        obs = self._push()
        return obs, float(reward), bool(success or out), False, {"is_success": bool(success)}

    def render(self):
        return np.transpose(self.frames[-1], (1, 2, 0))

    def set_dt(self, dt: float) -> None:
        """A setting made through a method (the vec env replays `set_*` calls on a replaced actor)."""
        self.dt = float(dt)


gym.register("tests/GoalSeek-v0", entry_point=GoalSeekEnv, max_episode_steps=60)
