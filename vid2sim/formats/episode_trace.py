"""Episode trace: what happened in one recorded episode, step by step, for replay.

`<name>.trace.json` sits beside the episode's `<name>.mp4` (camera view left of a top-down map;
video frame k is trace step k: the reset, then one per control step). Layout (schema 1):
  schema "vid2sim.episode/1", scene_id, registry (root the scene came from, or null), fps,
  robot {length_m, width_m, height_m}, goal [x, y], planned_path [[x, y], ...],
  xy [[x, y], ...] and yaw [rad, ...] of the robot per step, collided [bool, ...] per step,
  obstacles [[[x, y], ...], ...] and pedestrians [[[x, y], ...], ...] per step,
  end (the episode's end reason, '' while unfinished), video (MP4 file name or null),
  view_width_px (width of the camera-view panel at the left of each video frame).
Positions are metres in the scene's world frame (z up, ground at z = 0).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np

from vid2sim.formats.errors import BundleError, PathLike

SCHEMA = "vid2sim.episode/1"
TRACE_SUFFIX = ".trace.json"


def _xy_list(a: Any) -> list[list[float]]:
    return [[float(x), float(y)] for x, y in np.asarray(a, np.float64).reshape(-1, 2)]


@dataclass
class EpisodeTrace:
    scene_id: str
    robot: dict[str, float]
    goal: list[float]
    planned_path: list[list[float]]
    fps: float = 5.0
    registry: Optional[str] = None
    xy: list[list[float]] = field(default_factory=list)
    yaw: list[float] = field(default_factory=list)
    collided: list[bool] = field(default_factory=list)
    obstacles: list[list[list[float]]] = field(default_factory=list)
    pedestrians: list[list[list[float]]] = field(default_factory=list)
    end: str = ""
    video: Optional[str] = None
    view_width_px: int = 0
    schema: str = SCHEMA

    @property
    def steps(self) -> int:
        return len(self.xy)

    def append(self, xy: Any, yaw: float, collided: bool, obstacles: Any, pedestrians: Any) -> None:
        """Add one step (robot pose, contact flag, obstacle and pedestrian positions [N, 2])."""
        self.xy.append(_xy_list(xy)[0])
        self.yaw.append(float(yaw))
        self.collided.append(bool(collided))
        self.obstacles.append(_xy_list(obstacles))
        self.pedestrians.append(_xy_list(pedestrians))

    def write(self, path: PathLike) -> Path:
        path = Path(path)
        path.write_text(json.dumps(asdict(self)))
        return path


def trace_path(video: PathLike) -> Path:
    """The trace file beside an episode MP4."""
    video = Path(video)
    return video.with_name(video.stem + TRACE_SUFFIX)


def read_trace(path: PathLike) -> EpisodeTrace:
    """Read and check a trace file; raise BundleError naming the file and the reason."""
    path = Path(path)
    if not path.is_file():
        raise BundleError(path, "missing episode trace")
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise BundleError(path, f"unreadable JSON ({e})") from None
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        raise BundleError(path, f"not an episode trace (schema must be {SCHEMA!r})")
    try:
        trace = EpisodeTrace(**data)
    except TypeError as e:
        raise BundleError(path, f"wrong trace fields ({e})") from None
    n = trace.steps
    if n == 0:
        raise BundleError(path, "episode trace has no steps")
    if not all(len(getattr(trace, k)) == n for k in ("yaw", "collided", "obstacles", "pedestrians")):
        raise BundleError(path, "xy, yaw, collided, obstacles and pedestrians must have one entry per step")
    return trace
