"""Triangle-mesh primitives with per-face material ids, colours and instance ids."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Material ids (per face). Textures in textures.py are keyed by these.
SKY, ASPHALT, SIDEWALK, KERB, BRICK, PLASTER, POLE, PLANTER, PLANT, CAR = range(10)
MATERIAL_NAMES = {
    ASPHALT: "asphalt", SIDEWALK: "sidewalk", KERB: "kerb", BRICK: "brick", PLASTER: "plaster",
    POLE: "pole", PLANTER: "planter", PLANT: "plant", CAR: "car",
}
GROUND_MATERIALS = (ASPHALT, SIDEWALK, KERB)

_BOX_FACES = np.array([  # outward winding (counter-clockwise seen from outside)
    [0, 2, 1], [0, 3, 2],  # z-
    [4, 5, 6], [4, 6, 7],  # z+
    [0, 1, 5], [0, 5, 4],  # y-
    [2, 3, 7], [2, 7, 6],  # y+
    [1, 2, 6], [1, 6, 5],  # x+
    [3, 0, 4], [3, 4, 7],  # x-
], np.int64)


def box_mesh(lo: np.ndarray, hi: np.ndarray, skip_bottom: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box; returns vertices [8, 3], triangles [10 or 12, 3]."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                  [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], np.float64)
    return v, (_BOX_FACES[2:] if skip_bottom else _BOX_FACES)


def quad_mesh(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Quad from 4 corners in counter-clockwise order (seen from the front)."""
    return np.asarray(corners, np.float64), np.array([[0, 1, 2], [0, 2, 3]], np.int64)


def cylinder_mesh(cx: float, cy: float, z0: float, z1: float, r: float,
                  segments: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Vertical capped cylinder; vertices [2S + 1, 3]."""
    a = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([cx + r * np.cos(a), cy + r * np.sin(a)], 1)
    v = np.concatenate([np.c_[ring, np.full(segments, z0)], np.c_[ring, np.full(segments, z1)],
                        [[cx, cy, z1]]])
    i = np.arange(segments)
    j = (i + 1) % segments
    sides = np.concatenate([np.stack([i, j, j + segments], 1), np.stack([i, j + segments, i + segments], 1)])
    cap = np.stack([np.full(segments, 2 * segments), i + segments, j + segments], 1)
    return v, np.concatenate([sides, cap])


@dataclass
class MeshBuilder:
    """Accumulates parts; each part carries a material id, an albedo tint and an instance id."""

    vertices: list = field(default_factory=list)
    triangles: list = field(default_factory=list)
    material: list = field(default_factory=list)
    color: list = field(default_factory=list)
    instance: list = field(default_factory=list)
    _nv: int = 0
    _ninst: int = 0

    def add(self, part: tuple[np.ndarray, np.ndarray], material: int, color=(1.0, 1.0, 1.0)) -> int:
        v, f = part
        self.vertices.append(np.asarray(v, np.float64))
        self.triangles.append(np.asarray(f, np.int64) + self._nv)
        n = len(f)
        self.material.append(np.full(n, material, np.uint8))
        self.color.append(np.tile(np.asarray(color, np.float32), (n, 1)))
        self.instance.append(np.full(n, self._ninst, np.int32))
        self._nv += len(v)
        self._ninst += 1
        return self._ninst - 1

    def arrays(self) -> dict[str, np.ndarray]:
        return {
            "vertices": np.concatenate(self.vertices).astype(np.float64),  # [V, 3]
            "triangles": np.concatenate(self.triangles).astype(np.int32),  # [F, 3]
            "face_material": np.concatenate(self.material),  # [F]
            "face_color": np.concatenate(self.color),  # [F, 3]
            "face_instance": np.concatenate(self.instance),  # [F]
        }


def face_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Unit normals by winding; [F, 3]."""
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    n = np.cross(b - a, c - a)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)


def face_areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)  # [F]
