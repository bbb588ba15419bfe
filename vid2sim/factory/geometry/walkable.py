"""Physical layer: the walkable map and the collision mesh the envs drive in, made to agree.

Stage `walkable`: reads ground points (meshing's ground_points.npy), the fused collision mesh
and the camera path; writes `walkable.npz` (scene-bundle format: grid uint8 [H, W] 1 = walkable,
origin float64 [2], resolution float64), the physical `collision.ply` the bundle ships, plus
`walkable.json` (the runner adds the stage marker).

Grid convention and the one reader: `vid2sim.formats.walkable` (WalkableGrid, load_walkable).

Agreement by construction (the envs plan on the map and collide with the mesh in pybullet):
collision geometry lower than the robot's step above the local ground is ground (kerbs the
robot climbs, reconstructed ground noise) and is DROPPED from the collision mesh; every other
face blocks the map wherever it lies below `obstacle_max_z_m` above the local ground. So no
walkable cell (eroded by the robot's radius) has collision geometry anywhere in the robot's
body band, whatever the body's height; `tests/test_physical_layer.py` checks it on a fused scene.

Steps:
1. ground evidence: ground-classified depth pixels back-projected to world (meshing), and
   a corridor of `path_radius_m` around the camera path (someone walked there), rasterised;
   gaps closed with a disc of `close_radius_m`; holes grown over (enclosed by seen ground,
   and after step 4 by seen ground, obstacles and the ground beyond kerbs).
2. local ground height: median z of the ground points in the cell, median-filtered over
   step_smooth_m, nearest seen cell elsewhere (z = 0 without ground points); the walked
   corridor anchored at one height.
3. step height: `obstacle_min_z_m` (0.1 m, the robot's step; the envs' box rides 0.15 m up),
   raised to noise_k x the measured ground-height noise on reconstructed ground. Collision
   faces whose vertices all lie lower than the step above the local ground are dropped,
   unless within base_radius_m of geometry above the step (an obstacle's base).
   Optionally (floater_max_area_m2 > 0) small components that do not reach down to the local
   ground (reconstruction floaters) are dropped first. After the trim, what it leaves of noise
   lumps goes too: lump tops, pieces under `min_piece_area_m2`, and small pieces that the
   meshing's carving cut (`carved_points`: part of their depth lay inside the walker's body).
4. obstacles: the remaining collision surface below `obstacle_max_z_m` (1.8 m: awnings and
   canopies above do not block a ground robot; above `overhead_clear_m`, 1.2 m, only where the
   ground beneath was not seen) rasterised, plus the ground beyond a kerb drop
   beside the walk (`kerbs.py`: height profiles across the walk aggregated along it) and,
   optionally, local ground steps (smoothed height range > max_step_m within step_window_m),
   inflated by `robot_radius_m` (the walker's body radius, 0.25 m; environments add their
   robot's own clearance on top): a cell is blocked when its centre lies within
   the radius of a surface sample (exact distance) or of a kerb-step cell's centre. Steps 1-4
   model the ground on `resolution_m` cells; this clearance test and the map run on the finer
   `map_resolution_m` cells (each ground cell split k x k).
5. keep the 4-connected component(s) containing the camera path (each camera position
   snapped to the nearest walkable cell within `snap_m`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from vid2sim.factory.geometry.floaters import (
    carved_pieces, face_components, floater_faces, lump_tops, small_pieces,
)
from vid2sim.factory.geometry.kerbs import KerbConfig, kerb_cells
from vid2sim.factory.geometry.map_evidence import MapEvidence, path_miss_causes
from vid2sim.factory.geometry.walked_path import BODY_RADIUS_M, walked_path
from vid2sim.factory.geometry.raycast import MeshLike, mesh_arrays
from vid2sim.factory.geometry.surface_sampling import points_by_spacing
from vid2sim.factory.runtime.stage_cache import StageError, StageWork
from vid2sim.formats.robot import ROBOT
from vid2sim.formats.walkable import WALKABLE_NPZ, WalkableGrid
from vid2sim.ranges import checked
from vid2sim.versioning import to_jsonable

STAGE = "walkable"
STAGE_VERSION = 9  # bump when this stage's outputs change for the same inputs

@dataclass(frozen=True)
class WalkableOutputs:
    """This stage's output artifacts, as paths relative to its stage folder (the stage contract)."""

    grid: str = WALKABLE_NPZ  # vid2sim.formats.walkable
    collision: str = "collision.ply"  # the physical collision mesh (sub-step ground dropped)
    summary: str = "walkable.json"


OUTPUTS = WalkableOutputs()



class WalkableError(StageError):
    """Bad input to the walkable-map stage, or a map that cannot hold the camera path."""

    def __init__(self, reason: str, detail: str = "") -> None:
        super().__init__(STAGE, reason, detail)


@checked
@dataclass
class WalkableConfig:
    resolution_m: float = 0.1  # m, cell size of the ground model (evidence, heights, noise, kerbs)
    # the clearance a walkable cell's centre keeps from collision surface and kerbs: the
    # walker's body radius, what the video proves free along the walk (since 484c1ae; was the
    # robot's 0.3 m half-width). At 0.3 m the corridor check failed true geometry the walker
    # passed within 0.25-0.3 m of: ornamental grass on the GoPro clip that the body carving
    # shows the walker brushing through, and a GT obstacle 0.263 m from the walk of synthetic
    # street seed 5 (docs/studies/physical_layer.md). Environments add their robot's own clearance on top
    # (`EpisodeConfig.clearance` is counted from the surface minus this, read back from the
    # bundle by `envs.scenes.walkable_inflation`), so their planners keep the same distance
    robot_radius_m: float = BODY_RADIUS_M  # m, clearance a walkable cell's centre keeps from surfaces and kerbs
    # the robot's step: collision geometry lower than this above the local ground is ground
    # (dropped from the collision mesh when trim_collision, else only ignored by the map)
    obstacle_min_z_m: float = 0.1
    obstacle_max_z_m: float = 1.8  # m above the local ground: higher collision geometry does not block the map
    # overhead: surface higher than this above the local ground (the envs' box top 0.75 m plus
    # 0.45 m for ground-height noise) blocks the map only where the ground beneath it was not
    # seen. Where the video saw ground under a canopy or branch, the robot drives under it; where
    # it did not (foliage on a planter hides the planter's far side), it still blocks. Measured:
    # a canopy sagging to 1.8 m 0.13 m beside the GoPro walk split the map (path 93.8 % -> 97.4 %,
    # 1 component); demo splat build unchanged; exact-GT street IoU 0.904 -> 0.897 (0.26 m^2 opened
    # beside a planter whose foliage was the only fused surface there). None: every surface up to
    # obstacle_max_z_m blocks
    overhead_clear_m: Optional[float] = 1.2
    ground_z_m: float = 0.0  # m, ground plane height of the metric frame
    min_ground_hits: int = 1  # ground points needed to mark a cell as seen ground
    close_radius_m: float = 0.3  # morphological closing of the ground evidence
    path_radius_m: float = 0.3  # camera-path corridor counted as ground (0 disables)
    snap_m: float = 1.0  # how far a camera position may be from walkable cells
    max_dist_from_path_m: float = 30.0  # ground points farther from the path are ignored
    margin_m: float = 0.5  # grid padding around the evidence
    # local step test: ground whose height varies by more than max_step_m (raised to noise_k x
    # the ground noise) within step_window_m blocks like an obstacle; 0 disables. Off by
    # default: on splat ground (+-0.05-0.1 m per cell) it fires on noise beside the walk (demo
    # street: walkable IoU 0.703 with it, 0.766 without; GoPro 11.5 vs 16.6 m^2, same path
    # figures); kerbs along the walk are found by `kerb` instead, from profiles aggregated
    # along it. 0.08 (the kerb test of exact depth) to find steps that cross the walk
    max_step_m: float = 0.0
    step_window_m: float = 0.2  # m, neighbourhood of the local step test
    # per-cell ground heights are median-filtered over this size before the step test and the
    # obstacle heights (reconstructed ground is +-0.1 m noisy per cell; a kerb edge survives a
    # median filter); 0 disables
    step_smooth_m: float = 0.5
    # grow the ground over holes of the evidence that seen ground encloses (ground occluded
    # by obstacles, unseen patches on the walk): the fitted ground surface is continuous there;
    # obstacles and kerb steps still block it afterwards
    fill_holes: bool = True
    # grow the ground also over unseen cells that seen ground, obstacles and the ground beyond
    # kerbs enclose together (behind a planter, between it and the kerb; past its far end): demo
    # street walkable IoU 0.755 -> 0.766, GoPro 15.4 -> 16.6 m^2, nothing else moves
    fill_to_obstacles: bool = True
    # the walked corridor (camera path swept by this radius) is ground, at one height: the
    # median of the ground points inside it (robust to the per-cell noise, which is worst
    # there, right under the camera); it anchors the local ground heights, and kerb steps
    # inside it do not block (the walker went over them); 0 disables
    walked_radius_m: float = 0.25
    # noise-adaptive thresholds: max_step_m and obstacle_min_z_m are raised to at least
    # noise_k x the ground-height noise (robust sigma of per-cell heights around the smoothed
    # map at the step scale; ~0 on exact depth, ~0.035 m on the splat demo); 0 disables. The
    # noise is heavy-tailed: k = 3 / 4 / 6 gave walkable IoU 0.31 / 0.45 / 0.61 on the demo
    noise_k: float = 6.0
    # drop the collision faces below the step (physical layer: map and mesh agree); False keeps
    # the fused mesh and only ignores low geometry in the map (the old, disagreeing behaviour)
    trim_collision: bool = True
    # sub-step faces this close to geometry above the step are an obstacle's base (a wall's or
    # a planter's lowest 0.1-0.3 m): kept, they lie in blocked cells anyway
    base_radius_m: float = 0.0
    # the robot's box (vid2sim.formats.robot.ROBOT, which the envs' RobotConfig also reads:
    # 0.15 m ground clearance, 0.6 m tall) above z = 0, their ground plane: after trimming, a
    # surface sample blocks the map when it lies in this band, or between body_bottom_m and
    # obstacle_max_z_m above the local ground; what lies below body_bottom_m on both counts
    # cannot touch the box
    body_bottom_m: float = ROBOT.body_bottom_m
    body_top_m: float = ROBOT.body_top_m  # m above z = 0, top of the robot's box (0.75 m; see body_bottom_m)
    # inflate obstacles by exact distances from the cell centres to the surface samples (True)
    # rather than cell centre to occupied cell centre (up to 0.07 m off either way at 0.1 m)
    exact_inflation: bool = True
    # kerb drops found on the ground height profile across the walk, aggregated along it
    # (geometry/kerbs.py); the cells beyond a drop block like step cells. None disables
    kerb: Optional[KerbConfig] = field(default_factory=KerbConfig)
    # cell size of the robot-centre map the envs get (resolution_m divided by an integer): the
    # ground model (evidence, heights, noise, kerbs) stays at resolution_m, the clearance test
    # (cell centre within robot_radius_m of a surface sample) runs on these finer cells. At
    # 0.1 m a cell centre lies up to 0.07 m from a point in the cell, so a walked position
    # 0.345 m from a surface fell in a blocked cell (demo street path 97.1 -> 98.9 % at 0.05).
    # Then 0.05 -> 0.025 (a centre within 0.018 m of any point in its cell): demo path
    # 98.9 -> 99.3 %, GoPro 97.8 -> 98.2 %; +0.1 CPU-s per clip; the envs' planner searches the
    # finer grid in ~5 ms per distance field (demo street, 300 x 908 cells)
    map_resolution_m: float = 0.025
    # floaters (`floater_faces`): a connected component of the collision mesh (pieces within
    # floater_join_m joined: cleanup splits one surface into pieces 1-4 cm apart, e.g. a demo
    # planter face) that could block the map (lowest vertex below obstacle_max_z_m), whose
    # lowest vertex lies more than max(floater_gap_m, floater_noise_k x ground noise) above
    # the local ground (nothing holds it up) and whose area is below floater_max_area_m2 is
    # dropped before trimming. Measured on the fast-preset factory scenes (pieces joined at
    # 0.05 m): what stands on the ground reaches -0.3..+0.09 m (GoPro, 3 sigma = 0.16 m; demo
    # <= 0); an earlier GoPro pavement lump was 0.2-0.45 m up, 0.22 m^2; on the demo the
    # unsupported pieces > 0.14 m from any GT surface are 0.2-0.29 m^2 (dropped at 0.4), the
    # smallest real unsupported piece (car body, 0.7 m up) 0.50 m^2, cars 0.8-1.9, canopies
    # 1-40 m^2. Off (0) by default: on the rebuilt scenes no floater blocks the walk (path
    # figures unchanged), and on the GoPro clip it also drops real vegetation pieces that the
    # mesh holds up by nothing (a hedge top 1 m from the walk, grass heads): the
    # benchmarks/meshing.py variant "default + floaters dropped ..." measures it
    floater_max_area_m2: float = 0.0
    floater_gap_m: float = 0.1  # m, a floater's lowest vertex lies more than this above the ground ...
    floater_noise_k: float = 3.0  # ... and more than this x the ground noise
    floater_join_m: float = 0.05  # m, collision pieces this close count as one piece for the floater rule
    # lump tops (`floaters.lump_tops`): a piece of the collision mesh that the trim cut and
    # whose highest point lies less than lump_noise_k x the ground noise above the step is
    # dropped with the faces below the step. The trim judges faces one by one, so a noise lump
    # on the pavement (the splats' textureless-ground floaters, 0.2-0.35 m up on the GoPro clip)
    # that peaks just above the step left 1-4 face slivers at the step height (0.31-0.33 m,
    # step 0.308) 0.24-0.30 m beside the walk, inside the robot radius (docs/studies/physical_layer.md).
    # Scaled by the noise like the step: on clean ground (noise ~0) a 0.2 m box the trim cut
    # stays an obstacle. 0 disables
    lump_noise_k: float = 2.0
    # carved pieces (`floaters.carved_pieces`), after the trim: a piece smaller than
    # cut_max_area_m2 with >= cut_min_points of the depth pixels the meshing's carving removed
    # (`carved_points`, at the meshing render scale; by default those inside the walker's swept
    # body) within cut_near_m is dropped: the body carving removes the part of a splat phantom
    # that stood in the walker's way and leaves the rest 0.22-0.3 m beside the walk, inside
    # the robot's radius. On 320 px splats of the GoPro clip: two pavement phantoms of
    # 0.1-0.5 m^2 with 800-1500 carved points each (path walkable 80.7 -> 99.6 %); the demo
    # street and the 160 px builds lose nothing to it. 0 disables
    cut_max_area_m2: float = 0.5
    cut_near_m: float = 0.15  # m, carved points this close to a piece count for it
    cut_min_points: int = 10  # carved points a piece needs near it to be dropped
    # pieces left with less surface than this after the trim are dropped (`floaters.small_pieces`):
    # meshing removes fragments (under 40 faces, ~0.1 m^2 at 0.1 m voxels) before the trim, and
    # the trim makes new ones out of noise lumps (demo street, 320 px splats: a 13-face, 0.05 m^2
    # piece 0.05-0.17 m up, 0.11 m from the walk, blocked 3.9 % of the path). 0 disables
    min_piece_area_m2: float = 0.1


def _disc(radius_cells: float) -> np.ndarray:
    r = int(np.ceil(radius_cells))
    y, x = np.mgrid[-r:r + 1, -r:r + 1]
    return x * x + y * y <= radius_cells * radius_cells + 1e-9


def _grid_frame(xy: np.ndarray, conf: WalkableConfig) -> tuple[np.ndarray, tuple[int, int]]:
    """Origin (snapped to the resolution) and (H, W) covering xy [N, 2] plus the margin."""
    res = conf.resolution_m
    lo = np.floor((xy.min(axis=0) - conf.margin_m) / res) * res
    hi = np.ceil((xy.max(axis=0) + conf.margin_m) / res) * res
    W, H = np.maximum(np.round((hi - lo) / res).astype(int), 1)
    return lo, (int(H), int(W))


def _rasterise(xy: np.ndarray, origin: np.ndarray, shape: tuple[int, int], res: float,
               min_hits: int = 1) -> np.ndarray:
    """Cells [H, W] bool holding at least min_hits of the points xy [N, 2]."""
    counts = np.zeros(shape, np.int64)
    if len(xy):
        c = np.floor((xy[:, 0] - origin[0]) / res).astype(np.int64)
        r = np.floor((xy[:, 1] - origin[1]) / res).astype(np.int64)
        ok = (r >= 0) & (r < shape[0]) & (c >= 0) & (c < shape[1])
        np.add.at(counts, (r[ok], c[ok]), 1)
    return counts >= min_hits


def ground_evidence(ground_points: np.ndarray, path_xy: np.ndarray, origin: np.ndarray,
                    shape: tuple[int, int], conf: WalkableConfig) -> np.ndarray:
    """Seen-ground cells [H, W] bool (points + path corridor, small gaps closed)."""
    res = conf.resolution_m
    seen = _rasterise(ground_points[:, :2], origin, shape, res, conf.min_ground_hits)
    if conf.path_radius_m > 0:
        on_path = _rasterise(path_xy, origin, shape, res)
        seen |= ndimage.binary_dilation(on_path, _disc(conf.path_radius_m / res))
    if conf.close_radius_m > 0:
        k = _disc(conf.close_radius_m / res)
        pad = k.shape[0]
        seen = ndimage.binary_closing(np.pad(seen, pad), k)[pad:-pad, pad:-pad]
    if conf.fill_holes:
        seen = ndimage.binary_fill_holes(seen)
    return seen


def _cells(xy: np.ndarray, origin: np.ndarray, shape: tuple[int, int], res: float
           ) -> tuple[np.ndarray, np.ndarray]:
    """(row, col) of points xy [N, 2], clipped into the grid."""
    c = np.clip(np.floor((xy[:, 0] - origin[0]) / res).astype(np.int64), 0, shape[1] - 1)
    r = np.clip(np.floor((xy[:, 1] - origin[1]) / res).astype(np.int64), 0, shape[0] - 1)
    return r, c


def _cell_median_z(ground_points: np.ndarray, origin: np.ndarray, shape: tuple[int, int],
                   res: float) -> tuple[np.ndarray, np.ndarray]:
    """(median ground z per cell [H, W] (0 where unseen), seen [H, W] bool)."""
    r, c = _cells(ground_points[:, :2], origin, shape, res)
    flat = r * shape[1] + c
    z = np.zeros(shape[0] * shape[1])
    cells = np.unique(flat)
    z[cells] = ndimage.median(ground_points[:, 2], labels=flat, index=cells)
    seen = np.zeros(shape[0] * shape[1], bool)
    seen[cells] = True
    return z.reshape(shape), seen.reshape(shape)


def _fill_nearest(z: np.ndarray, seen: np.ndarray) -> np.ndarray:
    _, (nr, nc) = ndimage.distance_transform_edt(~seen, return_indices=True)
    return z[nr, nc]


def walked_cells(path_xy: np.ndarray, origin: np.ndarray, shape: tuple[int, int],
                 conf: WalkableConfig) -> np.ndarray:
    """Cells [H, W] bool within walked_radius_m of the camera path polyline [T, 2]."""
    if conf.walked_radius_m <= 0:
        return np.zeros(shape, bool)
    dense = walked_path(np.column_stack([path_xy, np.zeros(len(path_xy))]), conf.resolution_m / 2)
    on = _rasterise(dense[:, :2], origin, shape, conf.resolution_m)
    return ndimage.binary_dilation(on, _disc(conf.walked_radius_m / conf.resolution_m))


def _heights(ground_points: np.ndarray, origin: np.ndarray, shape: tuple[int, int],
             conf: WalkableConfig, anchor: Optional[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per-cell median ground z and seen mask [H, W], with the anchor cells [H, W] set to
    the median height of the ground points inside them (ground_z_m without any)."""
    z, seen = _cell_median_z(ground_points, origin, shape, conf.resolution_m)
    if anchor is not None and anchor.any():
        r, c = _cells(ground_points[:, :2], origin, shape, conf.resolution_m)
        inside = anchor[r, c]
        z0 = float(np.median(ground_points[inside, 2])) if inside.any() else conf.ground_z_m
        z, seen = np.where(anchor, z0, z), seen | anchor
    return z, seen


def ground_height(ground_points: np.ndarray, origin: np.ndarray, shape: tuple[int, int],
                  conf: WalkableConfig, anchor: Optional[np.ndarray] = None) -> np.ndarray:
    """Local ground z [H, W]: median z of the ground points per cell, median-filtered over
    step_smooth_m, nearest seen cell elsewhere (ground_z_m without ground points)."""
    if len(ground_points) == 0:
        return np.full(shape, conf.ground_z_m)
    z, seen = _heights(ground_points, origin, shape, conf, anchor)
    return _smooth_height(_fill_nearest(z, seen), conf)


def _smooth_height(z: np.ndarray, conf: WalkableConfig) -> np.ndarray:
    """Median filter of a filled height map over step_smooth_m (keeps step edges, drops the
    per-cell noise of reconstructed ground: +-0.1 m on the splat demo)."""
    k = 2 * int(round(conf.step_smooth_m / (2 * conf.resolution_m))) + 1
    return ndimage.median_filter(z, size=k, mode="nearest") if k > 1 else z


def step_cells(ground_points: np.ndarray, origin: np.ndarray, shape: tuple[int, int],
               conf: WalkableConfig, anchor: Optional[np.ndarray] = None) -> np.ndarray:
    """Seen cells [H, W] bool whose (smoothed) ground height range within step_window_m
    exceeds max_step_m (steps and drop-offs that ground-band obstacles miss)."""
    if conf.max_step_m <= 0 or len(ground_points) == 0:
        return np.zeros(shape, bool)
    z, seen = _heights(ground_points, origin, shape, conf, anchor)
    z = _smooth_height(_fill_nearest(z, seen), conf)
    k = 2 * int(np.ceil(conf.step_window_m / conf.resolution_m)) + 1
    zmax = ndimage.maximum_filter(np.where(seen, z, -np.inf), size=k)
    zmin = ndimage.minimum_filter(np.where(seen, z, np.inf), size=k)
    step = max(conf.max_step_m, conf.noise_k * ground_noise(ground_points, origin, shape, conf))
    out = seen & (zmax - zmin > step)
    return out & ~anchor if anchor is not None else out


def beyond_kerb(ground_points: np.ndarray, path: np.ndarray, origin: np.ndarray,
                shape: tuple[int, int], conf: WalkableConfig, walked: np.ndarray) -> np.ndarray:
    """Cells [H, W] bool beyond a kerb drop beside the walk (`kerbs.kerb_cells` on the raw
    per-cell ground heights), never the walked cells [H, W]."""
    if conf.kerb is None or len(ground_points) == 0:
        return np.zeros(shape, bool)
    z, seen = _cell_median_z(ground_points, origin, shape, conf.resolution_m)
    out = kerb_cells(z, seen, origin, conf.resolution_m, path[:, :2], conf.walked_radius_m, conf.kerb)
    return out & ~walked


def ground_noise(ground_points: np.ndarray, origin: np.ndarray, shape: tuple[int, int],
                 conf: WalkableConfig) -> float:
    """Ground-height noise at the step scale: robust sigma (1.4826 MAD) of the smoothed height
    map around a 3x wider median (a kerb edge is too rare to move the median)."""
    if len(ground_points) == 0:
        return 0.0
    z, seen = _cell_median_z(ground_points, origin, shape, conf.resolution_m)
    zs = _smooth_height(_fill_nearest(z, seen), conf)
    k = 2 * int(round(3 * conf.step_smooth_m / (2 * conf.resolution_m))) + 1
    resid = (zs - ndimage.median_filter(zs, size=k, mode="nearest"))[seen]
    return float(1.4826 * np.median(np.abs(resid)))


def height_above_ground(points: np.ndarray, ground_z: np.ndarray, origin: np.ndarray,
                        res: float) -> np.ndarray:
    """Height [P] of points [P, 3] above the local ground z [H, W] of their cell (clipped)."""
    r, c = _cells(points[:, :2], origin, ground_z.shape, res)
    return points[:, 2] - ground_z[r, c]


def trim_below_step(vertices: np.ndarray, faces: np.ndarray, ground_z: np.ndarray,
                    origin: np.ndarray, res: float, step_m: float, base_m: float = 0.0,
                    lump_top_m: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(vertices [V', 3], faces [F', 3]) without the faces whose vertices all lie lower than
    step_m above the local ground z [H, W] (ground noise, climbable kerbs), except those within
    base_m of a cell holding geometry above the step (the base of a real obstacle, which blocks
    the map there anyway); with lump_top_m > 0, also without the pieces the trim cut whose top
    lies less than lump_top_m above the step (`floaters.lump_tops`)."""
    if len(faces) == 0:
        return vertices, faces
    vh = height_above_ground(vertices, ground_z, origin, res)  # [V]
    keep = vh[faces].max(axis=1) >= step_m  # [F]
    if base_m > 0 and keep.any() and not keep.all():
        pts = points_by_spacing(vertices, faces[keep], res / 3.0)  # [P, 3]
        above = pts[height_above_ground(pts, ground_z, origin, res) >= step_m]
        tall = ndimage.binary_dilation(_rasterise(above[:, :2], origin, ground_z.shape, res),
                                       _disc(base_m / res))
        r, c = _cells(vertices[faces[~keep]].mean(axis=1)[:, :2], origin, ground_z.shape, res)
        keep[~keep] = tall[r, c]
    if lump_top_m > 0:
        keep &= ~lump_tops(vertices, faces, keep, vh, step_m + lump_top_m)
    return _keep_faces(vertices, faces, keep)


def drop_trim_leftovers(vertices: np.ndarray, faces: np.ndarray, carved_points: Optional[np.ndarray],
                        conf: WalkableConfig) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) without the small pieces (`min_piece_area_m2`) and, given carved_points,
    the pieces the carving cut (`cut_*`) of a trimmed collision mesh."""
    if len(faces) == 0:
        return vertices, faces
    lab = face_components(vertices, faces)  # [F], shared by both rules
    drop = small_pieces(vertices, faces, conf.min_piece_area_m2, lab)
    if carved_points is not None:
        drop |= carved_pieces(vertices, faces, carved_points, conf.cut_max_area_m2,
                              conf.cut_near_m, conf.cut_min_points, lab)
    return _keep_faces(vertices, faces, ~drop) if drop.any() else (vertices, faces)


def _keep_faces(vertices: np.ndarray, faces: np.ndarray, keep: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """(vertices [V', 3], faces [F', 3]) of the faces where keep [F] holds, unused vertices dropped."""
    used, inv = np.unique(faces[keep], return_inverse=True)
    return vertices[used], inv.reshape(-1, 3)


def obstacle_points(collision_mesh: Optional[MeshLike], ground_z: np.ndarray,
                    origin: np.ndarray, conf: WalkableConfig, min_z: float,
                    seen: Optional[np.ndarray] = None) -> np.ndarray:
    """xy [P, 2] of collision-surface samples (resolution / 3 apart) that can touch the robot:
    between min_z and obstacle_max_z_m above the local ground z [H, W], or inside the robot's
    box band [body_bottom_m, body_top_m] above z = 0 (the envs' ground plane), whichever
    holds (the band only with trim_collision: without it this is the old, height-only map).
    With seen [H, W] (observed ground) and conf.overhead_clear_m, samples higher than that
    above the ground over a seen cell are left out (overhead: the robot drives under them)."""
    if collision_mesh is None:
        return np.zeros((0, 2))
    v, f = mesh_arrays(collision_mesh)
    if len(f) == 0:
        return np.zeros((0, 2))
    pts = points_by_spacing(v, f, conf.resolution_m / 3.0)  # [P, 3]
    h = height_above_ground(pts, ground_z, origin, conf.resolution_m)
    in_body = (pts[:, 2] >= conf.body_bottom_m) & (pts[:, 2] <= conf.body_top_m) & conf.trim_collision
    block = ((h >= min_z) & (h <= conf.obstacle_max_z_m)) | in_body  # [P]
    if seen is not None and conf.overhead_clear_m is not None:
        r, c = _cells(pts[:, :2], origin, seen.shape, conf.resolution_m)
        block &= in_body | ~((h > conf.overhead_clear_m) & seen[r, c])
    return pts[block, :2]


def obstacle_cells(collision_mesh: Optional[MeshLike], ground_z: np.ndarray,
                   origin: np.ndarray, conf: WalkableConfig, min_z: float) -> np.ndarray:
    """Cells [H, W] bool holding an `obstacle_points` sample."""
    pts = obstacle_points(collision_mesh, ground_z, origin, conf, min_z)
    return _rasterise(pts, origin, ground_z.shape, conf.resolution_m)


def near_points(points: np.ndarray, origin: np.ndarray, shape: tuple[int, int], res: float,
                radius_m: float) -> np.ndarray:
    """Cells [H, W] bool whose centre lies within radius_m of a point of xy [P, 2] (exact
    distances: a robot centred on any other cell clears every point by more than radius_m)."""
    out = np.zeros(shape, bool)
    if len(points) == 0:
        return out
    pts = np.unique(np.round(points / (res / 10.0)), axis=0) * (res / 10.0)  # thin to res / 10
    rows, cols = np.mgrid[0:shape[0], 0:shape[1]]
    centres = np.stack([origin[0] + (cols.ravel() + 0.5) * res, origin[1] + (rows.ravel() + 0.5) * res], 1)
    d = cKDTree(pts).query(centres, distance_upper_bound=radius_m + 1e-9)[0]
    return np.isfinite(d).reshape(shape)


def inflate(occupied: np.ndarray, radius_m: float, res: float) -> np.ndarray:
    """Cells [H, W] bool within radius_m (centre to centre) of an occupied cell."""
    if not occupied.any():
        return occupied.copy()
    dist = ndimage.distance_transform_edt(~occupied) * res
    return dist <= radius_m + 1e-9


def path_component(free: np.ndarray, path_rc: np.ndarray, snap_cells: float) -> np.ndarray:
    """Keep the 4-connected components of `free` [H, W] reached by the path cells [T, 2]."""
    labels, n = ndimage.label(free)
    if n == 0:
        raise WalkableError("no_walkable_ground", "no walkable cell is left after removing "
                            "inflated obstacles")
    H, W = free.shape
    r = np.clip(path_rc[:, 0], 0, H - 1)
    c = np.clip(path_rc[:, 1], 0, W - 1)
    dist, (nr, nc) = ndimage.distance_transform_edt(~free, return_indices=True)
    near = dist[r, c] <= snap_cells
    if not near.any():
        raise WalkableError("path_off_ground", f"no camera position is within {snap_cells} "
                            "cells of walkable ground")
    keep = np.unique(labels[nr[r[near], c[near]], nc[r[near], c[near]]])
    return np.isin(labels, keep[keep > 0])


@dataclass
class PhysicalLayer:
    """What the envs get: the walkable map and the collision mesh that agrees with it."""

    walkable: WalkableGrid
    vertices: np.ndarray  # [V, 3] collision mesh, sub-step faces dropped
    faces: np.ndarray  # [F, 3]
    step_m: float  # the step height used (obstacle_min_z_m raised to the ground noise)
    dropped_faces: int
    evidence: Optional[MapEvidence] = None


def map_factor(conf: WalkableConfig) -> int:
    """Map cells per ground-model cell along each axis (resolution_m / map_resolution_m)."""
    k = conf.resolution_m / conf.map_resolution_m if conf.map_resolution_m > 0 else 1.0
    if k < 1 - 1e-6 or abs(k - round(k)) > 1e-6:
        raise ValueError(f"map_resolution_m {conf.map_resolution_m} must divide resolution_m "
                         f"{conf.resolution_m} by an integer")
    return int(round(k))


def upsample(mask: np.ndarray, k: int) -> np.ndarray:
    """Each cell of mask [H, W] as k x k cells: [H * k, W * k]."""
    return mask if k == 1 else np.repeat(np.repeat(mask, k, axis=0), k, axis=1)


def physical_layer(ground_points: np.ndarray, collision_mesh: Optional[MeshLike],
                   camera_path: np.ndarray, conf: WalkableConfig,
                   carved_points: Optional[np.ndarray] = None) -> PhysicalLayer:
    """Walkable map + trimmed collision mesh (module docstring). ground_points [N, 3],
    camera_path [T, 3], carved_points [M, 3] (meshing: depth removed as lying in proven-empty
    space; None = no carved-piece rule)."""
    gp = np.asarray(ground_points, np.float64).reshape(-1, 3)
    path = np.asarray(camera_path, np.float64).reshape(-1, 3)
    if len(path) == 0 or not np.all(np.isfinite(path)):
        raise WalkableError("bad_camera_path", f"camera path must be finite [T, 3], T >= 1; "
                            f"got {len(path)} positions")
    gp = gp[np.all(np.isfinite(gp), axis=1)]
    if len(gp):
        d = cKDTree(path[:, :2]).query(gp[:, :2])[0]
        gp = gp[d <= conf.max_dist_from_path_m]
    if len(gp) == 0 and conf.path_radius_m <= 0:
        raise WalkableError("no_ground_points", "no ground evidence near the camera path")
    res = conf.resolution_m
    origin, shape = _grid_frame(np.concatenate([gp[:, :2], path[:, :2]]), conf)
    walked = walked_cells(path[:, :2], origin, shape, conf)
    seen = ground_evidence(gp, path[:, :2], origin, shape, conf) | walked
    gz = ground_height(gp, origin, shape, conf, walked)
    noise = ground_noise(gp, origin, shape, conf)
    step = max(conf.obstacle_min_z_m, conf.noise_k * noise)
    v, f = mesh_arrays(collision_mesh) if collision_mesh is not None else \
        (np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    n_faces = len(f)
    if conf.floater_max_area_m2 > 0 and len(f):
        gap = max(conf.floater_gap_m, conf.floater_noise_k * noise)
        float_f = floater_faces(v, f, height_above_ground(v, gz, origin, res), gap,
                                conf.floater_max_area_m2,
                                conf.floater_join_m, conf.obstacle_max_z_m)
        v, f = _keep_faces(v, f, ~float_f)
    if conf.trim_collision:
        v, f = trim_below_step(v, f, gz, origin, res, step, conf.base_radius_m,
                               conf.lump_noise_k * noise)
        v, f = drop_trim_leftovers(v, f, carved_points, conf)
    min_z = conf.body_bottom_m if conf.trim_collision else step
    steps = step_cells(gp, origin, shape, conf, walked) | beyond_kerb(gp, path, origin, shape, conf, walked)
    pts = obstacle_points((v, f), gz, origin, conf, min_z, seen)  # [P, 2]
    if conf.fill_holes and conf.fill_to_obstacles:
        occ = steps | _rasterise(pts, origin, shape, res)
        seen |= ndimage.binary_fill_holes(seen | occ) & ~occ
    k = map_factor(conf)
    mres = res / k  # the map's cells: the ground model's split k x k
    seen, steps = upsample(seen, k), upsample(steps, k)
    if conf.exact_inflation:
        by_obstacle = near_points(pts, origin, seen.shape, mres, conf.robot_radius_m)
    else:
        by_obstacle = inflate(_rasterise(pts, origin, seen.shape, mres), conf.robot_radius_m, mres)
    by_kerb = inflate(steps, conf.robot_radius_m, mres)
    free = seen & ~by_obstacle & ~by_kerb
    path_rc = np.stack([np.floor((path[:, 1] - origin[1]) / mres),
                        np.floor((path[:, 0] - origin[0]) / mres)], axis=1).astype(np.int64)
    grid = path_component(free, path_rc, conf.snap_m / mres)
    evidence = MapEvidence(seen, by_obstacle, by_kerb, pts)
    return PhysicalLayer(WalkableGrid(grid.astype(np.uint8), origin, mres), v, f, float(step),
                         n_faces - len(f), evidence)


def walkable_map(ground_points: np.ndarray, collision_mesh: Optional[MeshLike],
                 camera_path: np.ndarray, conf: WalkableConfig) -> WalkableGrid:
    """The walkable map of `physical_layer` (see module docstring)."""
    return physical_layer(ground_points, collision_mesh, camera_path, conf).walkable


def load_points(path: Path, reason: str) -> np.ndarray:
    """Finite points [N, 3] from a .npy file (the meshing stage's ground / carved points), or
    WalkableError `reason` naming the file and what is wrong with it."""
    try:
        pts = np.load(path, allow_pickle=False)
    except Exception as e:  # missing, truncated, not an .npy file
        raise WalkableError(reason, f"{path}: unreadable ({type(e).__name__}: {e})") from None
    if pts.ndim != 2 or pts.shape[1] != 3 or not np.isfinite(pts).all():
        raise WalkableError(reason, f"{path}: expected finite [N, 3] points, got {pts.dtype} {pts.shape}")
    return pts


def work(conf: WalkableConfig, ground_points: np.ndarray, collision_mesh_path: Path,
         camera_path: np.ndarray, input_key: str = "", carved_points: Optional[np.ndarray] = None) -> StageWork:
    """The walkable map and physical collision mesh: keyed by the config and `input_key`, which
    identifies the inputs (and whatever else decides the folder's files)."""
    return StageWork(STAGE, STAGE_VERSION, conf, (input_key,), lambda out_dir: build(
        conf, ground_points, collision_mesh_path, camera_path, out_dir, carved_points))


def build(conf: WalkableConfig, ground_points: np.ndarray, collision_mesh_path: Path,
          camera_path: np.ndarray, out_dir: Path, carved_points: Optional[np.ndarray] = None) -> dict:
    """Write walkable.npz, the physical collision.ply and walkable.json into the empty
    `out_dir`; returns the summary."""
    import trimesh

    path = Path(collision_mesh_path)
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as e:  # trimesh raises many types for unreadable files
        raise WalkableError("bad_collision_mesh", f"{path}: {e}") from e
    layer = physical_layer(ground_points, mesh, camera_path, conf, carved_points)
    wm = layer.walkable
    wm.save(out_dir / OUTPUTS.grid)
    trimesh.Trimesh(layer.vertices, layer.faces, process=False).export(out_dir / OUTPUTS.collision)
    summary = dict(shape=list(wm.shape), origin=wm.origin.tolist(), resolution=wm.resolution,
                   walkable_area_m2=round(wm.area_m2(), 3), step_m=round(layer.step_m, 3),
                   collision_faces=int(len(layer.faces)), dropped_faces=layer.dropped_faces,
                   path_miss={k: round(x, 4) for k, x in path_miss_causes(
                       wm, layer.evidence, camera_path, conf.robot_radius_m).items()})
    (out_dir / OUTPUTS.summary).write_text(json.dumps(
        {"summary": summary, "config": to_jsonable(conf)}, indent=2))
    return summary
