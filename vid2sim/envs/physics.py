"""pybullet (DIRECT) world: the scene's collision mesh, a ground plane and the robot's footprint box.

The robot is kinematic: each 50 Hz substep proposes the bicycle model's next pose, moves the
box there and asks pybullet for penetrating contacts with anything but the ground. A blocked
move is undone (the robot stops at the obstacle) and reported as a collision. Nothing here is
ever drawn: the camera sees splats, pybullet only answers contacts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pybullet as pb

from vid2sim.envs.config import RobotConfig
from vid2sim.envs.scenes import MeshData

CONTACT_EPS = 1e-3  # m of penetration that counts as touching


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

    def _z(self) -> float:
        return self.robot_conf.ground_clearance + self.robot_conf.height / 2

    def place(self, x: float, y: float, yaw: float) -> None:
        quat = pb.getQuaternionFromEuler([0.0, 0.0, yaw])
        pb.resetBasePositionAndOrientation(self.robot_id, [x, y, self._z()], quat,
                                           physicsClientId=self.client)

    def contacts(self) -> list[int]:
        """Body ids (not robot, not ground) penetrating the robot box at its current pose.

        Static-static pairs get no contact manifold in Bullet, so this asks for closest points
        (negative distance = penetration) with every body whose AABB overlaps the robot's."""
        c = self.client
        lo, hi = pb.getAABB(self.robot_id, physicsClientId=c)
        near = {b for b, _ in (pb.getOverlappingObjects(lo, hi, physicsClientId=c) or ())}
        hit = []
        for body in sorted(near - self.ignore):
            pts = pb.getClosestPoints(self.robot_id, body, 0.0, physicsClientId=c)
            if any(p[8] < -CONTACT_EPS for p in pts):
                hit.append(body)
        return hit

    def step(self, state: RobotState, speed: float, steer: float, dt: float) -> tuple[RobotState, list[int]]:
        """One substep of the kinematic bicycle; returns (new state, bodies hit). Blocked moves stay."""
        L = self.robot_conf.wheelbase
        yaw = state.yaw + speed / L * math.tan(steer) * dt
        mid = 0.5 * (state.yaw + yaw)
        nx, ny = state.x + speed * math.cos(mid) * dt, state.y + speed * math.sin(mid) * dt
        self.place(nx, ny, yaw)
        hit = self.contacts()
        if hit:
            self.place(state.x, state.y, state.yaw)
            return RobotState(state.x, state.y, state.yaw, 0.0, steer), hit
        return RobotState(nx, ny, yaw, speed, steer), hit

    def close(self) -> None:
        if self.client >= 0 and pb.isConnected(self.client):
            pb.disconnect(self.client)
        self.client = -1
