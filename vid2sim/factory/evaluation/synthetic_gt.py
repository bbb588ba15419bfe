"""Score a reconstructed scene of a synthetic street against its ground truth.

Reads the rendered clip folder (GT poses, `ground_truth.json` with the street config) and the
scene's outputs (estimated PosedClip, collision mesh, walkable map). The estimate lives in its
own metric frame; a Sim(3) fitted on the camera centres (matched by timestamp) maps it onto the
GT frame before the mesh and the map are compared.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from vid2sim.factory.evaluation.poses import ate
from vid2sim.factory.evaluation.geometry_metrics import MeshLike, erode_walkable, grid_iou, mesh_arrays
from vid2sim.factory.evaluation.walkable_ceiling import ceiling, iou_breakdown, path_clearance
from vid2sim.factory.geometry.surface_sampling import sample_surface
from vid2sim.factory.geometry.meshing import backproject
from vid2sim.factory.geometry.raycast import RaycastRenderer
from vid2sim.factory.geometry.walked_path import BODY_RADIUS_M
from vid2sim.factory.sfm.posed import PosedClip
from vid2sim.factory.synthetic.config import StreetConfig
from vid2sim.factory.synthetic.geometry import MATERIAL_NAMES
from vid2sim.factory.synthetic.street import StreetScene, generate_street
from vid2sim.formats.walkable import WalkableGrid


def street_config(synthetic_dir: Path) -> StreetConfig:
    """The StreetConfig a rendered clip was made with (from its ground_truth.json)."""
    cfg = json.loads((Path(synthetic_dir) / "ground_truth.json").read_text())["config"]
    return StreetConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in cfg.items()})


def crop_x(wm: WalkableGrid, x0: float, x1: float) -> WalkableGrid:
    """The columns of a walkable map between world x0 and x1."""
    c = wm.world_to_cell(np.array([x0, x1]), np.zeros(2))[1]
    c0 = max(int(c[0]), 0)
    return WalkableGrid(wm.grid[:, c0:int(c[1])], wm.origin + np.array([c0 * wm.resolution, 0.0]),
                       wm.resolution)


def mesh_scene(vertices: np.ndarray, triangles: np.ndarray):
    """An open3d RaycastingScene holding one triangle mesh (distance / closest-point queries)."""
    import open3d as o3d

    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.core.Tensor(np.asarray(vertices, np.float32)),
                     o3d.core.Tensor(np.asarray(triangles, np.uint32)))
    return rc


def distance_to_mesh(points: np.ndarray, vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Exact distance (m) from points [P, 3] to a triangle mesh."""
    import open3d as o3d

    query = o3d.core.Tensor(np.asarray(points, np.float32))
    return mesh_scene(vertices, triangles).compute_distance(query).numpy()


def scene_errors(estimate: PosedClip, synthetic_dir: Path, collision: MeshLike, walkable: WalkableGrid,
                 robot_radius_m: float = BODY_RADIUS_M, unseen_m: float = 4.0, samples: int = 200_000,
                 evidence=None) -> dict:
    """Pose ATE, collision-mesh accuracy (reconstruction -> GT obstacles, m), ground left in the
    collision mesh, and walkable IoU over the walked x range (the first `unseen_m` metres, which a
    camera 1.5 m up never sees, excluded) against the robot-centre GT map; plus the ceiling of
    the corridor figures on the GT map, the walked path's clearance to our collision surface and
    the IoU's missed / extra area by side of the path, and with the map's `evidence`
    (geometry.map_evidence.MapEvidence) the missed area by cause (`walkable_ceiling`)."""
    gt_clip = PosedClip.load(synthetic_dir)
    by_t = {round(f.timestamp, 3): f.cam_to_world[:3, 3] for f in gt_clip.frames}
    frames = [f for f in estimate.frames if round(f.timestamp, 3) in by_t]
    src = np.array([f.cam_to_world[:3, 3] for f in frames])  # [T, 3] estimate frame
    dst = np.array([by_t[round(f.timestamp, 3)] for f in frames])  # [T, 3] GT frame
    pose = ate(src, dst, with_scale=True)
    s, R, t = pose["scale"], np.asarray(pose["rotation"]), np.asarray(pose["translation"])
    scene = generate_street(street_config(synthetic_dir))
    rec = s * sample_surface(*mesh_arrays(collision), samples) @ R.T + t  # [S, 3] in GT frame
    dist = distance_to_mesh(rec, *scene.without_ground())  # [S] to the GT obstacles (no ground)
    shifted = WalkableGrid(walkable.grid, walkable.origin + t[:2], walkable.resolution)  # R ~ I, s ~ 1
    g, o, r = scene.walkable_grid()  # footprints only: erode_walkable adds the robot radius
    gt_map = erode_walkable(WalkableGrid(g, o, r), robot_radius_m)
    path = s * src @ R.T + t
    x0, x1 = path[:, 0].min() + unseen_m, path[:, 0].max()
    mesh_gt = collision_mesh_gt(collision, s, R, t)
    near = near_path_figures(rec, dist, path, gt_clip, scene, mesh_gt)
    gt_path = np.array([f.cam_to_world[:3, 3] for f in gt_clip.frames])  # [T, 3]
    ours_clear = path_clearance(mesh_gt, path)
    diag = {**ceiling(gt_map, scene.without_ground(), gt_path, robot_radius_m),
            "path_clearance_min_m": float(ours_clear.min()),
            "path_within_robot_radius": float(np.mean(ours_clear < robot_radius_m)),
            **{f"iou_{k}": v for k, v in iou_breakdown(shifted, gt_map, path, x0, x1, evidence=evidence).items()}}
    return {"matched_frames": len(frames), "ate_m": pose["rmse"], "ate_pct_of_path": pose["rmse_pct_of_path"],
            "metric_scale_error_pct": 100 * abs(s - 1.0),
            "collision_accuracy_m": float(dist.mean()),
            "collision_accuracy_median_m": float(np.median(dist)),
            "ground_left_frac": float(np.mean((rec[:, 2] < 0.15) & (dist > 0.2))),
            "walkable_iou": grid_iou(crop_x(shifted, x0, x1), crop_x(gt_map, x0, x1)),
            "iou_x_range": [float(x0), float(x1)], "walkable_area_m2": walkable.area_m2(), **near, **diag}


def collision_mesh_gt(collision: MeshLike, s: float, R: np.ndarray, t: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(vertices [V, 3] in the GT frame, faces [F, 3]) of the reconstructed collision mesh."""
    v, f = mesh_arrays(collision)
    return s * v @ R.T + t, f


def visible_obstacle_surface(gt_clip: PosedClip, scene: StreetScene, every: int = 4,
                             scale: float = 0.25, max_depth_m: float = 8.0
                             ) -> tuple[np.ndarray, np.ndarray]:
    """GT obstacle surface seen by the GT cameras: points [P, 3] and the material id [P]
    (synthetic.geometry ids) of the obstacle face each lies on. Ray cast of the whole street at
    a reduced resolution, hits kept where they lie on the obstacles (within 1 cm), not the
    ground."""
    import open3d as o3d

    rend = RaycastRenderer((scene.vertices, scene.triangles))
    pts = []
    for f in gt_clip.frames[::every]:
        K = np.asarray(f.K, np.float64).copy()
        K[:2] *= scale
        w, h = int(round(f.width * scale)), int(round(f.height * scale))
        o = rend.render(K, f.cam_to_world, w, h)
        keep = (o.depth > 0) & (o.depth < max_depth_m)
        pts.append(backproject(o.depth, K, f.cam_to_world)[keep])
    p = np.concatenate(pts).astype(np.float32)  # [P, 3]
    nearest = mesh_scene(*scene.without_ground()).compute_closest_points(o3d.core.Tensor(p))
    on_obstacle = np.linalg.norm(nearest["points"].numpy() - p, axis=1) < 0.01
    material = scene.face_material[scene.obstacle_faces()]  # [F_obstacle], without_ground's face order
    return p[on_obstacle].astype(np.float64), material[nearest["primitive_ids"].numpy()[on_obstacle]]


def visible_obstacle_points(gt_clip: PosedClip, scene: StreetScene, every: int = 4,
                            scale: float = 0.25, max_depth_m: float = 8.0) -> np.ndarray:
    """The points [P, 3] of `visible_obstacle_surface`."""
    return visible_obstacle_surface(gt_clip, scene, every, scale, max_depth_m)[0]


def near_path_figures(rec: np.ndarray, dist: np.ndarray, path: np.ndarray, gt_clip: PosedClip,
                      scene: StreetScene, mesh_gt: tuple, radius_m: float = 5.0,
                      tol_m: float = 0.1) -> dict:
    """Collision accuracy (median) and completeness (visible GT obstacle surface within tol_m
    of the mesh) for geometry within radius_m (horizontal) of the walked path (GT frame); the
    completeness also per obstacle material (`near_path_completeness_<material>`, the share
    of that material's visible surface within tol_m: where the missed surface lies)."""
    tree = cKDTree(path[:, :2])
    near_rec = tree.query(rec[:, :2])[0] <= radius_m
    gt, material = visible_obstacle_surface(gt_clip, scene)
    near_gt = tree.query(gt[:, :2])[0] <= radius_m
    gt, material = gt[near_gt], material[near_gt]
    d_gt = distance_to_mesh(gt, *mesh_gt) if len(gt) else np.zeros(0)
    out = {"near_path_accuracy_median_m": float(np.median(dist[near_rec])) if near_rec.any() else float("nan"),
           "near_path_completeness": float(np.mean(d_gt <= tol_m)) if len(d_gt) else float("nan")}
    for mat_id in np.unique(material):
        of_mat = material == mat_id
        out[f"near_path_completeness_{MATERIAL_NAMES[int(mat_id)]}"] = float(np.mean(d_gt[of_mat] <= tol_m))
    return out
