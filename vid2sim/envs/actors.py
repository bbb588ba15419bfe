"""Per-episode actors beside the static scene: corridor obstacles and (SocialNav) pedestrians.

`EpisodeActors.spawn` places 0-5 obstacles on the A* corridor (envs-assets' library), checks
that a path around them still exists (obstacles that would cut the route are dropped, last
first), adds the crowd, and keeps the obstacle-aware shortest path (SPL's reference) and the
expert's path (the comfortable route when `EpisodeConfig.expert_comfort` is set, see
`planning`). `draw_over` draws the
actors into the camera image by z-buffer against the splat depth.
"""

from __future__ import annotations

import math
import time
from typing import Optional, Sequence

import numpy as np
from scipy import ndimage

from vid2sim.envs.obstacles import ObstacleConfig, ObstacleSet, Placement, occupancy, place_on_corridor
from vid2sim.envs.pedestrians import BODY_RADIUS, Crowd
from vid2sim.envs.planning import GridPlanner
from vid2sim.formats.walkable import WalkableGrid

# m added around obstacle footprints for the expert route (the box's corners reach 0.54 m
# from its centre while the planner keeps 0.35 m from anything blocked)
OBSTACLE_MARGIN = 0.25


def _layer(a: np.ndarray, dtype=np.uint8) -> np.ndarray:
    """a itself when it is a writable C-contiguous array of dtype, else such a copy."""
    if a.dtype == dtype and a.flags.c_contiguous and a.flags.writeable:
        return a
    return np.array(a, dtype=dtype, order="C")


class EpisodeActors:
    """Obstacles and pedestrians of one episode in one physics client."""

    def __init__(self, client_id: int) -> None:
        self.client_id = client_id
        self.obstacles: Optional[ObstacleSet] = None
        self.crowd: Optional[Crowd] = None
        self.shortest_path: Optional[np.ndarray] = None  # [K, 2] around the obstacles
        self.expert_path: Optional[np.ndarray] = None  # [K, 2] the route the expert follows
        self.route_planner: Optional[GridPlanner] = None  # the map with the static obstacles blocked
        self.goal: Optional[tuple[float, float]] = None

    def spawn(self, grid: WalkableGrid, planner: GridPlanner, path: np.ndarray, rng: np.random.Generator,
              obstacles: ObstacleConfig, pedestrians: int, pre_inflated: float = 0.0,
              comfort: float = 0.0) -> None:
        """Place this episode's actors (call `remove` first when re-using the client).

        pre_inflated: metres the scene's map was already shrunk by (a factory map is inflated by
        its robot radius, so `planner.clearance` is smaller there); the obstacles placed here
        are not in that map, so their footprints get it added back: the expert keeps the same
        distance from an obstacle on a factory scene as on a ground-truth one. comfort: the
        expert route's preferred distance from anything blocked, in the map's convention (0: the
        expert follows the shortest path)."""
        placements = place_on_corridor(path, rng, obstacles, is_walkable=planner.is_free)
        start, goal = (float(path[0, 0]), float(path[0, 1])), (float(path[-1, 0]), float(path[-1, 1]))
        while True:
            self.route_planner = self._route_planner(grid, planner.clearance, placements, pre_inflated,
                                                     comfort)
            route = self.route_planner.plan(start, goal)
            if route is not None or not placements:
                break
            placements = placements[:-1]
        self.shortest_path = route if route is not None else path
        comfortable = self.route_planner.plan(start, goal, comfortable=True) if route is not None else None
        self.expert_path = comfortable if comfortable is not None else self.shortest_path
        self.goal = goal
        self.obstacles = ObstacleSet(self.client_id, placements)
        self.crowd = (Crowd(planner, pedestrians, rng, self.client_id, avoid=[start, goal])
                      if pedestrians > 0 else None)

    @staticmethod
    def _route_planner(grid: WalkableGrid, clearance: float, placements: Sequence[Placement],
                       pre_inflated: float = 0.0, comfort: float = 0.0) -> GridPlanner:
        """A* planner on the map with the static obstacles' footprints blocked."""
        static = [p for p in placements if not p.dynamic]
        occ = occupancy(static, grid.origin, grid.resolution, grid.grid.shape)  # [H, W] bool
        if occ.any():  # footprints grown by the margin (+ what the map's obstacles already got)
            grow = OBSTACLE_MARGIN + max(pre_inflated, 0.0)
            occ = ndimage.distance_transform_edt(~occ) <= grow / grid.resolution
        blocked = WalkableGrid((grid.grid > 0) & ~occ, grid.origin, grid.resolution)
        return GridPlanner(blocked, clearance=clearance, comfort=comfort)

    def replan(self, x: float, y: float) -> Optional[np.ndarray]:
        """A* path [K, 2] from (x, y) to the episode's goal around the static obstacles (it becomes
        the expert path), or None when there is none from there (the expert path stays)."""
        if self.route_planner is None or self.goal is None:
            return None
        route = self.route_planner.plan((x, y), self.goal, comfortable=True)
        if route is not None:
            self.expert_path = route
        return route

    def step(self, dt: float, robot_xy: tuple[float, float]) -> tuple[float, float]:
        """Advance falling obstacles and walkers by dt; returns their seconds (obstacles, people)."""
        t0 = time.process_time()
        if self.obstacles is not None:
            self.obstacles.step(dt, robot_xy)
        t1 = time.process_time()
        if self.crowd is not None:
            self.crowd.step(dt)
        return t1 - t0, time.process_time() - t1

    def draw_over(self, rgb: np.ndarray, depth: np.ndarray, K: np.ndarray, w2c: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, float, float]:
        """Obstacles then pedestrians drawn over (rgb, depth) by z-buffer (the composite of
        `compositing.composite`, in place on copies only when the arrays are not writable
        C-contiguous uint8 / float32); also returns their seconds."""
        t0 = time.process_time()
        if (self.obstacles is not None and self.obstacles.placements) or self.crowd is not None:
            rgb, depth = _layer(rgb), _layer(depth, np.float32)
        if self.obstacles is not None and self.obstacles.placements:
            self.obstacles.draw_into(K, w2c, rgb, depth)
        t1 = time.process_time()
        if self.crowd is not None:
            self.crowd.draw_into(K, w2c, rgb, depth)
        return rgb, depth, t1 - t0, time.process_time() - t1

    def obstacle_xy(self) -> np.ndarray:
        return self.obstacles.positions if self.obstacles is not None else np.zeros((0, 2))

    def pedestrian_xy(self) -> np.ndarray:
        return self.crowd.positions if self.crowd is not None else np.zeros((0, 2))

    def near_pedestrian(self, x: float, y: float, yaw: float, half_len: float, half_wid: float,
                        radius: float) -> bool:
        """True when a pedestrian's body is within `radius` m of the robot's footprint box."""
        ped = self.pedestrian_xy()  # [P, 2]
        if len(ped) == 0:
            return False
        d = ped - np.array([x, y])
        c, s = math.cos(yaw), math.sin(yaw)
        local = np.abs(np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], 1))  # [P, 2]
        gap = np.linalg.norm(np.maximum(local - np.array([half_len, half_wid]), 0.0), axis=1)
        return bool((gap - BODY_RADIUS < radius).any())

    def remove(self) -> None:
        if self.obstacles is not None:
            self.obstacles.remove()
        if self.crowd is not None:
            self.crowd.remove()
        self.obstacles = self.crowd = None
        self.shortest_path = self.expert_path = self.route_planner = self.goal = None
