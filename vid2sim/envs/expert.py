"""Scripted expert: follow the episode's A* path with a pure-pursuit controller.

Pure pursuit (Coulter 1992) for the kinematic bicycle: steer = atan(2 L sin(alpha) / l_d),
alpha the bearing of the look-ahead point on the path, l_d its distance. Speed is reduced
in sharp turns. The path comes from `NavEnv.expert_path()` (A* on the clearance-inflated map,
obstacles blocked), so the expert also serves demonstrations. Before acting it checks the
constant-steer arc on the walkable map (`_safe_steer`: pure pursuit cuts corners, A* ignores
the 1.4 m turning circle); when its last action left the pose unchanged (blocked by the mesh:
the physics undoes moves that push further in) it tries full steering the other way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from vid2sim.ranges import checked


@checked
@dataclass(frozen=True)
class ExpertConfig:
    lookahead: float = 1.0  # m
    min_speed: float = 0.3  # normalised speed in the sharpest turns
    slow_angle_deg: float = 60.0  # bearing at which the speed reaches min_speed
    horizon: float = 1.0  # m of constant-steer arc checked on the walkable map before acting
    n_steers: int = 9  # steering candidates in [-1, 1] the check falls back to


class PurePursuitExpert:
    def __init__(self, config: ExpertConfig = ExpertConfig()) -> None:
        self.config = config
        self.path: Optional[np.ndarray] = None  # [K, 2]
        self.index = 0
        self.last: Optional[tuple] = None  # (env step count, pose, action) of the previous act
        self.stuck = 0

    def reset(self, env) -> None:
        """Take the path of the episode that env (a NavEnv, possibly wrapped) just reset into."""
        self.path = np.asarray(env.unwrapped.expert_path(), np.float64)
        self.index = 0
        self.last, self.stuck = None, 0

    def act(self, env) -> np.ndarray:
        """Action [2] (speed, steering) in [-1, 1] for the current robot pose."""
        u = env.unwrapped
        if self.last is not None and self.last[0] == u.steps:  # asked again before any step
            return self.last[2].copy()
        x, y, yaw = u.robot_pose()
        target = self._target(np.array([x, y]))
        dx, dy = target[0] - x, target[1] - y
        alpha = (math.atan2(dy, dx) - yaw + math.pi) % (2 * math.pi) - math.pi
        ld = max(math.hypot(dx, dy), 1e-3)
        robot = u.config.robot
        steer = math.atan2(2.0 * robot.wheelbase * math.sin(alpha), ld)
        c = self.config
        slow = min(abs(alpha) / math.radians(c.slow_angle_deg), 1.0)
        speed = 1.0 - (1.0 - c.min_speed) * slow
        steer_n = _safe_steer(u, float(np.clip(steer / robot.max_steer, -1.0, 1.0)), c)
        pose = (x, y, yaw)
        if self.last is not None and self.last[1] == pose:  # a step left the pose: blocked, steer away
            self.stuck += 1
            prev = float(self.last[2][1])
            steer_n = (-1.0 if prev >= 0 else 1.0) if self.stuck % 2 else -prev
        else:
            self.stuck = 0
        action = np.array([speed, steer_n], np.float32)
        self.last = (u.steps, pose, action)
        return action.copy()

    def _target(self, p: np.ndarray) -> np.ndarray:
        """Look-ahead point: first path point >= lookahead past the closest one (monotone)."""
        path = self.path
        window = path[self.index:self.index + 40]
        self.index += int(np.argmin(np.linalg.norm(window - p, axis=1)))
        d = np.linalg.norm(path[self.index:] - p, axis=1)
        far = np.nonzero(d >= self.config.lookahead)[0]
        return path[self.index + far[0]] if len(far) else path[-1]


def _safe_steer(u, steer_n: float, c: ExpertConfig) -> float:
    """The steering (normalised) closest to steer_n whose constant-steer arc of c.horizon m keeps
    the robot's footprint on the walkable map (steer_n itself when none does).

    Pure pursuit cuts corners and A* ignores the turning circle (wheelbase / tan(max steer),
    1.4 m): around an obstacle's corner or into a narrow spur the pursued arc can leave the map
    (whose cells are the robot radius clear of the collision mesh) and hit the mesh."""
    cands = sorted(np.linspace(-1.0, 1.0, c.n_steers).tolist() + [steer_n], key=lambda s: abs(s - steer_n))
    for s in cands:
        if _arc_on_map(u, s, c.horizon) >= c.horizon:
            return s
    return steer_n


def _arc_on_map(u, steer_n: float, horizon: float, ds: float = 0.1) -> float:
    """Metres of the constant-steer arc from the robot's pose along which the robot stays on the
    walkable map: its centre and the points of its centre line the map's inflation radius (the
    robot radius the factory shrank the map by) inside its front and back on walkable cells."""
    x, y, yaw = u.robot_pose()
    r = u.config.robot
    k = math.tan(steer_n * r.max_steer) / r.wheelbase  # curvature, 1/m
    reach = max(r.length / 2 - u.world.assets.walkable_inflation, 0.0)
    walk = u.world.walkable.is_walkable
    s = 0.0
    while s < horizon:
        s += ds
        mid = yaw + 0.5 * k * ds
        x, y, yaw = x + ds * math.cos(mid), y + ds * math.sin(mid), yaw + k * ds
        cx, cy = reach * math.cos(yaw), reach * math.sin(yaw)
        if not (walk(x, y) and walk(x + cx, y + cy) and walk(x - cx, y - cy)):
            return s - ds
    return s
