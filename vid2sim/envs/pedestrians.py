"""Pedestrians for SocialNav: people walking A* paths between random walkable points.

Each person walks the planner's path to a random free point at a speed drawn from
U(SPEED_RANGE) (human walking speeds, ~1.0-1.6 m/s; MetaUrban's pedestrians walk at ~1 m/s
and re-plan on arrival) and picks a new goal and a new path when it arrives. Local behaviour
is a simple yield rule, not ORCA (MetaUrban's choice): a person waits while the robot or
another person is within YIELD_DISTANCE m ahead (within YIELD_ANGLE of the walking
direction), for at most MAX_WAIT s, then walks on (so two people facing each other do not
wait forever).

Body: a simple articulated figure (legs and arms swing with the gait, torso, head), drawn by
the env rasteriser, 1.55-1.90 m tall. Physics: one kinematic pybullet capsule per person
(mass 0, radius BODY_RADIUS, moved with resetBasePositionAndOrientation every step), so the
robot's contact queries see it and it is never pushed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
import trimesh
from numba import njit

from .planning import GridPlanner
from vid2sim.bullet import import_pybullet

from .raster import rasterize, rasterize_into

pb = import_pybullet()  # without its "pybullet build time" banner

SPEED_RANGE = (1.0, 1.6)  # m/s
HEIGHT_RANGE = (1.55, 1.90)  # m
BODY_RADIUS = 0.25  # m, collision capsule
STRIDE = 1.4  # m per gait cycle (two steps)
SWING = 0.45  # rad, peak leg swing
YIELD_DISTANCE = 0.9  # m
YIELD_ANGLE = math.radians(50.0)
COS_YIELD = math.cos(YIELD_ANGLE)
MAX_WAIT = 2.0  # s
SKIN = ((230, 190, 160), (190, 140, 100), (120, 80, 55), (80, 55, 40))
LIGHT_DIR = np.array([0.35, 0.25, 0.9]) / np.linalg.norm([0.35, 0.25, 0.9])


@dataclass
class _Part:
    mesh: trimesh.Trimesh  # local person frame (x forward, y left, z up), at rest
    color: np.ndarray  # [3]
    pivot: Optional[np.ndarray] = None  # [3] hip / shoulder joint for swinging limbs
    swing_sign: float = 0.0  # +1 / -1: swings with / against the phase


def _box(sx: float, sy: float, sz: float, center: Sequence[float]) -> trimesh.Trimesh:
    m = trimesh.creation.box(extents=[sx, sy, sz])
    m.apply_translation(center)
    return m


def person_parts(height: float, rng: np.random.Generator) -> list[_Part]:
    """Legs, torso, arms and head of a person `height` m tall, with random clothes."""
    hip, shoulder = 0.52 * height, 0.81 * height
    shirt, trousers = rng.integers(30, 230, size=3), rng.integers(20, 140, size=3)
    skin = np.array(SKIN[int(rng.integers(len(SKIN)))])
    head = trimesh.creation.icosphere(subdivisions=1, radius=0.095 * height / 1.75)
    head.apply_translation([0.0, 0.0, shoulder + 0.05 + 0.095 * height / 1.75])
    parts = [_Part(_box(0.22, 0.38, shoulder - hip, (0, 0, (hip + shoulder) / 2)), shirt),
             _Part(head, skin)]
    for side, sign in ((0.1, 1.0), (-0.1, -1.0)):
        parts.append(_Part(_box(0.14, 0.13, hip, (0, side, hip / 2)), trousers,
                           np.array([0.0, side, hip]), sign))
        arm = 0.36 * height
        parts.append(_Part(_box(0.09, 0.09, arm, (0, 2.4 * side, shoulder - arm / 2)), shirt,
                           np.array([0.0, 2.4 * side, shoulder]), -sign))
    return parts


def _rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@njit(cache=True)
def _path_point(path: np.ndarray, arc: np.ndarray, s: float) -> tuple[float, float]:
    """The point at arc length s along waypoints path [K, 2] with cumulative lengths arc [K]
    (`np.interp` per axis: clamped at both ends; a repeated arc value takes the later point)."""
    K = arc.shape[0]
    if s <= arc[0]:
        return path[0, 0], path[0, 1]
    if s >= arc[K - 1]:
        return path[K - 1, 0], path[K - 1, 1]
    k = np.searchsorted(arc, s, side="right") - 1  # arc[k] <= s < arc[k + 1]
    t = (s - arc[k]) / (arc[k + 1] - arc[k])
    return (path[k, 0] + t * (path[k + 1, 0] - path[k, 0]),
            path[k, 1] + t * (path[k + 1, 1] - path[k, 1]))


@njit(cache=True)
def _pose_vertices(local, pivot, sign, owner, pose):
    """World vertices [V, 3] f32 of rest-mesh vertices local [V, 3]: limbs swung by
    sign [V] x SWING x sin(phase) about their joint pivot [V, 3] (y axis), then turned by yaw
    and moved to (x, y) of their walker owner [V]; pose [P, 4] = (phase, yaw, x, y)."""
    out = np.empty((local.shape[0], 3), np.float32)
    for v in range(local.shape[0]):
        p = owner[v]
        ang = sign[v] * SWING * math.sin(pose[p, 0])
        c, s = math.cos(ang), math.sin(ang)
        dx, dy, dz = local[v, 0] - pivot[v, 0], local[v, 1] - pivot[v, 1], local[v, 2] - pivot[v, 2]
        x = c * dx + s * dz + pivot[v, 0]
        y = dy + pivot[v, 1]
        z = -s * dx + c * dz + pivot[v, 2]
        cy, sy = math.cos(pose[p, 1]), math.sin(pose[p, 1])
        out[v, 0] = cy * x - sy * y + pose[p, 2]
        out[v, 1] = sy * x + cy * y + pose[p, 3]
        out[v, 2] = z
    return out


class _Walker:
    """One person's state: path, arc position, speed, gait phase."""

    def __init__(self, xy: np.ndarray, speed: float, height: float, parts: list[_Part]) -> None:
        self.xy = xy  # [2]
        self.yaw = 0.0
        self.speed = speed
        self.height = height
        self.parts = parts
        self.path: Optional[np.ndarray] = None  # [K, 2]
        self.arc: Optional[np.ndarray] = None  # [K]
        self.s = 0.0
        self.phase = 0.0
        self.waited = 0.0  # s spent yielding in a row

    def set_path(self, path: np.ndarray) -> None:
        self.path = path
        self.arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
        self.s = 0.0

    def advance(self, dist: float) -> bool:
        """Walk `dist` m along the path; True when the goal is reached."""
        if self.path is None or len(self.path) < 2:
            return True
        end = float(self.arc[-1])
        self.s = min(self.s + dist, end)
        x, y = _path_point(self.path, self.arc, self.s)
        dx, dy = x - float(self.xy[0]), y - float(self.xy[1])
        step = math.hypot(dx, dy)
        if step > 1e-6:
            self.yaw = math.atan2(dy, dx)
        self.phase += 2 * math.pi * step / STRIDE
        self.xy = np.array([x, y])
        return self.s >= end - 1e-9

    def world_vertices(self) -> list[np.ndarray]:
        """Every part's vertices [V_i, 3] in the world at the current pose and gait phase."""
        Rz = _rot_z(self.yaw)
        t = np.array([self.xy[0], self.xy[1], 0.0])
        out = []
        for p in self.parts:
            v = np.asarray(p.mesh.vertices)
            if p.pivot is not None:
                v = (v - p.pivot) @ _rot_y(p.swing_sign * SWING * math.sin(self.phase)).T + p.pivot
            out.append(v @ Rz.T + t)
        return out


class Crowd:
    """`count` pedestrians walking A* paths of `planner` between random free points.

    `avoid` points (e.g. the robot's start) keep people at least `min_distance` m away at
    spawn. `step(dt)` moves everyone and their pybullet capsules; `draw` rasters them.
    """

    def __init__(self, planner: GridPlanner, count: int, rng: np.random.Generator, client_id: int,
                 avoid: Sequence[Sequence[float]] = (), min_distance: float = 2.0) -> None:
        self.planner, self.rng, self.client_id = planner, rng, client_id
        self.walkers = [self._spawn(avoid, min_distance) for _ in range(count)]
        self.goals_reached = 0
        self.body_ids = [self._add_body(w) for w in self.walkers]
        self._faces, self._colors = self._static_arrays()
        self._pack()
        for w in self.walkers:
            self._new_path(w)
        self._sync_bodies()

    def _spawn(self, avoid: Sequence[Sequence[float]], min_distance: float) -> _Walker:
        for _ in range(100):
            xy = np.array(self.planner.sample_free(self.rng))
            if all(np.hypot(*(xy - np.asarray(a, float)[:2])) >= min_distance for a in avoid):
                break
        height = float(self.rng.uniform(*HEIGHT_RANGE))
        return _Walker(xy, float(self.rng.uniform(*SPEED_RANGE)), height,
                       person_parts(height, self.rng))

    def _new_path(self, w: _Walker) -> None:
        """A path to a fresh random free point (a few tries; standing still if none)."""
        for _ in range(5):
            path = self.planner.plan(tuple(w.xy), self.planner.sample_free(self.rng))
            if path is not None and len(path) >= 2:
                w.set_path(np.asarray(path, np.float64))
                return
        w.set_path(np.stack([w.xy, w.xy]))

    def _add_body(self, w: _Walker) -> int:
        shape = pb.createCollisionShape(pb.GEOM_CAPSULE, radius=BODY_RADIUS,
                                        height=w.height - 2 * BODY_RADIUS,
                                        physicsClientId=self.client_id)
        return pb.createMultiBody(0.0, shape, basePosition=[w.xy[0], w.xy[1], w.height / 2],
                                  physicsClientId=self.client_id)

    def _sync_bodies(self) -> None:
        for w, b in zip(self.walkers, self.body_ids):
            quat = pb.getQuaternionFromEuler([0.0, 0.0, w.yaw])
            pb.resetBasePositionAndOrientation(b, [w.xy[0], w.xy[1], w.height / 2], quat,
                                               physicsClientId=self.client_id)
        pb.performCollisionDetection(physicsClientId=self.client_id)

    def _static_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """Faces [F, 3] (offset for the concatenated vertices) and their colours [F, 3] u8."""
        faces, colors, offset = [], [], 0
        for w in self.walkers:
            for p in w.parts:
                faces.append(np.asarray(p.mesh.faces) + offset)
                lam = np.clip(np.asarray(p.mesh.face_normals) @ LIGHT_DIR, 0.0, 1.0)[:, None]
                colors.append(np.clip(p.color[None] * (0.55 + 0.45 * lam), 0, 255).astype(np.uint8))
                offset += len(p.mesh.vertices)
        if not faces:
            return np.zeros((0, 3), np.int32), np.zeros((0, 3), np.uint8)
        return np.concatenate(faces).astype(np.int32), np.concatenate(colors)

    def _pack(self) -> None:
        """Per-vertex arrays of everyone's rest mesh for the vectorised pose in mesh_arrays."""
        local, pivot, sign, owner = [], [], [], []
        for k, w in enumerate(self.walkers):
            for p in w.parts:
                n = len(p.mesh.vertices)
                local.append(np.asarray(p.mesh.vertices))
                pivot.append(np.broadcast_to(p.pivot if p.pivot is not None else np.zeros(3), (n, 3)))
                sign.append(np.full(n, p.swing_sign if p.pivot is not None else 0.0))
                owner.append(np.full(n, k))
        cat = (lambda xs, shape: np.concatenate(xs) if xs else np.zeros(shape))  # noqa: E731
        self._local, self._pivot = cat(local, (0, 3)), cat(pivot, (0, 3))  # [V, 3]
        self._sign, self._owner = cat(sign, (0,)), cat(owner, (0,)).astype(np.int64)  # [V]

    def step(self, dt: float, robot_xy: Optional[Sequence[float]] = None) -> None:
        """Walk everyone dt seconds (yielding to the robot and to each other); new goal and
        path on arrival; move the capsules."""
        others = self.positions  # [P, 2] before anyone moves
        if robot_xy is not None:
            others = np.concatenate([others, np.asarray(robot_xy, np.float64)[None, :2]])
        for k, w in enumerate(self.walkers):
            blocked = self._blocked(k, w, others)
            if blocked and w.waited < MAX_WAIT:
                w.waited += dt
                continue
            if not blocked:  # after MAX_WAIT, walk on until the way is clear again
                w.waited = 0.0
            if w.advance(w.speed * dt):
                self.goals_reached += 1
                self._new_path(w)
        self._sync_bodies()

    @staticmethod
    def _blocked(k: int, w: _Walker, others: np.ndarray) -> bool:
        """True when someone other than walker k stands within the yield cone ahead of it."""
        x, y, c, s = float(w.xy[0]), float(w.xy[1]), math.cos(w.yaw), math.sin(w.yaw)
        for m, (ox, oy) in enumerate(others.tolist()):
            if m == k:
                continue
            dx, dy = ox - x, oy - y
            dist = math.hypot(dx, dy)
            if 1e-6 < dist < YIELD_DISTANCE and dx * c + dy * s > dist * COS_YIELD:
                return True
        return False

    @property
    def positions(self) -> np.ndarray:
        """Ground positions [P, 2]."""
        return np.array([w.xy for w in self.walkers], np.float64).reshape(-1, 2)

    @property
    def headings(self) -> np.ndarray:
        """Walking directions [P] (rad, world yaw)."""
        return np.array([w.yaw for w in self.walkers], np.float64)

    def mesh_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Everyone's world mesh: vertices [V, 3] f32, faces [F, 3] i32, colours [F, 3] u8.

        One numba pass over all vertices (`_pose_vertices`); `_Walker.world_vertices` is the
        per-part reference."""
        if not self.walkers:
            return np.zeros((0, 3), np.float32), self._faces, self._colors
        pose = np.array([(w.phase, w.yaw, w.xy[0], w.xy[1]) for w in self.walkers])  # [P, 4]
        verts = _pose_vertices(self._local, self._pivot, self._sign, self._owner, pose)
        return verts, self._faces, self._colors

    def draw(self, K: np.ndarray, world_to_cam: np.ndarray, width: int, height: int
             ) -> tuple[np.ndarray, np.ndarray]:
        """Raster the crowd: (rgb [H, W, 3] u8, depth [H, W] f32, +inf where empty)."""
        return rasterize(*self.mesh_arrays(), K, world_to_cam, width, height)

    def draw_into(self, K: np.ndarray, world_to_cam: np.ndarray, rgb: np.ndarray,
                  depth: np.ndarray) -> None:
        """Raster the crowd over (rgb [H, W, 3] u8, depth [H, W] f32) in place (z-buffer)."""
        rasterize_into(*self.mesh_arrays(), K, world_to_cam, rgb, depth)

    def remove(self) -> None:
        for b in self.body_ids:
            pb.removeBody(b, physicsClientId=self.client_id)
        self.body_ids, self.walkers = [], []
        self._faces, self._colors = self._static_arrays()
        self._pack()
