"""Geometry metrics: mesh-to-mesh Chamfer distance (surface sampling) and walkable-map IoU."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from vid2sim.factory.geometry.raycast import MeshLike, mesh_arrays
from vid2sim.formats.walkable import WalkableGrid


class Chamfer(NamedTuple):
    """Mean nearest-surface distances in metres; symmetric = (a_to_b + b_to_a) / 2."""

    a_to_b: float  # accuracy when a is the reconstruction
    b_to_a: float  # completeness when b is the ground truth
    symmetric: float


def sample_surface(vertices: np.ndarray, faces: np.ndarray, n: int, seed: int = 0
                   ) -> np.ndarray:
    """`n` points [n, 3] uniformly by area on a triangle mesh (deterministic for a seed)."""
    tri = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]  # [F, 3, 3]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if len(tri) == 0 or area.sum() <= 0:
        raise ValueError("cannot sample an empty (zero-area) mesh")
    rng = np.random.default_rng(seed)
    idx = rng.choice(len(tri), size=n, p=area / area.sum())
    u, v = rng.random(n), rng.random(n)
    out = u + v > 1
    u[out], v[out] = 1 - u[out], 1 - v[out]
    t = tri[idx]
    return t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])


def points_by_spacing(vertices: np.ndarray, faces: np.ndarray, spacing: float, seed: int = 0
                      ) -> np.ndarray:
    """Surface points with about one per spacing^2 of area, plus every vertex: [P, 3]."""
    v, f = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    if len(f) == 0:
        return v.copy()
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    n = int(np.ceil(area.sum() / spacing ** 2))
    extra = sample_surface(v, f, n, seed) if n > 0 and area.sum() > 0 else np.zeros((0, 3))
    return np.concatenate([v, tri.mean(axis=1), extra])


def chamfer_distance(mesh_a: MeshLike, mesh_b: MeshLike, n_samples: int = 100_000,
                     seed: int = 0) -> Chamfer:
    """Chamfer distance (metres) between two meshes by sampling n_samples points on each."""
    pa = sample_surface(*mesh_arrays(mesh_a), n_samples, seed)
    pb = sample_surface(*mesh_arrays(mesh_b), n_samples, seed + 1)
    return chamfer_points(pa, pb)


def chamfer_points(pa: np.ndarray, pb: np.ndarray) -> Chamfer:
    """Chamfer distance between two point sets [N, 3], [M, 3]."""
    d_ab = cKDTree(pb).query(pa, workers=-1)[0]
    d_ba = cKDTree(pa).query(pb, workers=-1)[0]
    a, b = float(d_ab.mean()), float(d_ba.mean())
    return Chamfer(a, b, 0.5 * (a + b))


def grid_iou(a: WalkableGrid, b: WalkableGrid) -> float:
    """IoU of two walkable maps, resampled (nearest cell) onto a common grid at the finer
    resolution covering both. Both empty -> 1.0."""
    res = min(a.resolution, b.resolution)
    lo = np.minimum(a.origin, b.origin)
    hi = np.maximum(a.extent_max(), b.extent_max())
    w, h = (np.ceil((hi - lo) / res - 1e-9).astype(int))
    xs = lo[0] + (np.arange(w) + 0.5) * res
    ys = lo[1] + (np.arange(h) + 0.5) * res
    X, Y = np.meshgrid(xs, ys)  # [h, w]
    ga, gb = a.lookup(X, Y), b.lookup(X, Y)
    union = np.count_nonzero(ga | gb)
    if union == 0:
        return 1.0
    return float(np.count_nonzero(ga & gb) / union)


def erode_walkable(wm: WalkableGrid, radius_m: float) -> WalkableGrid:
    """Robot-centre version of a GT walkable area: cells farther than radius_m from any
    non-walkable cell (outside the grid counts as non-walkable). Compare our maps to this."""
    g = np.pad(wm.grid > 0, 1)
    dist = ndimage.distance_transform_edt(g)[1:-1, 1:-1] * wm.resolution
    return WalkableGrid((dist > radius_m).astype(np.uint8), wm.origin, wm.resolution)
