"""Free-space carving before TSDF fusion: drop depth that lies where space is proven empty.

Two kinds of evidence, on a dense voxel grid around the camera path:
  rays   every (strided) pixel ray is free from the camera up to `margin` before its own
         depth; a voxel counts the views whose rays crossed it (`free`) and the views whose
         depth landed in it (`hit`). A voxel is carved when free >= min_free_views and
         free >= free_ratio * hit: other views saw through it (splat floaters, depth noise in
         front of real surfaces), while a real surface stops the rays that reach it.
  body   the walker's body swept along the camera path (radius, from body_bottom_m above the
         ground to head_gap_m below the camera) is empty: a person walked there.
A depth pixel whose back-projected point falls in a carved voxel is not fused; optionally a
pixel must also land in a voxel hit by at least min_hit_views views (multi-view consistency).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numba
import numpy as np
from scipy.spatial import cKDTree

from vid2sim.factory.geometry.walked_path import BODY_RADIUS_M, walked_path
from vid2sim.factory.geometry.raycast import pixel_rays_cam
from vid2sim.ranges import checked


@checked
@dataclass(frozen=True)
class CarveConfig:
    # ray (space) carving: off by default, it did not pay on the GoPro clip (its phantom
    # obstacles are consistent splats, which every view's depth stops at;
    # docs/studies/physical_layer.md)
    rays: bool = False
    body: bool = True  # walker's body carving
    min_hit_views: int = 1  # 2+ = multi-view consistency: a depth voxel seen by that many views
    voxel_m: float = 0.1  # m, edge of the carving grid's voxels
    pixel_stride: int = 2  # carve with every n-th pixel ray (rows and columns)
    near_m: float = 0.3  # rays are free from this distance ...
    margin_m: float = 0.2  # ... up to max(margin_m, margin_rel * depth) before the surface
    margin_rel: float = 0.05  # splat median depth: 3-5 % relative error
    min_free_views: int = 3  # rays: a voxel is carved when at least this many views saw through it ...
    free_ratio: float = 2.0  # ... and at least this many times as many as the views whose depth hit it
    body_radius_m: float = BODY_RADIUS_M  # m, radius of the walker's body swept along the camera path
    body_bottom_m: float = 0.2  # m above the ground where the swept body starts
    head_gap_m: float = 0.1  # m, the swept body stops this far below the camera
    ground_z_m: float = 0.0  # m, ground plane height of the metric frame
    pad_m: float = 1.0  # grid padding above the cameras and below the ground


@dataclass
class VoxelGrid:
    origin: np.ndarray  # [3] world corner of voxel (0, 0, 0)
    shape: tuple[int, int, int]
    voxel: float

    def index(self, pts: np.ndarray) -> np.ndarray:
        """Flat voxel index [P] of points [P, 3]; -1 outside the grid."""
        ijk = np.floor((pts - self.origin) / self.voxel).astype(np.int64)  # [P, 3]
        ok = np.all((ijk >= 0) & (ijk < np.array(self.shape)), axis=1)
        flat = (ijk[:, 0] * self.shape[1] + ijk[:, 1]) * self.shape[2] + ijk[:, 2]
        return np.where(ok, flat, -1)


def grid_for(cam_pos: np.ndarray, reach_m: float, conf: CarveConfig) -> VoxelGrid:
    """Voxel grid covering the cameras [T, 3] plus reach_m horizontally, from below the ground
    to above the cameras."""
    lo = np.array([*(cam_pos[:, :2].min(0) - reach_m), conf.ground_z_m - conf.pad_m])
    hi = np.array([*(cam_pos[:, :2].max(0) + reach_m), cam_pos[:, 2].max() + conf.pad_m])
    shape = tuple(int(s) for s in np.ceil((hi - lo) / conf.voxel_m).astype(int) + 1)
    return VoxelGrid(lo, shape, conf.voxel_m)  # type: ignore[arg-type]


@numba.njit(cache=True, nogil=True)
def _mark_rays(free: np.ndarray, stamp: np.ndarray, view_id: int, origin: np.ndarray,
               dirs: np.ndarray, t0: float, t_end: np.ndarray, step: float,
               grid_origin: np.ndarray, shape: np.ndarray, voxel: float) -> None:
    """free[v] += 1 once per view for every voxel the rays cross between t0 and t_end[r]."""
    for r in range(dirs.shape[0]):
        t = t0
        while t < t_end[r]:
            i = int(np.floor((origin[0] + t * dirs[r, 0] - grid_origin[0]) / voxel))
            j = int(np.floor((origin[1] + t * dirs[r, 1] - grid_origin[1]) / voxel))
            k = int(np.floor((origin[2] + t * dirs[r, 2] - grid_origin[2]) / voxel))
            if 0 <= i < shape[0] and 0 <= j < shape[1] and 0 <= k < shape[2]:
                v = (i * shape[1] + j) * shape[2] + k
                if stamp[v] != view_id:
                    stamp[v] = view_id
                    free[v] += 1
            t += step


@dataclass
class FreeSpace:
    grid: VoxelGrid
    free: np.ndarray  # [V] int16 views whose rays crossed the voxel
    hit: np.ndarray  # [V] int16 views whose depth landed in the voxel
    body: np.ndarray  # [V] bool inside the walker's swept body

    def carved(self, conf: CarveConfig) -> np.ndarray:
        """[V] bool voxels proven empty."""
        out = self.body.copy() if conf.body else np.zeros_like(self.body)
        if conf.rays:
            out |= (self.free >= conf.min_free_views) & (self.free >= conf.free_ratio * self.hit)
        return out


def body_voxels(grid: VoxelGrid, cam_pos: np.ndarray, conf: CarveConfig) -> np.ndarray:
    """[V] bool voxel centres inside the body swept along the camera path [T, 3]."""
    walked = walked_path(cam_pos, conf.voxel_m / 2)  # [S, 3]
    nx, ny, nz = grid.shape
    xs = grid.origin[0] + (np.arange(nx) + 0.5) * conf.voxel_m
    ys = grid.origin[1] + (np.arange(ny) + 0.5) * conf.voxel_m
    zs = grid.origin[2] + (np.arange(nz) + 0.5) * conf.voxel_m
    X, Y = np.meshgrid(xs, ys, indexing="ij")  # [nx, ny]
    d, nearest = cKDTree(walked[:, :2]).query(np.stack([X.ravel(), Y.ravel()], 1),
                                              distance_upper_bound=conf.body_radius_m)
    inside_xy = np.isfinite(d)  # [nx * ny]
    top = np.full(inside_xy.shape, -np.inf)
    top[inside_xy] = walked[nearest[inside_xy], 2] - conf.head_gap_m
    z_ok = (zs[None, :] >= conf.ground_z_m + conf.body_bottom_m) & (zs[None, :] <= top[:, None])
    return z_ok.reshape(-1)  # [nx * ny * nz], flat order (i, j, k)


def free_space(depths: Sequence[np.ndarray], Ks: Sequence[np.ndarray],
               c2ws: Sequence[np.ndarray], reach_m: float, conf: CarveConfig) -> FreeSpace:
    """Free / hit counts from every view's rays and depth (depth [H, W], 0 = invalid)."""
    cam_pos = np.array([np.asarray(c, np.float64)[:3, 3] for c in c2ws])  # [T, 3]
    grid = grid_for(cam_pos, reach_m, conf)
    n = int(np.prod(grid.shape))
    free, hit = np.zeros(n, np.int16), np.zeros(n, np.int16)
    stamp = np.full(n, -1, np.int32)
    shape = np.array(grid.shape, np.int64)
    s = max(1, conf.pixel_stride)
    need_rays = conf.rays or conf.min_hit_views > 1
    for vid, (depth, K, c2w) in enumerate(zip(depths, Ks, c2ws) if need_rays else ()):
        c2w = np.asarray(c2w, np.float64)
        H, W = depth.shape
        rays = pixel_rays_cam(K, W, H)  # [H, W, 3] z = 1
        pts = (rays * depth[..., None]) @ c2w[:3, :3].T + c2w[:3, 3]  # [H, W, 3]
        idx = grid.index(pts[depth > 0])
        hit[np.unique(idx[idx >= 0])] += 1
        d = depth[::s, ::s].ravel().astype(np.float64)  # [R]
        ok = d > 0
        dirs = (rays[::s, ::s].reshape(-1, 3) @ c2w[:3, :3].T)[ok]  # [R, 3] unit z in camera
        t_end = d[ok] - np.maximum(conf.margin_m, conf.margin_rel * d[ok])
        _mark_rays(free, stamp, vid, c2w[:3, 3].copy(), np.ascontiguousarray(dirs), conf.near_m,
                   t_end, conf.voxel_m / 2, grid.origin, shape, conf.voxel_m)
    body = body_voxels(grid, cam_pos, conf) if conf.body else np.zeros(n, bool)
    return FreeSpace(grid, free, hit, body)


def keep_mask(depth: np.ndarray, K: np.ndarray, c2w: np.ndarray, space: FreeSpace,
              carved: np.ndarray, conf: CarveConfig) -> np.ndarray:
    """[H, W] bool depth pixels to fuse: valid, not in a carved voxel, and (min_hit_views)
    landing in a voxel enough views hit."""
    H, W = depth.shape
    c2w = np.asarray(c2w, np.float64)
    pts = (pixel_rays_cam(K, W, H) * depth[..., None]) @ c2w[:3, :3].T + c2w[:3, 3]
    idx = space.grid.index(pts.reshape(-1, 3)).reshape(H, W)
    keep = depth > 0
    inside = keep & (idx >= 0)
    bad = np.zeros_like(keep)
    bad[inside] = carved[idx[inside]]
    if conf.min_hit_views > 1:
        bad[inside] |= space.hit[idx[inside]] < conf.min_hit_views
    return keep & ~bad
