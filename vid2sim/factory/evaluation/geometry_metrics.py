"""Geometry metrics: mesh-to-mesh Chamfer distance (surface sampling) and walkable-map IoU."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from vid2sim.factory.geometry.raycast import MeshLike, mesh_arrays
from vid2sim.factory.geometry.surface_sampling import sample_surface
from vid2sim.formats.walkable import WalkableGrid


class Chamfer(NamedTuple):
    """Mean nearest-surface distances in metres; symmetric = (a_to_b + b_to_a) / 2."""

    a_to_b: float  # accuracy when a is the reconstruction
    b_to_a: float  # completeness when b is the ground truth
    symmetric: float


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
