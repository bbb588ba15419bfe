"""What the walked-corridor and walkable-IoU targets can reach, and where a map loses IoU.

Ceiling: the same corridor figures (walked path on walkable cells, components, collision area
in the body) computed on the GROUND-TRUTH robot-centre map and GT obstacle mesh with the GT
camera path, plus the path's clearance: the smallest horizontal distance from the walked path
to obstacle surface that can touch the robot (between `band_bottom_m` and `band_top_m` above
the ground). A clearance below the robot radius means no faithful map can hold the whole
path for that robot; above it, the figure a reconstruction misses is its geometry's fault.

Breakdown: the IoU's missed (GT walkable, ours not) and extra (ours walkable, GT not) areas
split by the side of the walked path they lie on, on a common grid over an x range; with the
map's evidence, the missed area also by cause (unseen ground, obstacle or kerb clearance, cut
off from the path's component), as `geometry.map_evidence.path_miss_causes` does for the walked path.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
from scipy.spatial import cKDTree

from vid2sim.factory.evaluation.corridor import corridor_check
from vid2sim.factory.geometry.kerbs import path_coordinates
from vid2sim.factory.geometry.map_evidence import MapEvidence
from vid2sim.factory.geometry.raycast import MeshLike, mesh_arrays
from vid2sim.factory.geometry.surface_sampling import points_by_spacing
from vid2sim.factory.geometry.walked_path import walked_path
from vid2sim.formats.walkable import WalkableGrid


def path_clearance(mesh: MeshLike, camera_path: np.ndarray, band_bottom_m: float = 0.15,
                   band_top_m: float = 1.8, ground_z_m: float = 0.0, spacing_m: float = 0.03,
                   reach_m: float = 3.0) -> np.ndarray:
    """Horizontal distance [S] from each walked-path sample (every 0.05 m of camera_path
    [T, 3]) to the nearest mesh surface point in the height band above the ground, sampled
    every spacing_m on the faces whose xy box comes within reach_m of the path's (inf: none)."""
    walked = walked_path(camera_path, 0.05)  # [S, 3]
    v, f = mesh_arrays(mesh)
    if len(f) == 0:
        return np.full(len(walked), np.inf)
    tri = v[f]  # [F, 3, 3]
    lo, hi = walked[:, :2].min(0) - reach_m, walked[:, :2].max(0) + reach_m
    near = np.all((tri[:, :, :2].max(axis=1) >= lo) & (tri[:, :, :2].min(axis=1) <= hi), axis=1)
    if not near.any():
        return np.full(len(walked), np.inf)
    used, inv = np.unique(f[near], return_inverse=True)
    pts = points_by_spacing(v[used], inv.reshape(-1, 3), spacing_m)  # [P, 3]
    z = pts[:, 2] - ground_z_m
    pts = pts[(z >= band_bottom_m) & (z <= band_top_m)]
    if len(pts) == 0:
        return np.full(len(walked), np.inf)
    return cKDTree(pts[:, :2]).query(walked[:, :2])[0]


def ceiling(gt_map: WalkableGrid, gt_obstacles: MeshLike, gt_path: np.ndarray,
            robot_radius_m: float) -> dict:
    """Corridor figures on the GT robot-centre map and GT obstacle mesh along the GT camera
    path [T, 3], and the path's clearance to GT obstacle surface (module docstring)."""
    rep = corridor_check(gt_map, gt_obstacles, gt_path)
    clear = path_clearance(gt_obstacles, gt_path)
    return {"gt_walkable_fraction": rep.walkable_fraction, "gt_path_components": rep.path_components,
            "gt_corridor_area_m2": rep.corridor_area_m2, "gt_clearance_min_m": float(clear.min()),
            "gt_path_within_robot_radius": float(np.mean(clear < robot_radius_m))}


def iou_breakdown(ours: WalkableGrid, gt: WalkableGrid, camera_path: np.ndarray, x0: float,
                  x1: float, res: float = 0.05, evidence: Optional[MapEvidence] = None) -> dict:
    """Missed and extra walkable area (m^2) between world x0 and x1, split into the left
    (+) and right (-) side of the walked path (camera_path [T, 3]), on a res grid; with
    `evidence` (on ours's grid) the missed area also by its first cause (module docstring)."""
    lo_y = min(ours.origin[1], gt.origin[1])
    hi_y = max(ours.extent_max()[1], gt.extent_max()[1])
    X, Y = np.meshgrid(np.arange(x0, x1, res) + res / 2, np.arange(lo_y, hi_y, res) + res / 2)
    a, b = ours.lookup(X, Y), gt.lookup(X, Y)
    _, d = path_coordinates(np.stack([X.ravel(), Y.ravel()], 1), camera_path[:, :2])
    left = (d >= 0).reshape(X.shape)
    cell = res * res
    out = {}
    for name, m in (("missed", b & ~a), ("extra", a & ~b)):
        out[f"{name}_left_m2"] = float(np.count_nonzero(m & left) * cell)
        out[f"{name}_right_m2"] = float(np.count_nonzero(m & ~left) * cell)
    out["gt_area_m2"] = float(np.count_nonzero(b) * cell)
    out["ours_area_m2"] = float(np.count_nonzero(a) * cell)
    if evidence is not None:
        out.update(missed_causes(ours, evidence, X[b & ~a], Y[b & ~a], cell))
    return out


def missed_causes(ours: WalkableGrid, evidence: MapEvidence, x: np.ndarray, y: np.ndarray,
                  cell_m2: float) -> dict:
    """Area (m^2) of the missed points x, y [N] by first cause: outside our grid, unseen,
    obstacle clearance, kerb clearance, else another component."""
    H, W = ours.shape
    r, c = ours.world_to_cell(x, y)
    inside = (r >= 0) & (r < H) & (c >= 0) & (c < W)
    r, c = np.clip(r, 0, H - 1), np.clip(c, 0, W - 1)
    left = np.ones(len(x), bool)
    out = {}
    for name, hit in (("off_grid", ~inside), ("unseen", ~evidence.seen[r, c]),
                      ("obstacle", evidence.blocked_obstacle[r, c]), ("kerb", evidence.blocked_kerb[r, c]),
                      ("component", np.ones(len(x), bool))):
        out[f"missed_{name}_m2"] = float(np.count_nonzero(left & hit) * cell_m2)
        left &= ~hit
    return out
