"""Per-step cost of the env's asset side at 128x72: obstacles, pedestrians, augmentation,
compositing and the recorder's frame, in ms of process CPU time (wall time is printed too).

Usage: .venv/bin/python benchmarks/envs_assets.py [--people 5] [--reps 300] [--quick]
"""

from __future__ import annotations

import argparse
import time
from typing import Callable

import numpy as np
import pybullet as pb

from common import Run, add_run_args
from vid2sim.envs.augment import AugmentConfig, Augmenter
from vid2sim.envs.compositing import composite
from vid2sim.envs.obstacles import OBSTACLE_KINDS, ObstacleSet, Placement, make_obstacle
from vid2sim.envs.pedestrians import Crowd
from vid2sim.envs.planning import GridPlanner
from vid2sim.envs.recording import TopdownMap, side_by_side
from vid2sim.formats.walkable import WalkableGrid

W, H = 128, 72
K = np.array([[64.0, 0.0, 64.0], [0.0, 64.0, 36.0], [0.0, 0.0, 1.0]])


def camera(x: float, y: float, yaw: float, height: float = 0.6) -> np.ndarray:
    """World -> OpenCV camera [4, 4] looking along yaw."""
    R = np.stack([[np.sin(yaw), -np.cos(yaw), 0.0], [0.0, 0.0, -1.0], [np.cos(yaw), np.sin(yaw), 0.0]])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, -R @ np.array([x, y, height])
    return T


def timed(fn: Callable[[], object], reps: int) -> tuple[float, float]:
    """(CPU ms, wall ms) per call."""
    fn()
    t, c = time.perf_counter(), time.process_time()
    for _ in range(reps):
        fn()
    return (time.process_time() - c) / reps * 1e3, (time.perf_counter() - t) / reps * 1e3


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--people", type=int, default=5)
    ap.add_argument("--reps", type=int, default=300)
    ap.add_argument("--quick", action="store_true", help="60 calls per part (smoke run)")
    add_run_args(ap)
    args = ap.parse_args()
    reps = 60 if args.quick and args.reps == 300 else args.reps
    with Run("envs_assets", args) as run:
        measure(run, args.people, reps)


def measure(run: Run, people: int, reps: int) -> None:
    rng = np.random.default_rng(0)
    cid = pb.connect(pb.DIRECT)
    grid = WalkableGrid(np.ones((200, 300), np.uint8), np.zeros(2), 0.1)  # 30 x 20 m plaza
    obstacles = ObstacleSet(cid, [Placement(make_obstacle(k, rng), (4.0 + 1.5 * i, 10.0 + 0.5 * i))
                                  for i, k in enumerate(OBSTACLE_KINDS)])
    crowd = Crowd(GridPlanner(grid), people, rng, cid)
    aug = Augmenter(AugmentConfig(enabled=True, fog_prob=1.0, rain_prob=1.0))
    aug.reset(rng)
    w2c = camera(1.0, 10.0, 0.0)
    base = (np.full((H, W, 3), 120, np.uint8), np.full((H, W), 12.0, np.float32))
    layer = obstacles.draw(K, w2c, W, H)
    tmap = TopdownMap(grid.grid, grid.origin, grid.resolution)
    state = {"goal": np.array([20.0, 10.0]), "robot_xy": np.array([1.0, 10.0]), "robot_yaw": 0.0,
             "path": np.array([[0.0, 10.0], [1.0, 10.0]]), "planned_path": np.array([[1.0, 10.0], [20.0, 10.0]]),
             "obstacles": obstacles.positions, "pedestrians": crowd.positions}
    parts = {
        f"obstacles.draw ({len(obstacles.placements)} obstacles, {len(obstacles.mesh_arrays()[1])} faces)":
            lambda: obstacles.draw(K, w2c, W, H),
        f"crowd.step ({people} people, incl. re-planning)": lambda: crowd.step(0.2, (1.0, 10.0)),
        f"crowd.draw ({people} people, {len(crowd.mesh_arrays()[1])} faces)":
            lambda: crowd.draw(K, w2c, W, H),
        "composite (one layer)": lambda: composite(*base, *layer),
        "augment.apply (exposure, tint, fog, rain)": lambda: aug.apply(*base),
        "recorder frame (map + view, 800x288)": lambda: side_by_side(base[0], tmap.draw(state)),
    }
    for name, fn in parts.items():
        cpu, wall = timed(fn, reps)
        run.record_all(name, {"cpu_ms": cpu, "wall_ms": wall}, "ms/call", {"reps": reps, "image": f"{W}x{H}"})
        print(f"{name}: {cpu:.3f} ms CPU, {wall:.3f} ms wall")
    pb.disconnect(cid)


if __name__ == "__main__":
    main()
