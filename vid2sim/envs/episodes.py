"""Episode sampling: start and goal on the walkable map joined by an A* path of a given length.

Start and goal lie on `ends` cells when given (cells `EpisodeConfig.end_clearance` from blocked
ones, where the robot can turn; `end_cells`), else on the planner's free cells. A random start
from which no goal lies far enough (the middle of a narrow map whose longest path is close to the
range's lower end) is moved to the farthest point from it.

Geodesic range: 10-30 m (the paper) when the map's longest A* path allows, else from 70 % of
the longest path up to it, never below 5 m (the paper's real-world range): a map whose longest
path is shorter than 5 m is refused with `SceneError("map_too_small")`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np
from scipy import ndimage

from vid2sim.envs.config import EpisodeConfig
from vid2sim.envs.planning import GridPlanner, inflate, path_length
from vid2sim.envs.scenes import SceneError

MAX_TRIES = 64


@dataclass(frozen=True)
class Episode:
    scene_id: str
    start: np.ndarray  # [2] m
    start_yaw: float  # rad
    goal: np.ndarray  # [2] m
    path: np.ndarray  # [K, 2] A* waypoints start -> goal
    geodesic: float  # m, length of `path`


def longest_path(planner: GridPlanner) -> float:
    """Approximate geodesic diameter (m) of the largest free component (double sweep)."""
    labels, n = ndimage.label(planner.free, structure=np.ones((3, 3)))
    if n == 0:
        return 0.0
    sizes = np.bincount(labels.ravel())[1:]
    rows, cols = np.nonzero(labels == 1 + int(np.argmax(sizes)))
    p = planner.to_world(rows[0], cols[0])
    for _ in range(2):
        d = planner.distance_field((float(p[0]), float(p[1])))
        far = np.unravel_index(np.argmax(np.where(np.isfinite(d), d, -1)), d.shape)
        p = planner.to_world(*far)
    return float(d[far])


def geodesic_range(planner: GridPlanner, conf: EpisodeConfig, scene_id: str = "") -> tuple[float, float]:
    """(lo, hi) geodesic start-goal length for this map, or SceneError('map_too_small')."""
    diam = longest_path(planner)
    lo, hi = conf.geodesic_range
    if diam >= lo:
        return lo, min(hi, diam)
    if diam < conf.min_geodesic:
        raise SceneError("map_too_small", f"scene {scene_id!r}: the walkable map's longest A* path "
                         f"is {diam:.1f} m (< {conf.min_geodesic:.0f} m) after {conf.clearance} m "
                         "clearance")
    return max(conf.min_geodesic, 0.7 * diam), diam


def end_cells(planner: GridPlanner, clearance: float) -> np.ndarray:
    """Free cells at least `clearance` m (planner's convention) from blocked cells [H, W] bool;
    the planner's free cells when there is none."""
    cells = inflate(planner.raw > 0, clearance / planner.resolution) & planner.free
    return cells if cells.any() else planner.free.copy()


def sample_episode(planner: GridPlanner, rng: np.random.Generator, span: tuple[float, float],
                   conf: EpisodeConfig, scene_id: str = "", ends: Optional[np.ndarray] = None
                   ) -> Episode:
    """Random start, a goal whose A* geodesic length lies in span, facing along the path;
    both on `ends` cells [H, W] bool when given (see `end_cells`)."""
    lo, hi = span
    ends = planner.free if ends is None else ends
    for _ in range(MAX_TRIES):
        start = _sample_cell(planner, ends, rng)
        d = planner.distance_field(start)  # [H, W] m
        if not np.any(np.isfinite(d) & (d >= lo) & ends):  # a start in the middle of a narrow
            start = _farthest(planner, d, ends, rng)  # map: restart from its far end (double sweep)
            d = planner.distance_field(start)
        rows, cols = np.nonzero((d >= lo) & (d <= 1.1 * hi) & ends)  # the smoothed path is shorter
        if len(rows) == 0:
            continue
        i = int(rng.integers(len(rows)))
        g = planner.to_world(rows[i], cols[i])
        path = planner.plan(start, (float(g[0]), float(g[1])))
        if path is None or not lo <= path_length(path) <= hi:
            continue
        return Episode(scene_id, np.asarray(start), _start_yaw(path, rng, conf), g, path,
                       path_length(path))
    raise SceneError("no_episode", f"scene {scene_id!r}: no start/goal pair with a {lo:.1f}-"
                     f"{hi:.1f} m A* path in {MAX_TRIES} tries")


def _sample_cell(planner: GridPlanner, cells: np.ndarray, rng: np.random.Generator) -> tuple[float, float]:
    """A uniformly random point inside a random cell of the mask cells [H, W] bool."""
    rows, cols = np.nonzero(cells)
    if len(rows) == 0:
        raise ValueError("walkable grid has no free cell (after clearance inflation)")
    i = int(rng.integers(len(rows)))
    p = planner.to_world(rows[i], cols[i]) + rng.uniform(-0.4, 0.4, size=2) * planner.resolution
    return float(p[0]), float(p[1])


def _farthest(planner: GridPlanner, d: np.ndarray, ends: np.ndarray, rng: np.random.Generator
              ) -> tuple[float, float]:
    """A random point in the end cell (ends [H, W] bool; any cell when none is reachable)
    farthest (geodesic distance field d [H, W]) from a start."""
    reach = np.isfinite(d)
    if (reach & ends).any():
        reach &= ends
    far = np.unravel_index(np.argmax(np.where(reach, d, -1.0)), d.shape)
    p = planner.to_world(*far) + rng.uniform(-0.4, 0.4, size=2) * planner.resolution
    return float(p[0]), float(p[1])


def _start_yaw(path: np.ndarray, rng: np.random.Generator, conf: EpisodeConfig) -> float:
    """Heading towards the path point ~1 m ahead, plus uniform noise."""
    seg = np.cumsum(np.r_[0.0, np.linalg.norm(np.diff(path, axis=0), axis=1)])
    ahead = path[min(int(np.searchsorted(seg, 1.0)), len(path) - 1)] - path[0]
    noise = math.radians(conf.start_yaw_noise_deg) * rng.uniform(-1.0, 1.0)
    return math.atan2(ahead[1], ahead[0]) + noise
