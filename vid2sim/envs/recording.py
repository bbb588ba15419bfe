"""Episode recording: an MP4 of the robot's view beside a top-down map.

`RecordEpisode(env, folder)` wraps any env whose `unwrapped.topdown_state()` returns the
TEAM.md dict (`grid` [H, W] walkable 0/1 with rows along +y, `origin` (x, y) of cell [0, 0]'s
lower-left corner and `resolution` m/cell (defaults (0, 0) and 0.1), `robot_xy`, `robot_yaw`,
`path` (taken), `planned_path`, `goal`, `obstacles` [N, 2], `pedestrians` [P, 2]). The view is
`env.render()` when it returns an image, else the newest frame of `obs["image"]`. One file per
episode (`<prefix>-<k>.mp4`, OpenCV mp4v), one video frame per reset and per step, closed when
the episode ends or the wrapper closes.

Map colours: walkable light grey, blocked dark grey, planned path blue, path taken green,
obstacles orange, pedestrians magenta, goal red, robot yellow with its heading.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional, Protocol

import cv2
import gymnasium as gym
import numpy as np

PANEL_H = 288  # px: height of both panels
BGR = {"free": (205, 205, 205), "blocked": (60, 60, 60), "planned": (220, 120, 30),
       "taken": (40, 190, 40), "obstacle": (20, 120, 250), "pedestrian": (200, 40, 200),
       "goal": (30, 30, 230), "robot": (0, 220, 255)}


class TopdownMap:
    """Draws topdown_state dicts on a fixed-size map image of one walkable grid."""

    def __init__(self, grid: np.ndarray, origin, resolution: float, height: int = PANEL_H) -> None:
        g = np.asarray(grid) > 0  # [Hg, Wg], row 0 at the lowest y
        self.origin = np.asarray(origin, np.float64).reshape(2)
        self.resolution = float(resolution)
        self.scale = height / g.shape[0]  # px per cell
        width = max(2, int(round(g.shape[1] * self.scale)) // 2 * 2)
        base = np.where(g[::-1, :, None], BGR["free"], BGR["blocked"]).astype(np.uint8)
        self.base = cv2.resize(base, (width, height), interpolation=cv2.INTER_NEAREST)

    def px(self, xy: np.ndarray) -> np.ndarray:
        """World points [N, 2] -> map pixels [N, 2] int (x right, y down = -world y)."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        cells = (xy - self.origin) / self.resolution  # [N, 2] (col, row) continuous
        u = cells[:, 0] * self.scale
        v = self.base.shape[0] - cells[:, 1] * self.scale
        return np.round(np.stack([u, v], 1)).astype(np.int32)

    def draw(self, state: dict[str, Any]) -> np.ndarray:
        """The map [PANEL_H, W, 3] BGR u8 with paths, obstacles, people, goal and robot."""
        img = self.base.copy()
        r = max(2, int(round(0.3 / self.resolution * self.scale)))
        for key, color in (("planned_path", "planned"), ("path", "taken")):
            pts = np.asarray(state.get(key, np.zeros((0, 2))), np.float64).reshape(-1, 2)
            if len(pts) >= 2:
                cv2.polylines(img, [self.px(pts)], False, BGR[color], 2, cv2.LINE_AA)
        for key, color in (("obstacles", "obstacle"), ("pedestrians", "pedestrian")):
            for p in self.px(np.asarray(state.get(key, np.zeros((0, 2))), np.float64)):
                cv2.circle(img, tuple(int(c) for c in p), r, BGR[color], -1, cv2.LINE_AA)
        goal = self.px(np.asarray(state["goal"])[:2])[0]
        cv2.drawMarker(img, tuple(int(c) for c in goal), BGR["goal"], cv2.MARKER_STAR, 3 * r, 2)
        self._robot(img, np.asarray(state["robot_xy"])[:2], float(state["robot_yaw"]), r)
        return img

    def _robot(self, img: np.ndarray, xy: np.ndarray, yaw: float, r: int) -> None:
        c, s = np.cos(yaw), np.sin(yaw)
        tri = np.array([[1.6, 0.0], [-1.0, 0.9], [-1.0, -0.9]]) * 0.35  # m, robot frame
        world = xy + tri @ np.array([[c, s], [-s, c]])
        cv2.fillPoly(img, [self.px(world)], BGR["robot"], cv2.LINE_AA)


def side_by_side(view_rgb: np.ndarray, map_bgr: np.ndarray) -> np.ndarray:
    """View (RGB, scaled to the map's height) left of the map: one BGR frame."""
    h = map_bgr.shape[0]
    w = max(2, int(round(view_rgb.shape[1] * h / view_rgb.shape[0])) // 2 * 2)
    view = cv2.resize(np.ascontiguousarray(view_rgb[..., ::-1]), (w, h), interpolation=cv2.INTER_NEAREST)
    return np.concatenate([view, map_bgr], axis=1)


def _view_from_obs(obs: Any) -> Optional[np.ndarray]:
    """Newest frame [H, W, 3] of a stacked image observation ([S, C, H, W] or [S*C, H, W])."""
    img = obs.get("image") if isinstance(obs, dict) else obs
    if img is None or np.ndim(img) < 3:
        return None
    img = np.asarray(img)
    last = img[-1] if img.ndim == 4 else img[-3:] if img.shape[0] % 3 == 0 else img[-1:]
    last = np.repeat(last, 3, 0) if last.shape[0] == 1 else last
    return np.ascontiguousarray(last.transpose(1, 2, 0)).astype(np.uint8)


class RecordEpisode(gym.Wrapper):
    """Writes every episode (or those `episode_trigger(k)` selects) to `folder` as MP4."""

    def __init__(self, env: gym.Env, folder: str | Path, name_prefix: str = "episode",
                 fps: int = 5, episode_trigger=None) -> None:
        super().__init__(env)
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.name_prefix, self.fps = name_prefix, fps
        self.episode_trigger = episode_trigger or (lambda k: True)
        self.episode = -1
        self.paths: list[Path] = []
        self._writer: Optional[cv2.VideoWriter] = None
        self._map: Optional[TopdownMap] = None
        self.frames_written = 0

    def reset(self, **kwargs):
        self._finish()
        obs, info = self.env.reset(**kwargs)
        self.episode += 1
        if self.episode_trigger(self.episode):
            state = self.env.unwrapped.topdown_state()
            self._map = TopdownMap(state["grid"], state.get("origin", (0.0, 0.0)),
                                   state.get("resolution", 0.1))
            self._write(obs, state)
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        if self._map is not None:
            self._write(obs, self.env.unwrapped.topdown_state())
            if terminated or truncated:
                self._finish()
        return obs, reward, terminated, truncated, info

    def _write(self, obs: Any, state: dict[str, Any]) -> None:
        view = self.env.render() if getattr(self.env, "render_mode", None) == "rgb_array" else None
        view = view if isinstance(view, np.ndarray) and view.ndim == 3 else _view_from_obs(obs)
        frame = side_by_side(view, self._map.draw(state))
        if self._writer is None:
            path = self.folder / f"{self.name_prefix}-{self.episode}.mp4"
            self._writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), self.fps,
                                           (frame.shape[1], frame.shape[0]))
            if not self._writer.isOpened():
                raise RuntimeError(f"OpenCV cannot open an mp4v writer for {path}")
            self.paths.append(path)
            self.frames_written = 0
        self._writer.write(frame)
        self.frames_written += 1

    def _finish(self) -> None:
        if self._writer is not None:
            self._writer.release()
        self._writer, self._map = None, None

    def close(self) -> None:
        self._finish()
        super().close()


class Agent(Protocol):
    """What `record_episodes` drives: the scripted expert's interface."""

    def reset(self, env: gym.Env) -> None: ...

    def act(self, env: gym.Env) -> np.ndarray: ...


def record_episodes(env: gym.Env, folder: str | Path, episodes: int, agent: Agent,
                    seed: int = 0, fps: int = 5) -> list[Path]:
    """Run `episodes` episodes of `agent` in env (seeds seed, seed + 1, ...), one MP4 each."""
    rec = RecordEpisode(env, folder, fps=fps)
    try:
        for k in range(episodes):
            rec.reset(seed=seed + k)
            agent.reset(rec)
            done = False
            while not done:
                _, _, terminated, truncated, _ = rec.step(agent.act(rec))
                done = terminated or truncated
    finally:
        rec.close()
    return rec.paths
