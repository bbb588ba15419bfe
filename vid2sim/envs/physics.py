"""pybullet (DIRECT) world: the scene's collision mesh, a ground plane and the robot's footprint box.

The robot is kinematic: each 50 Hz substep proposes the bicycle model's next pose, moves the
box there and asks pybullet for penetrating contacts with anything but the ground. A move that
deepens the penetration is undone (the robot stops at the obstacle); one that keeps or reduces
it is allowed (sliding along, or turning away from, what it touches); both count as contact. Nothing here is
ever drawn: the camera sees splats, pybullet only answers contacts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vid2sim.bullet import import_pybullet
from vid2sim.envs.config import RobotConfig
from vid2sim.envs.scenes import MeshData

pb = import_pybullet()  # without its "pybullet build time" banner

CONTACT_EPS = 1e-3  # m of penetration that counts as touching
SWEEP_MARGIN = 0.02  # m added to the swept reach before substep contact queries are skipped
DEPTH_TOL = 1e-4  # m: a move that deepens the penetration by more than this is blocked


@dataclass
class RobotState:
    x: float
    y: float
    yaw: float
    speed: float = 0.0  # m/s
    steer: float = 0.0  # rad


class PhysicsWorld:
    """One pybullet DIRECT client holding the static scene and the robot box."""

    def __init__(self, collision: MeshData, robot: RobotConfig) -> None:
        self.client = pb.connect(pb.DIRECT)
        self.robot_conf = robot
        c = self.client
        pb.setGravity(0.0, 0.0, -9.81, physicsClientId=c)  # only falling obstacles feel it
        plane = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=c)
        self.ground_id = pb.createMultiBody(0, plane, physicsClientId=c)
        self.scene_id = -1
        if len(collision.faces):
            shape = pb.createCollisionShape(
                pb.GEOM_MESH, vertices=collision.vertices.astype(np.float64).tolist(),
                indices=collision.faces.reshape(-1).astype(int).tolist(),
                flags=pb.GEOM_FORCE_CONCAVE_TRIMESH, physicsClientId=c)
            self.scene_id = pb.createMultiBody(0, shape, physicsClientId=c)
        half = [robot.length / 2, robot.width / 2, robot.height / 2]
        box = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=c)
        self.robot_id = pb.createMultiBody(0, box, basePosition=[0, 0, self._z()], physicsClientId=c)
        self.ignore = {self.robot_id, self.ground_id}
        self.depth = 0.0  # penetration at the current pose

    def _z(self) -> float:
        return self.robot_conf.ground_clearance + self.robot_conf.height / 2

    def place(self, x: float, y: float, yaw: float) -> None:
        """Put the robot at a pose (episode start) and record its penetration there."""
        self._move(x, y, yaw)
        self.depth = self.contacts()[1]

    def _move(self, x: float, y: float, yaw: float) -> None:
        quat = pb.getQuaternionFromEuler([0.0, 0.0, yaw])
        pb.resetBasePositionAndOrientation(self.robot_id, [x, y, self._z()], quat,
                                           physicsClientId=self.client)

    def contacts(self) -> tuple[list[int], float]:
        """(body ids penetrating the robot box, deepest penetration in m) at its current pose.

        Static-static pairs get no contact manifold in Bullet, so this asks for closest points
        (negative distance = penetration) with every body whose AABB overlaps the robot's."""
        c = self.client
        lo, hi = pb.getAABB(self.robot_id, physicsClientId=c)
        near = {b for b, _ in (pb.getOverlappingObjects(lo, hi, physicsClientId=c) or ())}
        hit, depth = [], 0.0
        for body in sorted(near - self.ignore):
            pts = pb.getClosestPoints(self.robot_id, body, 0.0, physicsClientId=c)
            d = max((-p[8] for p in pts), default=0.0)
            if d > CONTACT_EPS:
                hit.append(body)
                depth = max(depth, d)
        return hit, depth

    def propose(self, state: RobotState, speed: float, steer: float, dt: float
                ) -> tuple[float, float, float]:
        """The kinematic bicycle's next pose (x, y, yaw) after dt, ignoring contacts."""
        L = self.robot_conf.wheelbase
        yaw = state.yaw + speed / L * math.tan(steer) * dt
        mid = 0.5 * (state.yaw + yaw)
        return state.x + speed * math.cos(mid) * dt, state.y + speed * math.sin(mid) * dt, yaw

    def clear_within(self, reach: float) -> bool:
        """True when no body but the ground comes within `reach` m of the robot box at its pose.

        Every point of the box moves at most |dxy| + |dyaw| x (half-diagonal) between two poses,
        so a box `reach` m clear of everything cannot touch anything at a pose that close: the
        substeps' contact queries can be skipped (`NavEnv._drive`)."""
        c = self.client
        lo, hi = pb.getAABB(self.robot_id, physicsClientId=c)
        lo = [v - reach for v in lo]
        hi = [v + reach for v in hi]
        near = {b for b, _ in (pb.getOverlappingObjects(lo, hi, physicsClientId=c) or ())}
        return not any(pb.getClosestPoints(self.robot_id, b, reach, physicsClientId=c)
                       for b in near - self.ignore)

    def reach_of(self, x0: float, y0: float, yaw0: float, x: float, y: float, yaw: float) -> float:
        """Bound (m) on how far any point of the box moves from pose 0 to pose 1."""
        r = math.hypot(self.robot_conf.length / 2, self.robot_conf.width / 2)
        return math.hypot(x - x0, y - y0) + abs(yaw - yaw0) * r

    def move_free(self, x: float, y: float, yaw: float) -> None:
        """Move the box to a pose known to be clear of everything (see `clear_within`)."""
        self._move(x, y, yaw)
        self.depth = 0.0

    def step(self, state: RobotState, speed: float, steer: float, dt: float) -> tuple[RobotState, list[int]]:
        """One substep of the kinematic bicycle; returns (new state, bodies hit). Blocked moves stay."""
        nx, ny, yaw = self.propose(state, speed, steer, dt)
        self._move(nx, ny, yaw)
        hit, depth = self.contacts()
        if hit and depth > self.depth + DEPTH_TOL:  # pushing further in: blocked, undone
            self._move(state.x, state.y, state.yaw)
            return RobotState(state.x, state.y, state.yaw, 0.0, steer), hit
        self.depth = depth  # free, or sliding / backing out of a contact
        return RobotState(nx, ny, yaw, speed, steer), hit

    def close(self) -> None:
        if self.client >= 0 and pb.isConnected(self.client):
            pb.disconnect(self.client)
        self.client = -1
