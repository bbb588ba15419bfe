"""Collision mesh by TSDF fusion of rendered depth, with the ground removed (paper, supp.).

Stage `meshing`: reads depth views (median depth + camera-frame normals rendered from the
splats, or ground truth), writes into `out_dir`:
  collision.ply      triangle mesh for physics, ground removed, cleaned, simplified
  visual_mesh.ply    vertex-coloured mesh WITH the ground (the mesh-RGB baseline)
  ground_points.npy  [N, 3] float32 world points on the fused ground (walkable map)
  carved_points.npy  [M, 3] float32 world points of the depth pixels the free-space carving
                     removed (they lay in space proven empty, e.g. the walker's body): the
                     walkable stage drops the small mesh pieces they belonged to
  meshing.json       summary (face counts, timings, config)
  stage.json         marker, written by the runner (vid2sim.factory.runtime.runner)

Ground removal (choice: pixel masking as the paper, plus a face filter): a pixel is ground
when its rendered normal, rotated to world, lies within `ground_normal_deg` (paper: delta =
15 deg) of the ground normal (world +z; the world frame has the ground at z = 0) AND its
back-projected point lies within `ground_band_m` (0.15 m) of the ground height seen by that
view (`view_ground_z`: z = 0 refined by at most `ground_adapt_m`). The height band keeps
horizontal surfaces that are not the ground (box tops, benches, kerbs above the band). Two
TSDFs are fused in one pass: the visual one (open3d's legacy volume) gets every pixel, the
collision one (voxel blocks with free-space fill-in, `block_tsdf`; `collision_tsdf`) gets every
pixel except the ground pixels. A final face-level filter removes any leftover face whose
normal and height match the same rule (slivers at ground/obstacle junctions, and the ground
pixels the rendered normals missed).

Real splat renders (the demo street) differ from GT depth in three ways that shaped the
defaults: rendered normals are noisy (median 15-50 deg off on the sidewalk, only ~50 % of the
ground pixels pass 15 deg, but those that pass are ~98 % ground), median depth has 3-5 %
relative error, and the sky holds floaters 8-28 m away. So the pixel mask stays the paper's
(high precision), the face filter takes its normals from PCA over `ground_normal_radius_m` of
the fused surface (robust: the TSDF averages all views), depth beyond `depth_max_m` is not
fused, and the ground points handed to the walkable map are vertices of the fused ground
faces (multi-view averaged heights) rather than single-view pixels.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Iterable, Optional

import numpy as np
import open3d as o3d

from vid2sim.factory.geometry.block_tsdf import BlockTSDF
from vid2sim.factory.geometry.carving import CarveConfig, free_space, keep_mask
from vid2sim.factory.geometry.mesh_ops import remove_fragments, simplify, tidy
from vid2sim.factory.geometry.raycast import pixel_rays_cam
from vid2sim.factory.geometry.visual_mesh import make_visual_mesh
from vid2sim.factory.runtime.stage_cache import StageError, StageWork, Timer
from vid2sim.ranges import checked
from vid2sim.versioning import to_jsonable

STAGE = "meshing"
STAGE_VERSION = 3  # bump when this stage's outputs change for the same inputs

@dataclass(frozen=True)
class MeshingOutputs:
    """This stage's output artifacts, as paths relative to its stage folder (the stage contract)."""

    collision: str = "collision.ply"  # ground removed
    visual: str = "visual_mesh.ply"  # with the ground, vertex colours
    ground_points: str = "ground_points.npy"  # [N, 3] float32
    carved_points: str = "carved_points.npy"  # [M, 3] float32
    summary: str = "meshing.json"


OUTPUTS = MeshingOutputs()



class MeshingError(StageError):
    """Bad input to (or empty output of) the meshing stage."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(STAGE, reason, detail)


@checked
@dataclass
class MeshingConfig:
    voxel_m: float = 0.1  # m, TSDF voxel size (the paper's 0.1)
    # SDF truncation = trunc_voxels * voxel_m. 3.5 (0.35 m; was 4): a narrower band smears less
    # splat depth noise into the free space beside surfaces. Over five splat builds
    # (docs/studies/physical_layer.md) the walked path gained on three and lost on one
    # (100 -> 98.2 %), accuracy median 0.051 -> 0.049 m on the demo street, completeness -0.5
    # to -0.7 points
    trunc_voxels: float = 3.5  # SDF truncation distance, in voxels (x voxel_m)
    depth_min_m: float = 0.1  # m, nearer splat depth is not fused
    # splat depth error grows with distance (median depth of the demo splats: 3-5 % relative,
    # plus floaters in the sky at 8-28 m); beyond ~8 m it exceeds the voxel size and the far
    # street and sky dominate the error (demo: accuracy 0.87 m at 20 m, 0.41 m at 12, 0.27 at 8)
    depth_max_m: float = 8.0  # m, farther splat depth is not fused
    ground_normal_deg: float = 15.0  # paper's delta
    ground_band_m: float = 0.15  # |z| below this (ground plane z = 0) can be ground
    ground_z_m: float = 0.0  # m, ground plane height of the metric frame
    # per-view ground height: the 30th percentile z of flat pixels within this distance of
    # ground_z_m (absorbs alignment error / gentle slopes); 0 disables
    ground_adapt_m: float = 0.3
    ground_adapt_min_pixels: int = 200  # fewer flat pixels near the ground keep ground_z_m for that view
    face_ground_filter: bool = True  # also drop ground-like faces after extraction
    # face-level normals: PCA of the mesh vertices within this radius. Per-face normals of a
    # TSDF mesh of splat depth are noise at the voxel scale (sidewalk: median 28 deg off +z);
    # at 0.5 m the median is 7 deg, so the paper's 15 deg criterion holds again
    ground_normal_radius_m: float = 0.5
    # flat faces down to this far below the ground height are ground too (a road below the
    # kerb, a gutter); only the band above the ground (ground_band_m) can hold obstacle tops
    ground_below_m: float = 0.6
    min_fragment_faces: int = 40  # components with fewer faces are dropped ...
    min_fragment_extent_m: float = 0.25  # ... and so are those whose bbox diagonal is smaller
    target_faces: int = 100_000  # physics-friendly collision mesh (quadric decimation)
    visual_target_faces: int = 300_000  # visual (coloured) mesh budget
    ground_point_cell_m: float = 0.05  # ground points kept: one per xy cell of this size
    # depth-edge filter (`depth_edges`): near-side pixels within edge_px of a depth
    # discontinuity larger than edge_rel x their depth are not fused (silhouette fattening of
    # splat depth); 0 disables. At 0.1 the demo street's path goes 93.5 -> 97.1 % walkable,
    # the GoPro corridor 0.044 -> 0 m^2 (path 83.3 -> 92.8 %), accuracy median 0.053 -> 0.049 m,
    # at 0.6 points of completeness (86.8 -> 86.2 %, on car and facade silhouettes)
    edge_rel: float = 0.1
    edge_px: int = 1  # px, width of the depth-edge band not fused (see edge_rel)
    # free-space carving before fusion (vid2sim.factory.geometry.carving); None = fuse every pixel
    carve: Optional[CarveConfig] = field(default_factory=CarveConfig)
    # TSDF engine of the collision volume: "blocks" (`block_tsdf`: tensor VoxelBlockGrid, plus
    # free-space fill-in of unobserved voxels that fill_free_views views see through; 0 = no
    # fill-in) or "legacy" (open3d ScalableTSDFVolume, the default until 484c1ae). The
    # visual volume (whose ground vertices feed the walkable map) stays legacy. Demo street:
    # completeness 87.1 -> 89.2 % (blocks) -> 90.4 % (+ fill-in), poles 70 -> 98 -> 99.5 %, path
    # 99.3 -> 100 %. On the GoPro clip the more complete mesh holds ornamental grass 0.25-0.3 m
    # beside the walk's end, which a map cleared for 0.3 m blocked (path 95.1 %); the map now
    # clears the walker's body radius (`WalkableConfig.robot_radius_m`; docs/studies/physical_layer.md)
    collision_tsdf: str = "blocks"  # TSDF engine of the collision volume: "blocks" | "legacy"
    fill_free_views: int = 1  # blocks engine: views that must see through an unobserved voxel to free it (0: off)


@dataclass
class DepthView:
    """One rendered (or GT) view. Depth is camera z in metres, 0 = invalid."""

    depth: np.ndarray  # [H, W] float32
    K: np.ndarray  # [3, 3]
    cam_to_world: np.ndarray  # [4, 4] OpenCV axes
    normal_cam: Optional[np.ndarray] = None  # [H, W, 3] camera frame
    rgb: Optional[np.ndarray] = None  # [H, W, 3] uint8
    valid: Optional[np.ndarray] = None  # [H, W] bool
    name: str = ""


@dataclass
class FusionResult:
    visual: o3d.geometry.TriangleMesh  # raw, with ground, coloured
    collision: o3d.geometry.TriangleMesh  # raw, ground pixels excluded
    ground_points: np.ndarray  # [N, 3] float32 world
    n_views: int
    n_valid_pixels: int
    n_ground_pixels: int
    carve_seconds: float = 0.0
    carved_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))  # [M, 3]
    n_filled_voxels: int = 0  # block engine's free-space fill-in


@dataclass
class MeshingResult:
    collision: o3d.geometry.TriangleMesh
    visual: o3d.geometry.TriangleMesh
    ground_points: np.ndarray  # [N, 3]
    summary: dict = field(default_factory=dict)
    carved_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))  # [M, 3]


def check_view(view: DepthView, idx: int) -> np.ndarray:
    """Validate one view; return its effective valid mask [H, W] (raises MeshingError)."""
    name = view.name or f"view[{idx}]"
    depth = np.asarray(view.depth)
    if depth.ndim != 2 or depth.size == 0:
        raise MeshingError("bad_depth", f"{name}: depth must be a non-empty [H, W] array, "
                           f"got shape {depth.shape}")
    if np.asarray(view.K).shape != (3, 3) or not np.all(np.isfinite(view.K)):
        raise MeshingError("bad_intrinsics", f"{name}: K must be a finite [3, 3] matrix")
    c2w = np.asarray(view.cam_to_world, np.float64)
    if c2w.shape != (4, 4) or not np.all(np.isfinite(c2w)):
        raise MeshingError("bad_pose", f"{name}: cam_to_world must be a finite [4, 4] matrix")
    if abs(np.linalg.det(c2w[:3, :3]) - 1.0) > 1e-3:
        raise MeshingError("bad_pose", f"{name}: cam_to_world rotation is not orthonormal")
    for key, arr, shape in (("normal_cam", view.normal_cam, depth.shape + (3,)),
                            ("rgb", view.rgb, depth.shape + (3,)), ("valid", view.valid, depth.shape)):
        if arr is not None and np.asarray(arr).shape != shape:
            raise MeshingError("shape_mismatch", f"{name}: {key} has shape "
                               f"{np.asarray(arr).shape}, expected {shape}")
    valid = np.isfinite(depth) & (depth > 0)
    if view.valid is not None:
        valid &= np.asarray(view.valid, bool)
    return valid


def backproject(depth: np.ndarray, K: np.ndarray, cam_to_world: np.ndarray) -> np.ndarray:
    """World points [H, W, 3] of every pixel (pixel centres at +0.5, camera z depth)."""

    H, W = depth.shape
    pts_cam = pixel_rays_cam(K, W, H) * depth[..., None].astype(np.float64)  # [H, W, 3]
    c2w = np.asarray(cam_to_world, np.float64)
    return pts_cam @ c2w[:3, :3].T + c2w[:3, 3]


def ground_mask(view: DepthView, valid: np.ndarray, conf: MeshingConfig) -> np.ndarray:
    """Ground pixels [H, W] bool: normal within delta of world +z and near the ground plane.

    Without rendered normals (normal_cam None) normals come from depth differences. The
    angle uses |cos| so either normal orientation convention works.
    """
    pts = backproject(np.where(valid, view.depth, 0.0), view.K, view.cam_to_world)
    if view.normal_cam is not None:
        R = np.asarray(view.cam_to_world, np.float64)[:3, :3]
        n_world = np.asarray(view.normal_cam, np.float64) @ R.T  # [H, W, 3]
    else:
        n_world = normals_from_points(pts)
    norm = np.linalg.norm(n_world, axis=-1)
    cos = np.abs(n_world[..., 2]) / np.maximum(norm, 1e-12)
    flat = valid & (cos >= np.cos(np.deg2rad(conf.ground_normal_deg))) & (norm > 1e-6)
    z0 = view_ground_z(pts[..., 2], flat, conf)
    return flat & (np.abs(pts[..., 2] - z0) < conf.ground_band_m)


def view_ground_z(z: np.ndarray, flat: np.ndarray, conf: MeshingConfig) -> float:
    """Ground height seen by one view: a low percentile of flat pixels near ground_z_m.

    The ground is the lowest large flat surface, so the 30th percentile leans away from
    raised flat things (benches, box tops) that share the search window."""
    if conf.ground_adapt_m <= 0:
        return conf.ground_z_m
    cand = z[flat & (np.abs(z - conf.ground_z_m) < conf.ground_adapt_m)]
    if cand.size < conf.ground_adapt_min_pixels:
        return conf.ground_z_m
    return float(np.percentile(cand, 30))


def normals_from_points(pts: np.ndarray) -> np.ndarray:
    """Unnormalised normals [H, W, 3] from central differences of a point map [H, W, 3].

    Fallback when a view has no rendered normals; 0 at the border.
    """
    n = np.zeros_like(pts)
    dx = pts[1:-1, 2:] - pts[1:-1, :-2]
    dy = pts[2:, 1:-1] - pts[:-2, 1:-1]
    n[1:-1, 1:-1] = np.cross(dx, dy)
    return n


def _rgbd(depth: np.ndarray, rgb: np.ndarray, conf: MeshingConfig) -> o3d.geometry.RGBDImage:
    return o3d.geometry.RGBDImage.create_from_color_and_depth(
        o3d.geometry.Image(np.ascontiguousarray(rgb, np.uint8)),
        o3d.geometry.Image(np.ascontiguousarray(depth, np.float32)),
        depth_scale=1.0, depth_trunc=conf.depth_max_m, convert_rgb_to_intensity=False)


def _intrinsic(K: np.ndarray, width: int, height: int) -> o3d.camera.PinholeCameraIntrinsic:
    # open3d rounds the projection to the nearest pixel (pixel centres at integers); ours are
    # at +0.5 (COLMAP / splat renderer), so shift the principal point by half a pixel
    # (measured: Chamfer error is lowest with this shift).
    return o3d.camera.PinholeCameraIntrinsic(width, height, float(K[0, 0]), float(K[1, 1]),
                                             float(K[0, 2]) - 0.5, float(K[1, 2]) - 0.5)


class LegacyTSDF:
    """open3d's coloured ScalableTSDFVolume behind `BlockTSDF`'s interface (integrate,
    fill_free, mesh). It cannot be edited, so it has no free-space fill-in."""

    def __init__(self, conf: MeshingConfig) -> None:
        self.conf = conf
        self.volume = o3d.pipelines.integration.ScalableTSDFVolume(
            voxel_length=conf.voxel_m, sdf_trunc=conf.trunc_voxels * conf.voxel_m,
            color_type=o3d.pipelines.integration.TSDFVolumeColorType.RGB8)

    def integrate(self, depth: np.ndarray, K: np.ndarray, cam_to_world: np.ndarray,
                  rgb: Optional[np.ndarray] = None) -> None:
        """Fuse one view: depth [H, W] float32 (0 = skip), rgb [H, W, 3] uint8 (grey if None)."""
        H, W = depth.shape
        rgb = rgb if rgb is not None else np.full((H, W, 3), 128, np.uint8)
        intrinsic = _intrinsic(np.asarray(K, np.float64), W, H)
        world_to_cam = np.linalg.inv(np.asarray(cam_to_world, np.float64))
        self.volume.integrate(_rgbd(depth, rgb, self.conf), intrinsic, world_to_cam)

    def fill_free(self, views: list, min_views: int, near_m: float = 0.1) -> int:
        return 0

    def mesh(self) -> o3d.geometry.TriangleMesh:
        return self.volume.extract_triangle_mesh()


def clamped_depth(view: DepthView, idx: int, conf: MeshingConfig) -> np.ndarray:
    """Validated depth [H, W] float32 with invalid or out-of-range pixels set to 0."""
    valid = check_view(view, idx)
    depth = np.where(valid, view.depth, 0.0).astype(np.float32)
    depth[(depth < conf.depth_min_m) | (depth > conf.depth_max_m)] = 0.0
    if conf.edge_rel > 0:
        depth[depth_edges(depth, conf.edge_rel, conf.edge_px)] = 0.0
    return depth


def depth_edges(depth: np.ndarray, rel: float, radius_px: int) -> np.ndarray:
    """[H, W] bool valid pixels on the near side of a depth discontinuity: within radius_px of
    it (the valid depths of the (2 radius_px + 1)^2 window span more than rel x the pixel's
    depth) and closer to the window's nearest depth than to its farthest. Splat depth blends
    a foreground surface into the background across its silhouette (edge fattening): those
    pixels carry the near depth on the far side of the true edge."""
    from scipy import ndimage

    valid = depth > 0
    k = 2 * radius_px + 1
    hi = ndimage.maximum_filter(np.where(valid, depth, 0.0), size=k)
    lo = ndimage.minimum_filter(np.where(valid, depth, np.inf), size=k)
    return valid & (hi - lo > rel * depth) & (depth - lo < hi - depth)


def carve_views(views: list[DepthView], conf: MeshingConfig) -> tuple[list[np.ndarray], np.ndarray]:
    """Depth [H, W] per view with the pixels in proven-empty space removed (conf.carve), and
    the world points [M, 3] float32 of the pixels the carving removed."""
    depths = [clamped_depth(v, i, conf) for i, v in enumerate(views)]
    none = np.zeros((0, 3), np.float32)
    if conf.carve is None or not depths or not any(d.any() for d in depths):
        return depths, none
    Ks = [np.asarray(v.K, np.float64) for v in views]
    c2ws = [np.asarray(v.cam_to_world, np.float64) for v in views]
    space = free_space(depths, Ks, c2ws, conf.depth_max_m, conf.carve)
    carved = space.carved(conf.carve)
    in_empty = replace(conf.carve, min_hit_views=1)  # removed as lying in proven-empty space
    kept, removed = [], [none]
    for d, K, c in zip(depths, Ks, c2ws):
        keep = keep_mask(d, K, c, space, carved, conf.carve)
        kept.append(np.where(keep, d, 0.0).astype(np.float32))
        gone = (d > 0) & ~(keep if conf.carve.min_hit_views <= 1 else
                           keep_mask(d, K, c, space, carved, in_empty))
        if gone.any():
            removed.append(backproject(d, K, c)[gone].astype(np.float32))
    return kept, np.concatenate(removed)


TSDF_ENGINES = ("legacy", "blocks")


def _collision_volume(conf: MeshingConfig):
    """The collision TSDF for conf.collision_tsdf (MeshingError bad_config otherwise)."""
    if conf.collision_tsdf not in TSDF_ENGINES:
        raise MeshingError("bad_config", f"collision_tsdf must be one of {TSDF_ENGINES}, "
                           f"got {conf.collision_tsdf!r}")
    if conf.collision_tsdf == "blocks":
        return BlockTSDF(conf.voxel_m, conf.trunc_voxels, conf.depth_max_m)
    return LegacyTSDF(conf)


def fill_views(views: list[DepthView]) -> list[tuple]:
    """(raw rendered depth [H, W] float32, valid [H, W], K, cam_to_world) per view: what the
    free-space fill-in sees through (any range, unlike the fused depth)."""
    return [(np.nan_to_num(np.asarray(v.depth, np.float32)), check_view(v, i), v.K, v.cam_to_world)
            for i, v in enumerate(views)]


def fuse_tsdf(views: Iterable[DepthView], conf: MeshingConfig) -> FusionResult:
    """Fuse views into two TSDFs (visual: all pixels, collision: no ground), after carving.

    `views` may be a lazy generator (e.g. rendering splats view by view); carving needs every
    view twice, so they are held in memory. Raises MeshingError when there are no views or
    no valid depth at all.
    """
    views = list(views)
    vol_vis, vol_col = LegacyTSDF(conf), _collision_volume(conf)
    ground_pts: list[np.ndarray] = []
    n_valid = n_ground = 0
    with Timer() as t_carve:
        depths, carved_pts = carve_views(views, conf)
    for view, depth in zip(views, depths):
        valid = depth > 0
        gmask = ground_mask(view, valid, conf)
        vol_vis.integrate(depth, view.K, view.cam_to_world, view.rgb)
        vol_col.integrate(np.where(gmask, 0.0, depth).astype(np.float32), view.K, view.cam_to_world,
                          view.rgb)
        pts = backproject(depth, view.K, view.cam_to_world)[gmask]  # [P, 3]
        ground_pts.append(thin_xy(pts, conf.ground_point_cell_m))
        n_valid += int(valid.sum())
        n_ground += int(gmask.sum())
    if not views:
        raise MeshingError("no_views", "no depth views were given")
    if n_valid == 0:
        raise MeshingError("no_valid_depth", f"all {len(views)} depth views are empty or invalid "
                           f"(range {conf.depth_min_m}..{conf.depth_max_m} m)")
    n_filled = (vol_col.fill_free(fill_views(views), conf.fill_free_views, conf.depth_min_m)
                if conf.fill_free_views > 0 else 0)
    gp = thin_xy(np.concatenate(ground_pts), conf.ground_point_cell_m)
    return FusionResult(vol_vis.mesh(), vol_col.mesh(), gp, len(views), n_valid, n_ground,
                        round(t_carve.seconds, 3), carved_pts, n_filled)


def thin_xy(pts: np.ndarray, cell_m: float) -> np.ndarray:
    """One point [K, 3] float32 per occupied xy cell of size cell_m (bounds memory)."""
    if len(pts) == 0:
        return np.zeros((0, 3), np.float32)
    keys = np.floor(pts[:, :2] / cell_m).astype(np.int64)  # [P, 2]
    _, first = np.unique(keys, axis=0, return_index=True)
    return pts[np.sort(first)].astype(np.float32)


def pca_vertex_normals(vertices: np.ndarray, which: np.ndarray, radius_m: float) -> np.ndarray:
    """Unit normals [K, 3] of vertices[which] ([V, 3], which [K] indices) by PCA of the vertices
    within radius_m (robust to voxel-scale noise, unlike face normals; sign arbitrary). Only
    vertices within radius_m in z of the wanted ones can be neighbours, so the search runs on
    that slab: exact, and the walls and trees above the ground band cost nothing."""
    z = vertices[which, 2]
    lo, hi = z.min() - radius_m, z.max() + radius_m
    slab = np.flatnonzero((vertices[:, 2] >= lo) & (vertices[:, 2] <= hi))  # [S] sorted
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(vertices[slab]))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamRadius(radius_m))
    row = np.empty(len(vertices), np.int64)
    row[slab] = np.arange(len(slab))  # vertex index -> row of the slab cloud
    return np.asarray(pc.normals)[row[which]]


def ground_faces(mesh: o3d.geometry.TriangleMesh, conf: MeshingConfig) -> np.ndarray:
    """Faces [F] bool that are ground: the centroid lies in [ground_z - ground_below_m,
    ground_z + ground_band_m], and the face normal or the mean PCA normal of its vertices lies
    within delta of +-z (exact slivers at junctions / noisy flat ground)."""
    f = np.asarray(mesh.triangles)
    if len(f) == 0:
        return np.zeros(0, bool)
    v = np.asarray(mesh.vertices)
    zc = v[f].mean(axis=1)[:, 2] - conf.ground_z_m  # [F]
    band = (zc >= -conf.ground_below_m) & (zc < conf.ground_band_m)  # [F]
    if not band.any():
        return band
    cos_d = np.cos(np.deg2rad(conf.ground_normal_deg))
    mesh.compute_triangle_normals()
    flat = np.abs(np.asarray(mesh.triangle_normals)[:, 2]) >= cos_d  # [F]
    steep = band & ~flat  # [F] the faces the PCA normals can still make ground
    if conf.ground_normal_radius_m > 0 and steep.any():
        fs = f[steep]  # [S, 3]
        which, inv = np.unique(fs, return_inverse=True)
        nz = np.abs(pca_vertex_normals(v, which, conf.ground_normal_radius_m)[:, 2])  # [K]
        flat[steep] = nz[inv.reshape(fs.shape)].mean(axis=1) >= cos_d
    return flat & band


def remove_ground_faces(mesh: o3d.geometry.TriangleMesh, conf: MeshingConfig
                        ) -> o3d.geometry.TriangleMesh:
    """Drop the faces `ground_faces` selects (in place; returns the mesh)."""
    if len(mesh.triangles) == 0:
        return mesh
    mesh.remove_triangles_by_mask(ground_faces(mesh, conf))
    mesh.remove_unreferenced_vertices()
    return mesh


def mesh_ground_points(mesh: o3d.geometry.TriangleMesh, conf: MeshingConfig) -> np.ndarray:
    """Vertices [N, 3] float32 of the ground faces of a fused mesh WITH the ground: heights
    averaged over all views by the TSDF, far less noisy than single-view ground pixels."""
    g = ground_faces(mesh, conf)
    if not g.any():
        return np.zeros((0, 3), np.float32)
    v = np.asarray(mesh.vertices)[np.unique(np.asarray(mesh.triangles)[g])]
    return thin_xy(v, conf.ground_point_cell_m)


def clean_collision_mesh(mesh: o3d.geometry.TriangleMesh, conf: MeshingConfig
                         ) -> o3d.geometry.TriangleMesh:
    """Ground-face filter, fragment removal, then simplification to the target size."""
    mesh = tidy(mesh)
    if conf.face_ground_filter:
        mesh = remove_ground_faces(mesh, conf)
    mesh = remove_fragments(mesh, conf.min_fragment_faces, conf.min_fragment_extent_m)
    mesh = simplify(mesh, conf.target_faces)
    mesh.compute_vertex_normals()
    return mesh


def build_meshes(views: Iterable[DepthView], conf: MeshingConfig) -> MeshingResult:
    """Fusion + cleanup: the whole meshing computation without touching disk."""

    with Timer() as t_fuse:
        fused = fuse_tsdf(views, conf)
    raw_faces = len(fused.collision.triangles)
    with Timer() as t_clean:
        collision = clean_collision_mesh(fused.collision, conf)
        ground_points = mesh_ground_points(tidy(fused.visual), conf)
        if len(ground_points) == 0:  # no flat ground in the fused mesh: fall back to pixels
            ground_points = fused.ground_points
        visual = make_visual_mesh(fused.visual, conf.visual_target_faces)
    if len(collision.triangles) == 0:
        raise MeshingError("empty_mesh", "no collision geometry left after ground removal "
                           f"and cleanup ({raw_faces} raw faces, {fused.n_views} views)")
    summary = dict(n_views=fused.n_views, n_valid_pixels=fused.n_valid_pixels,
                   n_ground_pixels=fused.n_ground_pixels, raw_collision_faces=raw_faces,
                   collision_faces=len(collision.triangles), visual_faces=len(visual.triangles),
                   n_ground_points=len(ground_points), n_carved_points=len(fused.carved_points),
                   n_filled_voxels=fused.n_filled_voxels,
                   fuse_seconds=round(t_fuse.seconds, 3), carve_seconds=fused.carve_seconds,
                   clean_seconds=round(t_clean.seconds, 3))
    return MeshingResult(collision, visual, ground_points, summary, fused.carved_points)


def save_mesh(mesh: o3d.geometry.TriangleMesh, path: Path) -> None:
    if not o3d.io.write_triangle_mesh(str(path), mesh, write_ascii=False, compressed=False,
                                      print_progress=False):
        raise MeshingError("write_failed", f"could not write {path}")


def work(conf: MeshingConfig, views: Iterable[DepthView], input_key: str = "") -> StageWork:
    """Fusing `views` into meshes: keyed by the config and `input_key`, which identifies the
    views (e.g. the reconstruction stage key); views may be a lazy generator, only consumed when
    the stage actually runs."""
    return StageWork(STAGE, STAGE_VERSION, conf, (input_key,), lambda out_dir: build(conf, views, out_dir))


def build(conf: MeshingConfig, views: Iterable[DepthView], out_dir: Path) -> dict:
    """Fuse `views` and write the meshes, points and meshing.json into the empty `out_dir`;
    returns the summary."""
    res = build_meshes(views, conf)
    save_mesh(res.collision, out_dir / OUTPUTS.collision)
    save_mesh(res.visual, out_dir / OUTPUTS.visual)
    np.save(out_dir / OUTPUTS.ground_points, res.ground_points.astype(np.float32))
    np.save(out_dir / OUTPUTS.carved_points, res.carved_points.astype(np.float32))
    (out_dir / OUTPUTS.summary).write_text(json.dumps(
        {"summary": res.summary, "config": to_jsonable(conf)}, indent=2))
    return res.summary
