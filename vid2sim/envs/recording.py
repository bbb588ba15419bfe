"""Episode recording: an MP4 of the robot's view beside a top-down map.

`RecordEpisode(env, folder)` wraps any env whose `unwrapped.topdown_state()` returns the
top-down state dict (`grid` [H, W] walkable 0/1 with rows along +y, `origin` (x, y) of cell [0, 0]'s
lower-left corner and `resolution` m/cell (defaults (0, 0) and 0.1), `robot_xy`, `robot_yaw`,
`path` (taken), `planned_path`, `goal`, `obstacles` [N, 2], `pedestrians` [P, 2]). The view is
`env.render()` when it returns an image, else the newest frame of `obs["image"]`. One file per
episode (`<prefix>-<k>.mp4`, OpenCV mp4v), one video frame per reset and per step, closed when
the episode ends or the wrapper closes; beside it `<prefix>-<k>.trace.json`, the episode's steps
for replay in the viewer (`vid2sim.formats.episode_trace`).

Map colours: walkable light grey, blocked dark grey, planned path blue, path taken green,
obstacles orange, pedestrians magenta, goal red, robot yellow with its heading.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional, Protocol

import cv2
import gymnasium as gym
import numpy as np

from vid2sim.formats.episode_trace import EpisodeTrace, trace_path

PANEL_H = 288  # px: height of both panels
MAP_W = 512  # px: width of the map panel
BGR = {"free": (205, 205, 205), "blocked": (60, 60, 60), "planned": (220, 120, 30),
       "taken": (40, 190, 40), "obstacle": (20, 120, 250), "pedestrian": (200, 40, 200),
       "goal": (30, 30, 230), "robot": (0, 220, 255)}


class TopdownMap:
    """Draws topdown_state dicts on a fixed-size map image of one walkable grid.

    The grid is cropped to the `focus` points (the episode: planned path, robot, goal) or,
    without them, to the walkable cells, plus CROP_MARGIN m, widened towards the panel's
    aspect where the grid allows, and fitted (aspect kept) into a PANEL_H x MAP_W box."""

    CROP_MARGIN = 3.0  # m

    def __init__(self, grid: np.ndarray, origin, resolution: float, height: int = PANEL_H,
                 width: int = MAP_W, focus: Optional[np.ndarray] = None) -> None:
        g = np.asarray(grid) > 0  # [Hg, Wg], row 0 at the lowest y
        self.resolution = float(resolution)
        origin = np.asarray(origin, np.float64).reshape(2)
        if focus is not None and len(focus):
            cells = np.floor((np.asarray(focus, np.float64).reshape(-1, 2) - origin) / self.resolution)
            rows, cols = cells[:, 1].astype(int), cells[:, 0].astype(int)
        else:
            rows, cols = np.nonzero(g)
        margin = int(round(self.CROP_MARGIN / self.resolution))
        r0, r1, c0, c1 = _crop(g.shape, rows, cols, margin, width / height)
        g = g[r0:r1, c0:c1]
        self.origin = origin + np.array([c0, r0]) * self.resolution
        self.scale = min(height / g.shape[0], width / g.shape[1])  # px per cell
        h, w = max(1, int(g.shape[0] * self.scale)), max(1, int(g.shape[1] * self.scale))
        self.offset = np.array([(width - w) // 2, (height - h) // 2])  # px (x, y) of the grid
        self.grid_h = h
        img = np.where(g[::-1, :, None], BGR["free"], BGR["blocked"]).astype(np.uint8)
        self.base = np.full((height, width, 3), BGR["blocked"], np.uint8)
        self.base[self.offset[1]:self.offset[1] + h, self.offset[0]:self.offset[0] + w] = cv2.resize(
            img, (w, h), interpolation=cv2.INTER_NEAREST)

    def px(self, xy: np.ndarray) -> np.ndarray:
        """World points [N, 2] -> map pixels [N, 2] int (x right, y down = -world y)."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        cells = (xy - self.origin) / self.resolution  # [N, 2] (col, row) continuous
        u = self.offset[0] + cells[:, 0] * self.scale
        v = self.offset[1] + self.grid_h - cells[:, 1] * self.scale
        return np.round(np.stack([u, v], 1)).astype(np.int32)

    def draw(self, state: dict[str, Any]) -> np.ndarray:
        """The map [PANEL_H, W, 3] BGR u8 with paths, obstacles, people, goal and robot."""
        img = self.base.copy()
        r = max(3, int(round(0.3 / self.resolution * self.scale)))
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


def _crop(shape: tuple[int, int], rows: np.ndarray, cols: np.ndarray, margin: int, aspect: float
          ) -> tuple[int, int, int, int]:
    """Bounds (r0, r1, c0, c1) of the cells rows/cols plus margin, the short side widened
    towards width/height = aspect, all clipped to the grid `shape`."""
    if len(rows) == 0:
        return 0, shape[0], 0, shape[1]
    r0, r1 = rows.min() - margin, rows.max() + margin + 1
    c0, c1 = cols.min() - margin, cols.max() + margin + 1
    h, w = r1 - r0, c1 - c0
    if w < aspect * h:
        grow = int(aspect * h - w) // 2
        c0, c1 = c0 - grow, c1 + grow
    else:
        grow = int(w / aspect - h) // 2
        r0, r1 = r0 - grow, r1 + grow
    r0, c0 = max(r0, 0), max(c0, 0)
    r1, c1 = min(r1, shape[0]), min(c1, shape[1])
    if r1 <= r0 or c1 <= c0:
        return 0, shape[0], 0, shape[1]
    return int(r0), int(r1), int(c0), int(c1)


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
        self._trace: Optional[EpisodeTrace] = None
        self.frames_written = 0

    def reset(self, **kwargs):
        self._finish()
        obs, info = self.env.reset(**kwargs)
        self.episode += 1
        if self.episode_trigger(self.episode):
            state = self.env.unwrapped.topdown_state()
            focus = [np.asarray(state[k], np.float64).reshape(-1, 2)
                     for k in ("planned_path", "robot_xy", "goal") if state.get(k) is not None]
            self._map = TopdownMap(state["grid"], state.get("origin", (0.0, 0.0)),
                                   state.get("resolution", 0.1), focus=np.concatenate(focus))
            self._trace = self._new_trace(state, info)
            self._write(obs, state)
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        if self._map is not None:
            self._write(obs, self.env.unwrapped.topdown_state(), bool(info.get("collided", False)))
            if terminated or truncated:
                self._trace.end = str(info.get("end", ""))
                self._finish()
        return obs, reward, terminated, truncated, info

    def _new_trace(self, state: dict[str, Any], info: dict) -> EpisodeTrace:
        env = self.env.unwrapped
        robot = getattr(getattr(env, "config", None), "robot", None)
        size = {k: float(getattr(robot, k, d)) for k, d in (("length_m", 0.9), ("width_m", 0.6), ("height_m", 0.6))}
        registry = getattr(env, "registry", None)
        return EpisodeTrace(scene_id=str(info.get("scene_id", getattr(getattr(env, "episode", None), "scene_id", ""))),
                            robot=size, goal=[float(v) for v in np.asarray(state["goal"]).reshape(-1)[:2]],
                            planned_path=np.asarray(state.get("planned_path", np.zeros((0, 2))),
                                                    np.float64).reshape(-1, 2).tolist(),
                            fps=float(self.fps), registry=str(getattr(registry, "root", "")) or None)

    def _write(self, obs: Any, state: dict[str, Any], collided: bool = False) -> None:
        view = self.env.render() if getattr(self.env, "render_mode", None) == "rgb_array" else None
        view = view if isinstance(view, np.ndarray) and view.ndim == 3 else _view_from_obs(obs)
        frame = side_by_side(view, self._map.draw(state))
        self._trace.append(state["robot_xy"], state["robot_yaw"], collided, state.get("obstacles", np.zeros((0, 2))),
                           state.get("pedestrians", np.zeros((0, 2))))
        self._trace.view_width_px = frame.shape[1] - self._map.base.shape[1]
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
            if self._trace is not None:
                self._trace.video = self.paths[-1].name
                self._trace.write(trace_path(self.paths[-1]))
        self._writer, self._map, self._trace = None, None, None

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
