"""Procedural sidewalk street: a triangle mesh with per-face materials and a walkable GT grid.

World frame: metric, z up, sidewalk surface z = 0, walking direction +x,
facades at y > sidewalk_width (left), kerb at y in [-kerb_width, 0], road at z = -kerb_height.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vid2sim.factory.synthetic.config import StreetConfig
from vid2sim.factory.synthetic.geometry import (
    ASPHALT, BRICK, CAR, GROUND_MATERIALS, KERB, PLANT, PLANTER, PLASTER, POLE, SIDEWALK,
    MeshBuilder, box_mesh, cylinder_mesh, quad_mesh,
)

BRICK_COLORS = [(0.62, 0.30, 0.22), (0.55, 0.33, 0.25), (0.70, 0.45, 0.32), (0.48, 0.27, 0.22)]
PLASTER_COLORS = [(0.85, 0.80, 0.68), (0.75, 0.78, 0.80), (0.90, 0.72, 0.55), (0.70, 0.76, 0.62),
                  (0.82, 0.66, 0.66)]
CAR_COLORS = [(0.75, 0.10, 0.10), (0.10, 0.25, 0.60), (0.85, 0.85, 0.82), (0.15, 0.15, 0.16),
              (0.55, 0.57, 0.60), (0.20, 0.45, 0.25), (0.90, 0.70, 0.15)]


@dataclass
class Obstacle:
    """A footprint on the ground: 'box' (x0, y0, x1, y1) or 'circle' (cx, cy, r)."""

    kind: str
    shape: str
    params: tuple[float, ...]
    height: float

    def contains(self, x: np.ndarray, y: np.ndarray, pad: float = 0.0) -> np.ndarray:
        if self.shape == "box":
            x0, y0, x1, y1 = self.params
            return (x >= x0 - pad) & (x <= x1 + pad) & (y >= y0 - pad) & (y <= y1 + pad)
        cx, cy, r = self.params
        return (x - cx) ** 2 + (y - cy) ** 2 <= (r + pad) ** 2


@dataclass
class StreetScene:
    """GT street: mesh arrays (see MeshBuilder.arrays), obstacles and the facade line."""

    config: StreetConfig
    vertices: np.ndarray  # [V, 3] float64
    triangles: np.ndarray  # [F, 3] int32
    face_material: np.ndarray  # [F] uint8
    face_color: np.ndarray  # [F, 3] float32 albedo tint
    face_instance: np.ndarray  # [F] int32
    obstacles: list[Obstacle] = field(default_factory=list)
    facade_front: list[tuple[float, float, float]] = field(default_factory=list)  # (x0, x1, y)
    x_range: tuple[float, float] = (0.0, 0.0)  # extent of the modelled street

    @property
    def n_faces(self) -> int:
        return len(self.triangles)

    def obstacle_faces(self) -> np.ndarray:
        """[F] bool: faces that are not ground (asphalt / sidewalk / kerb)."""
        return ~np.isin(self.face_material, GROUND_MATERIALS)

    def without_ground(self) -> tuple[np.ndarray, np.ndarray]:
        """Collision mesh: the `obstacle_faces`; (vertices, triangles), in face order."""
        tris = self.triangles[self.obstacle_faces()]
        used, inv = np.unique(tris, return_inverse=True)
        return self.vertices[used], inv.reshape(-1, 3).astype(np.int32)

    def facade_y(self, x: np.ndarray) -> np.ndarray:
        """y of the building front at each x (the sidewalk's far edge)."""
        y = np.full(np.shape(x), self.config.sidewalk_width, np.float64)
        for x0, x1, fy in self.facade_front:
            y = np.where((x >= x0) & (x < x1), fy, y)
        return y

    def walkable_grid(self, resolution: float | None = None, pad: float = 0.0
                      ) -> tuple[np.ndarray, np.ndarray, float]:
        """GT walkable area: sidewalk (kerb excluded) minus obstacle footprints.

        Returns grid [H, W] uint8 (row = y, column = x), origin (x, y) of cell [0, 0]'s corner, resolution.
        """
        res = resolution or self.config.gt_grid_resolution
        y_max = max([self.config.sidewalk_width] + [f[2] for f in self.facade_front])
        x0, x1 = self.x_range
        nx, ny = int(np.ceil((x1 - x0) / res)), int(np.ceil((y_max + 0.5) / res))
        xs = x0 + (np.arange(nx) + 0.5) * res
        ys = (np.arange(ny) + 0.5) * res
        X, Y = np.meshgrid(xs, ys)  # [H, W]
        ok = (Y >= 0.0) & (Y < self.facade_y(X))
        for ob in self.obstacles:
            ok &= ~ob.contains(X, Y, pad)
        return ok.astype(np.uint8), np.array([x0, 0.0]), float(res)


def _ground(mb: MeshBuilder, c: StreetConfig, x0: float, x1: float, y_far: float) -> None:
    kw, kh, rw, sw = c.kerb_width, c.kerb_height, c.road_width, c.sidewalk_width
    mb.add(quad_mesh([[x0, 0, 0], [x1, 0, 0], [x1, y_far, 0], [x0, y_far, 0]]), SIDEWALK)
    mb.add(quad_mesh([[x0, -kw, 0], [x1, -kw, 0], [x1, 0, 0], [x0, 0, 0]]), KERB)
    mb.add(quad_mesh([[x0, -kw, -kh], [x1, -kw, -kh], [x1, -kw, 0], [x0, -kw, 0]]), KERB)
    y_road = -kw - rw
    mb.add(quad_mesh([[x0, y_road, -kh], [x1, y_road, -kh], [x1, -kw, -kh], [x0, -kw, -kh]]), ASPHALT)
    # far side: kerb face, kerb top and sidewalk
    mb.add(quad_mesh([[x1, y_road, -kh], [x0, y_road, -kh], [x0, y_road, 0], [x1, y_road, 0]]), KERB)
    y_fs = y_road - kw
    mb.add(quad_mesh([[x0, y_fs, 0], [x1, y_fs, 0], [x1, y_road, 0], [x0, y_road, 0]]), KERB)
    mb.add(quad_mesh([[x0, y_fs - sw, 0], [x1, y_fs - sw, 0], [x1, y_fs, 0], [x0, y_fs, 0]]), SIDEWALK)


def _building_row(mb: MeshBuilder, c: StreetConfig, rng: np.random.Generator, x0: float, x1: float,
                  y_front: float, side: int) -> list[tuple[float, float, float]]:
    """Boxes along x; side=+1 faces -y (near row), side=-1 faces +y (far row)."""
    fronts = []
    x = x0
    while x < x1:
        w = rng.uniform(*c.building_width_range)
        h = rng.uniform(*c.facade_height_range)
        setback = rng.uniform(*c.facade_setback_range)
        depth = rng.uniform(6.0, 12.0)
        yf = y_front + side * setback
        lo = np.array([x, min(yf, yf + side * depth), 0.0])
        hi = np.array([x + w, max(yf, yf + side * depth), h])
        if rng.random() < 0.5:
            mat, col = BRICK, BRICK_COLORS[rng.integers(len(BRICK_COLORS))]
        else:
            mat, col = PLASTER, PLASTER_COLORS[rng.integers(len(PLASTER_COLORS))]
        mb.add(box_mesh(lo, hi), mat, col)
        if side > 0:
            fronts.append((x, x + w, yf))
        x += w
    return fronts


def _poles(mb: MeshBuilder, c: StreetConfig, rng: np.random.Generator, x0: float, x1: float,
           obstacles: list[Obstacle]) -> None:
    xs = np.sort(rng.uniform(x0, x1, c.n_poles))
    for x in xs:
        r, h, y = rng.uniform(0.05, 0.09), rng.uniform(2.8, 5.0), rng.uniform(0.3, 0.5)
        mb.add(cylinder_mesh(x, y, 0.0, h, r), POLE, (0.25, 0.30, 0.28))
        if rng.random() < 0.6:  # a sign plate
            mb.add(box_mesh(np.array([x - 0.02, y - 0.3, h - 0.9]), np.array([x + 0.02, y + 0.3, h - 0.3])),
                   POLE, tuple(rng.uniform(0.2, 0.9, 3)))
        obstacles.append(Obstacle("pole", "circle", (float(x), float(y), float(r)), float(h)))


def _planters(mb: MeshBuilder, c: StreetConfig, rng: np.random.Generator, x0: float, x1: float,
              obstacles: list[Obstacle]) -> None:
    for x in rng.uniform(x0, x1, c.n_planters):
        lx, ly, h = rng.uniform(0.9, 1.8), rng.uniform(0.5, 0.8), rng.uniform(0.4, 0.7)
        near_facade = rng.random() < 0.6
        y = c.sidewalk_width - ly - 0.1 if near_facade else 0.55
        lo, hi = np.array([x, y, 0.0]), np.array([x + lx, y + ly, h])
        mb.add(box_mesh(lo, hi), PLANTER, tuple(rng.uniform(0.45, 0.75, 3)))
        # foliage: a few boxes of plant material on top
        for _ in range(3):
            px, py = rng.uniform(x, x + lx * 0.6), rng.uniform(y, y + ly * 0.5)
            ph = rng.uniform(0.2, 0.6)
            mb.add(box_mesh(np.array([px, py, h]), np.array([px + lx * 0.4, py + ly * 0.5, h + ph])),
                   PLANT, (0.25, rng.uniform(0.45, 0.6), 0.18))
        obstacles.append(Obstacle("planter", "box", (float(x), float(y), float(x + lx), float(y + ly)), float(h)))


def _parked_boxes(mb: MeshBuilder, c: StreetConfig, rng: np.random.Generator, x0: float, x1: float) -> None:
    y_c, z0 = -c.kerb_width - 1.3, -c.kerb_height
    x = x0 + rng.uniform(0, 3)
    slots = []
    while x < x1:
        slots.append(x)
        x += rng.uniform(5.5, 9.0)
    for x in rng.permutation(slots)[: c.n_parked_boxes]:
        L, W = rng.uniform(3.8, 4.8), rng.uniform(1.7, 1.9)
        col = CAR_COLORS[rng.integers(len(CAR_COLORS))]
        mb.add(box_mesh(np.array([x, y_c - W / 2, z0 + 0.2]), np.array([x + L, y_c + W / 2, z0 + 0.95])),
               CAR, col)
        mb.add(box_mesh(np.array([x + 0.25 * L, y_c - W / 2 + 0.1, z0 + 0.95]),
                        np.array([x + 0.8 * L, y_c + W / 2 - 0.1, z0 + 1.45])), CAR, (0.12, 0.14, 0.18))


def generate_street(conf: StreetConfig) -> StreetScene:
    """Build the street for `conf.seed`: same seed -> identical mesh, other seeds -> other streets."""
    rng = np.random.default_rng(conf.seed)
    x0, x1 = -conf.margin_m, conf.length_m + conf.margin_m
    mb = MeshBuilder()
    y_back = conf.sidewalk_width + conf.facade_setback_range[1] + 0.05
    _ground(mb, conf, x0, x1, y_back)
    fronts = _building_row(mb, conf, rng, x0 - 5, x1 + 5, conf.sidewalk_width, +1)
    if conf.far_side_buildings:
        y_far = -2 * conf.kerb_width - conf.road_width - conf.sidewalk_width
        _building_row(mb, conf, rng, x0 - 5, x1 + 5, y_far, -1)
    obstacles: list[Obstacle] = []
    _poles(mb, conf, rng, -2.0, conf.length_m + 4.0, obstacles)
    _planters(mb, conf, rng, -2.0, conf.length_m + 4.0, obstacles)
    _parked_boxes(mb, conf, rng, -6.0, conf.length_m + 8.0)
    a = mb.arrays()
    return StreetScene(config=conf, obstacles=obstacles, facade_front=fronts, x_range=(x0, x1), **a)
