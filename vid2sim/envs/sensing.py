"""Range readings around the robot: what a 2-D lidar at the robot would measure (privileged).

The agents that may not see pixels read them (`training/privileged.py`), and the distillation
teacher reports them as an auxiliary target for the pixel student (`training/wrappers.py`
`TeacherLabels`). Two readings per ray, both in metres and saturating at `max_range`:
- mesh: pybullet `rayTestBatch` from (x, y, height) against the collision mesh and the obstacles
  (the robot's own body ignored);
- walkable: the same ray marched over the walkable map in `march_step` m steps, distance to the
  first cell off the map (leaving the map ends an episode too).
"""

from __future__ import annotations

import math

import numpy as np

from vid2sim.bullet import import_pybullet
from vid2sim.formats.walkable import WalkableGrid

pb = import_pybullet()

RAY_HEIGHT = 0.3  # m above the ground the rays start at (the privileged agent's and the teacher's)


def ray_angles(n_rays: int, fov_deg: float) -> np.ndarray:
    """n_rays angles [n] in radians, evenly over [-fov/2, fov/2] around the heading (left positive)."""
    return np.radians(np.linspace(-fov_deg / 2, fov_deg / 2, n_rays))


def camera_hfov_deg(width: int, focal_px: float) -> float:
    """Horizontal field of view of a pinhole camera of `width` px and focal length `focal_px`."""
    return math.degrees(2.0 * math.atan(0.5 * width / focal_px))


def world_grid(world) -> WalkableGrid:
    """The raw walkable map of a loaded `SceneWorld` as a WalkableGrid (built once per world)."""
    grid = getattr(world, "_sensing_grid", None)
    if grid is None:
        w = world.assets.walkable
        grid = WalkableGrid(np.asarray(w.grid), np.asarray(w.origin, np.float64), float(w.resolution))
        world._sensing_grid = grid
    return grid


def mesh_ranges(physics, x: float, y: float, yaw: float, angles: np.ndarray, max_range: float,
                height: float) -> np.ndarray:
    """Distance [n] along each ray to the first collision body other than the robot (max_range if none)."""
    dirs = np.stack([np.cos(yaw + angles), np.sin(yaw + angles)], axis=1)  # [n, 2]
    start = np.array([x, y, height])
    ends = start + np.concatenate([dirs * max_range, np.zeros((len(angles), 1))], axis=1)
    hits = pb.rayTestBatch([start.tolist()] * len(angles), ends.tolist(), physicsClientId=physics.client)
    return np.array([h[2] * max_range if h[0] not in (-1, physics.robot_id) else max_range for h in hits])


def walkable_ranges(grid: WalkableGrid, x: float, y: float, yaw: float, angles: np.ndarray, max_range: float,
                    march_step: float = 0.1) -> np.ndarray:
    """Distance [n] along each ray to the first non-walkable map cell (max_range if none within it)."""
    march = np.arange(march_step, max_range + 1e-9, march_step)  # [S]
    dirs = np.stack([np.cos(yaw + angles), np.sin(yaw + angles)], axis=1)  # [n, 2]
    pts = np.array([x, y]) + dirs[:, None, :] * march[None, :, None]  # [n, S, 2]
    ok = grid.lookup(pts[..., 0], pts[..., 1])  # [n, S]
    first_bad = np.where(ok.all(axis=1), len(march), np.argmin(ok, axis=1))
    return np.where(first_bad < len(march), march[np.minimum(first_bad, len(march) - 1)], max_range)
