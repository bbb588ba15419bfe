"""TSDF fusion on open3d's sparse voxel-block grid (tensor API), with free-space fill-in.

The meshing stage's collision-volume engine (`MeshingConfig.collision_tsdf = "blocks"`, the
default since 484c1ae). Reads depth views (camera z in metres, 0 = not fused); writes
nothing: `mesh()` returns a legacy open3d TriangleMesh like the ScalableTSDFVolume it replaces.

Fill-in (`fill_free`). Marching cubes makes no surface in a cube with an unobserved corner.
Beside thin structures (poles) and along silhouettes against a far background, the voxels
next to a surface are seen only through pixels whose depth was not fused (beyond
`depth_max_m`, or on the depth-edge rim), so they keep zero weight and the surface there is
lost. `fill_free` sets such a voxel free (tsdf +1, weight 1) when at least `min_views` views
see through it: their valid rendered depth lies a truncation band or more beyond it. A filled
voxel only completes cubes next to observed negative voxels; it never moves an observed surface.
"""

from __future__ import annotations

from typing import Optional

import numba
import numpy as np
import open3d as o3d
import open3d.core as o3c

from vid2sim.factory.geometry.mesh_ops import canonical_order

BLOCK_RESOLUTION = 16  # voxels per block side: the legacy volume's unit size
INITIAL_BLOCKS = 1024  # the hash map grows past this on demand


@numba.njit(cache=True, nogil=True, parallel=True)
def _see_through(points: np.ndarray, world_to_cam: np.ndarray, K: np.ndarray, depth: np.ndarray,
                 valid: np.ndarray, near: float, band: float, need: int) -> np.ndarray:
    """Votes [N] int32: for each of points [N, 3], the number of views (world_to_cam [V, 4, 4],
    K [V, 3, 3], depth [V, H, W], valid [V, H, W]) whose pixel of the point holds valid depth
    >= its camera z + band, counted up to `need` (a point stops once it has enough)."""
    V, H, W = depth.shape
    votes = np.zeros(points.shape[0], np.int32)
    for i in numba.prange(points.shape[0]):
        n = 0
        for j in range(V):
            T = world_to_cam[j]
            x, y, z = T[0, 3], T[1, 3], T[2, 3]
            for k in range(3):  # camera coordinates of points[i]
                x += T[0, k] * points[i, k]
                y += T[1, k] * points[i, k]
                z += T[2, k] * points[i, k]
            if z <= near:
                continue
            u = int(np.floor(K[j, 0, 0] * x / z + K[j, 0, 2]))  # pixel centres at +0.5
            v = int(np.floor(K[j, 1, 1] * y / z + K[j, 1, 2]))
            if 0 <= u < W and 0 <= v < H and valid[j, v, u] and depth[j, v, u] - z >= band:
                n += 1
                if n >= need:
                    break
        votes[i] = n
    return votes


def _stack_views(views: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]):
    """(world_to_cam [V, 4, 4], K [V, 3, 3], depth [V, H, W], valid [V, H, W]) of the fill-in's
    views, padded to the largest image (padding is not valid)."""
    H = max(d.shape[0] for d, *_ in views)
    W = max(d.shape[1] for d, *_ in views)
    depth = np.zeros((len(views), H, W), np.float32)
    valid = np.zeros((len(views), H, W), np.bool_)
    for j, (d, ok, _, _) in enumerate(views):
        depth[j, :d.shape[0], :d.shape[1]] = d
        valid[j, :d.shape[0], :d.shape[1]] = ok
    w2c = np.stack([np.linalg.inv(np.asarray(c2w, np.float64)) for *_, c2w in views])
    K = np.stack([np.asarray(k, np.float64) for _, _, k, _ in views])
    return w2c, K, depth, valid


class BlockTSDF:
    """Depth-only TSDF (no colour: the collision mesh needs none) on a sparse block grid."""

    def __init__(self, voxel_m: float, trunc_voxels: float, depth_max_m: float) -> None:
        self.voxel_m, self.trunc_voxels, self.depth_max_m = voxel_m, trunc_voxels, depth_max_m
        self.grid = o3d.t.geometry.VoxelBlockGrid(
            ("tsdf", "weight"), (o3c.float32, o3c.float32), ((1), (1)), voxel_m,
            BLOCK_RESOLUTION, INITIAL_BLOCKS, o3c.Device("CPU:0"))

    @property
    def trunc_m(self) -> float:
        return self.trunc_voxels * self.voxel_m

    def integrate(self, depth: np.ndarray, K: np.ndarray, cam_to_world: np.ndarray,
                  rgb: Optional[np.ndarray] = None) -> None:
        """Fuse one view: depth [H, W] float32 camera z (0 = skip), K [3, 3] with pixel centres
        at +0.5 (the tensor kernel floors projections, so K goes in unshifted), cam_to_world
        [4, 4] OpenCV axes; rgb is ignored (depth only)."""
        if not (depth > 0).any():
            return
        img = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(depth, np.float32)))
        Kt = o3c.Tensor(np.asarray(K, np.float64))
        ext = o3c.Tensor(np.linalg.inv(np.asarray(cam_to_world, np.float64)))
        blocks = self.grid.compute_unique_block_coordinates(img, Kt, ext, 1.0, self.depth_max_m,
                                                            self.trunc_voxels)
        self.grid.integrate(blocks, img, Kt, ext, 1.0, self.depth_max_m, self.trunc_voxels)

    def fill_free(self, views: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
                  min_views: int, near_m: float = 0.1) -> int:
        """Set unobserved voxels free that >= min_views views see through (module docstring).
        views: (depth [H, W] float32 raw rendered depth, valid [H, W] bool, K [3, 3],
        cam_to_world [4, 4]). Returns the number of voxels filled."""
        if min_views <= 0 or self.grid.hashmap().size() == 0:
            return 0
        coords, index = self.grid.voxel_coordinates_and_flattened_indices()
        weight = self.grid.attribute("weight").reshape((-1,)).numpy()  # shares memory
        tsdf = self.grid.attribute("tsdf").reshape((-1,)).numpy()
        index = index.numpy()
        unseen = weight[index] <= 0
        points = np.ascontiguousarray(coords.numpy()[unseen], np.float64)  # [N, 3]
        votes = _see_through(points, *_stack_views(views), near_m, self.trunc_m, min_views)
        filled = index[unseen][votes >= min_views]
        tsdf[filled] = 1.0
        weight[filled] = 1.0
        return int(len(filled))

    def mesh(self) -> o3d.geometry.TriangleMesh:
        """Marching cubes over cubes whose 8 corners are all observed (or filled), in canonical
        order: the block hash map hands out blocks in a different order from run to run, and the
        clean-up's decimation depends on the order."""
        if self.grid.hashmap().size() == 0:
            return o3d.geometry.TriangleMesh()
        return canonical_order(self.grid.extract_triangle_mesh(0.5).to_legacy())
