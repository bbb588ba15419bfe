"""Training-only env wrappers (never used by `vid2sim eval`, which keeps the paper's episode rules).

`StuckTermination`: the bicycle robot cannot reverse and a blocked move is undone, so a robot
pressed head-on against a wall or obstacle can stay there for the rest of the episode, paying the
paper's crash penalty (-1) plus the time penalty (-0.1) every step until the step limit: a
-660 (600-step horizon) to -3300 (3000 steps) tail that dwarfs the +10 success reward and the
~+20 distance reward of a whole successful episode and swamps the critic's targets. The wrapper
ends such an episode as a failure (the paper's -10 terminal reward, `terminated`, end "stuck")
once the robot has not moved (< `min_move` m per control step) for `steps` consecutive control steps.
Standing still counts too: without it, stopping (-0.1 per step, bootstrapped over a long horizon)
looks safer to a young critic than driving past walls (-10 per crash), and SAC learns to freeze
(observed: speed < 0, i.e. stopped, on every held-out episode after 10-40k steps).

`ExpertActions`: the scripted expert's action on demand (warm-up demonstrations for SAC).

`TeacherLabels`: the scripted expert labels every state the env reaches, whoever drives
(teacher-student distillation): `info["teacher_action"]` [2] and `info["teacher_stuck"]` after
`reset` and after every step that does not end the episode. `teacher_stuck` is True while the
expert is in its blocked-pose recovery (alternating full lock): those labels depend on the
expert's own history, not on what the camera sees, and the learner drops them. When the robot
is more than `replan_distance` m from the expert's path (the student drove elsewhere, e.g. round
the other side of an obstacle), the path is re-planned from the robot's position, so the label is
the way to the goal from where the robot is, not back to a path it left. With `replan_distance`
0 it re-plans at every state: the label is then a function of the state alone (pose, map,
obstacles, goal), never of where the robot was when the path was planned; `inf`: never.
With `clearance_rays` = K > 0 it also adds `info["teacher_clearance"]` float32 [K]: what the camera
looks at, as privileged ranges (`envs/sensing.py`): K rays from the robot centre at
`RAY_HEIGHT` (`envs/sensing.py`) over the camera's horizontal field of view (left to right as seen), each the
nearer of the collision-mesh / obstacle hit and the walkable map's edge, divided by
`CLEARANCE_RANGE` m (saturating at 1). The pixel student may learn to predict it (an auxiliary target).
With `depth_grid` = (h, w) it adds `info["teacher_depth"]` uint8 [h, w]: the latest frame's depth
(obstacles and pedestrians included) as the nearest depth in each of h x w equal blocks of the
image, / `DEPTH_RANGE` m (saturating at 255): what the camera shows and how near, a dense auxiliary
target for the student's encoder (`depth_blocks`).
With `waypoints` = K > 0 it adds `info["teacher_waypoints"]` float32 [K, 2]: the teacher's route ahead
as K points `WAYPOINT_SPACING` m apart along it (from the route point nearest the robot), in the
robot's frame (x forward, y left, metres; past the goal the goal repeats): where the teacher will
drive, which a student can learn to predict and follow (Chen et al., "Learning by Cheating", 2019).
"""

from __future__ import annotations

import math
from typing import Any, Optional

import gymnasium as gym
import numpy as np

from vid2sim.envs.expert import ExpertConfig, PurePursuitExpert
from vid2sim.envs.rendering import depth_to_u8
from vid2sim.envs.sensing import RAY_HEIGHT, camera_hfov_deg, mesh_ranges, ray_angles, walkable_ranges, world_grid
from vid2sim.training.student import WAYPOINT_SPACING

STUCK = "stuck"
CLEARANCE_RANGE = 5.0  # m: the teacher's clearance readings saturate here


class StuckTermination(gym.Wrapper):
    """Terminates (failure reward) after `steps` consecutive control steps with < `min_move` m of motion."""

    def __init__(self, env: gym.Env, steps: int = 10, min_move: float = 0.02) -> None:
        super().__init__(env)
        self.steps, self.min_move = steps, min_move
        self.count = 0

    def reset(self, **kwargs: Any):
        obs, info = self.env.reset(**kwargs)
        self.count = 0
        self.pose = self.env.unwrapped.robot_pose()[:2]
        return obs, info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        u = self.env.unwrapped
        pose = u.robot_pose()[:2]
        moved = math.hypot(pose[0] - self.pose[0], pose[1] - self.pose[1])
        self.pose = pose
        self.count = self.count + 1 if moved < self.min_move else 0
        if self.count >= self.steps and not (terminated or truncated):
            reward += u.config.reward.failure
            terminated = True
            info = {**info, "end": STUCK, "nav_episode": u.record(STUCK)}
        return obs, reward, terminated, truncated, info


class TeacherError(RuntimeError):
    """The teacher cannot act in this env (no A* expert path: not a vid2sim NavEnv)."""


DEPTH_RANGE = 5.0  # m: the depth target saturates here (what is farther cannot be hit within 5 s)


def check_depth_grid(grid: tuple[int, int], image: tuple[int, int]) -> None:
    """ValueError unless the h x w grid divides the image [H, W] into equal blocks."""
    (h, w), (height, width) = grid, image
    if h < 1 or w < 1 or height % h or width % w:
        raise ValueError(f"depth_grid {h} x {w} must divide the {height} x {width} image into equal blocks")


def depth_blocks(depth: np.ndarray, grid: tuple[int, int]) -> np.ndarray:
    """Depth [H, W] in m (inf: nothing) -> uint8 [h, w]: each block's nearest depth / DEPTH_RANGE x 255."""
    h, w = grid
    H, W = depth.shape
    near = np.nan_to_num(depth, nan=np.inf).reshape(h, H // h, w, W // w).min(axis=(1, 3))  # [h, w]
    return depth_to_u8(near, DEPTH_RANGE)


class TeacherLabels(gym.Wrapper):
    """Adds the scripted expert's label of the current state to `info` (see the module docs)."""

    def __init__(self, env: gym.Env, replan_distance: float = 0.0, clearance_rays: int = 0,
                 depth_grid: Optional[tuple[int, int]] = None, lookahead: float = ExpertConfig.lookahead,
                 waypoints: int = 0) -> None:
        super().__init__(env)
        if not hasattr(env.unwrapped, "expert_path"):
            raise TeacherError(f"teacher_unavailable: env {env.unwrapped.__class__.__name__} has no A* expert "
                               "path (the scripted teacher acts only in vid2sim navigation envs)")
        if clearance_rays < 0:
            raise ValueError(f"clearance_rays must be >= 0, got {clearance_rays}")
        if not replan_distance >= 0:
            raise ValueError(f"replan_distance must be >= 0 (inf: never), got {replan_distance}")
        self.expert = PurePursuitExpert(ExpertConfig(lookahead=lookahead))
        self.replan_distance = replan_distance
        self.replans = 0
        self.clearance_angles = None
        cam = env.unwrapped.config.camera
        if clearance_rays:
            # image columns run left to right, angles right to left (yaw is counter-clockwise)
            self.clearance_angles = ray_angles(clearance_rays, camera_hfov_deg(cam.width, cam.focal))[::-1].copy()
        self.depth_grid = tuple(depth_grid) if depth_grid else None
        if self.depth_grid:
            check_depth_grid(self.depth_grid, (cam.height, cam.width))
        if waypoints < 0:
            raise ValueError(f"waypoints must be >= 0, got {waypoints}")
        self.waypoints = waypoints

    def clearance(self) -> np.ndarray:
        """Privileged clearance over the camera's view [K] in [0, 1] (see the module docs)."""
        base = self.env.unwrapped
        x, y, yaw = base.state.x, base.state.y, base.state.yaw
        mesh = mesh_ranges(base.world.physics, x, y, yaw, self.clearance_angles, CLEARANCE_RANGE, RAY_HEIGHT)
        walk = walkable_ranges(world_grid(base.world), x, y, yaw, self.clearance_angles, CLEARANCE_RANGE)
        return (np.minimum(mesh, walk) / CLEARANCE_RANGE).astype(np.float32)

    def _off_path(self) -> bool:
        x, y, _ = self.env.unwrapped.robot_pose()
        path = self.expert.path
        return float(np.min(np.hypot(path[:, 0] - x, path[:, 1] - y))) > self.replan_distance

    def _label(self, info: dict) -> dict:
        if self.replan_distance == 0 or (math.isfinite(self.replan_distance) and self._off_path()):
            path = self.env.unwrapped.replan_expert_path()
            if path is not None:
                self.expert.path, self.expert.index = np.asarray(path, np.float64), 0
                self.replans += 1
        action = self.expert.act(self.env)
        label = {**info, "teacher_action": action, "teacher_stuck": self.expert.stuck > 0}
        if self.clearance_angles is not None:
            label["teacher_clearance"] = self.clearance()
        if self.depth_grid:
            label["teacher_depth"] = depth_blocks(self.env.unwrapped.last_depth, self.depth_grid)
        if self.waypoints:
            label["teacher_waypoints"] = route_waypoints(self.expert.path, self.expert.index,
                                                         self.env.unwrapped.robot_pose(), self.waypoints)
        return label

    def reset(self, **kwargs: Any):
        obs, info = self.env.reset(**kwargs)
        self.expert.reset(self.env)
        return obs, self._label(info)

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        if not (terminated or truncated):
            info = self._label(info)
        return obs, reward, terminated, truncated, info


class ExpertActions(gym.Wrapper):
    """Exposes `expert_action()`: the scripted A* pure-pursuit expert's action for the current state.

    Used to fill SAC's replay buffer during the warm-up steps with demonstrations instead of random
    actions (`SACConfig.warmup = "expert"`); the expert re-plans on every reset.
    """

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.expert = PurePursuitExpert()

    def reset(self, **kwargs: Any):
        obs, info = self.env.reset(**kwargs)
        self.expert.reset(self.env)
        return obs, info

    def expert_action(self) -> np.ndarray:
        return self.expert.act(self.env)  # [2] speed, steering in [-1, 1]


def route_waypoints(path: np.ndarray, start: int, pose: tuple[float, float, float], k: int,
                    spacing: float = WAYPOINT_SPACING) -> np.ndarray:
    """k points [k, 2] spacing m apart along the route path [P, 2] from its point `start` (the one
    nearest the robot), in the robot's frame at pose (x, y, yaw): x forward, y left, metres; points
    past the route's end are its end."""
    route = np.asarray(path, np.float64)[start:]  # [P', 2]
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(route, axis=0).T))])  # [P']
    want = spacing * np.arange(1, k + 1)  # [k]
    px, py = np.interp(want, arc, route[:, 0]), np.interp(want, arc, route[:, 1])  # past the end: the end
    x, y, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    dx, dy = px - x, py - y
    return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=1).astype(np.float32)
