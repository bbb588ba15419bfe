"""Meshing + walkable-map benchmark on the synthetic street with ground-truth depth.

Renders GT depth / normals / colour along the synthetic walk (ray casting the GT mesh), fuses
them (TSDF, ground removal, cleanup), builds the walkable map and prints: time per view, face
counts, Chamfer accuracy (collision mesh -> GT mesh without ground), completeness (visible GT
non-ground points -> collision mesh), walkable IoU vs the GT grid (obstacles padded and edges
eroded by the robot radius, i.e. valid robot-centre positions). `--noise` perturbs depth
(relative sigma) and normals (degrees) to mimic splat renders.

  .venv/bin/python benchmarks/meshing.py [--preset demo] [--every 4] [--scale 0.5] [--noise 0.01]

`--from-splats WORKDIR` instead evaluates a pipeline run (`vid2sim demo` work folder: the clip
under WORKDIR/clips/*/ with metric/ and recon/splats.ply, the GT under WORKDIR/synthetic/):
renders the splats (SplatViewConfig defaults), meshes, builds the walkable map and reports
the same figures; the metric frame is aligned to the GT frame by a similarity fit of the
camera centres (matched by timestamp), the walkable grid by its xy translation.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import trimesh

from vid2sim.factory.geometry_metrics import (
    chamfer_points, erode_walkable, grid_iou, sample_surface)
from vid2sim.factory.meshing import DepthView, MeshingConfig, backproject, build_meshes
from vid2sim.factory.raycast import RaycastRenderer, mesh_arrays
from vid2sim.factory.synthetic.config import preset
from vid2sim.factory.synthetic.render import intrinsics
from vid2sim.factory.synthetic.street import generate_street
from vid2sim.factory.synthetic.trajectory import walking_poses
from vid2sim.factory.walkable import WalkableConfig, WalkableMap, walkable_map


def noisy(depth, normal, rel, deg, rng):
    if rel <= 0:
        return depth, normal
    d = depth * (1 + rel * rng.standard_normal(depth.shape)).astype(np.float32)
    n = normal + np.deg2rad(deg) * rng.standard_normal(normal.shape).astype(np.float32)
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-9)
    return np.where(depth > 0, d, 0).astype(np.float32), np.where(depth[..., None] > 0, n, 0)


def run(args) -> dict:
    conf = preset(args.preset)
    scene = generate_street(conf)
    mesh = trimesh.Trimesh(scene.vertices, scene.triangles, process=False,
                           face_colors=(np.clip(scene.face_color, 0, 1) * 255).astype(np.uint8))
    _, T = walking_poses(conf)
    T = T[:: args.every]
    K = intrinsics(conf).copy()
    K[:2] *= args.scale
    W, H = int(round(conf.width * args.scale)), int(round(conf.height * args.scale))
    rend = RaycastRenderer(mesh)
    rng = np.random.default_rng(0)
    mconf = MeshingConfig()
    views, gt_vis = [], []
    t0 = time.perf_counter()
    for c2w in T:
        o = rend.render(K, c2w, W, H)
        pts = backproject(o.depth, K, c2w)
        keep = (o.depth > 0) & (o.depth < mconf.depth_max_m) & (pts[..., 2] > 0.02)
        gt_vis.append(pts[keep][::7])
        d, n = noisy(o.depth, o.normal_cam, args.noise, args.noise_deg, rng)
        views.append(DepthView(d, K, c2w, n, o.rgb))
    t_render = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = build_meshes(views, mconf)
    t_mesh = time.perf_counter() - t0
    wconf = WalkableConfig()
    t0 = time.perf_counter()
    wm = walkable_map(res.ground_points, res.collision, T[:, :3, 3], wconf)
    t_walk = time.perf_counter() - t0
    rec = sample_surface(*mesh_arrays(res.collision), 200_000)
    gv = np.concatenate(gt_vis)
    gt_ng = sample_surface(*scene.without_ground(), 400_000, seed=1)
    acc = chamfer_points(rec, gt_ng).a_to_b
    comp = chamfer_points(rec, gv[rng.choice(len(gv), min(len(gv), 200_000), replace=False)]).b_to_a
    g, o, r = scene.walkable_grid(pad=wconf.robot_radius_m)
    gt = erode_walkable(WalkableMap(g, o, r), wconf.robot_radius_m)
    # compare on the stretch the walk covers and sees: the GT grid spans the whole modelled
    # street, and a forward camera 1.5 m up first sees the ground about 3-4 m ahead
    x0, x1 = T[:, 0, 3].min() + args.unseen_m, T[:, 0, 3].max()
    c0, c1 = (np.floor((np.array([x0, x1]) - gt.origin[0]) / gt.resolution)).astype(int)
    gt_crop = WalkableMap(gt.grid[:, c0:c1], gt.origin + [c0 * gt.resolution, 0], gt.resolution)
    wc = wm.world_to_cell(np.array([x0, x1]), np.zeros(2))[1]
    wm_crop = WalkableMap(wm.grid[:, max(wc[0], 0):wc[1]],
                          wm.origin + [max(wc[0], 0) * wm.resolution, 0], wm.resolution)
    return dict(preset=args.preset, views=len(T), width=W, height=H, noise=args.noise,
                render_s=round(t_render, 2), mesh_s=round(t_mesh, 2),
                fuse_ms_per_view=round(1000 * res.summary["fuse_seconds"] / len(T), 1),
                walkable_s=round(t_walk, 2), collision_faces=res.summary["collision_faces"],
                visual_faces=res.summary["visual_faces"],
                accuracy_m=round(acc, 4), completeness_visible_m=round(comp, 4),
                chamfer_m=round((acc + comp) / 2, 4),
                walkable_iou=round(grid_iou(wm_crop, gt_crop), 4), iou_x_range=[round(float(x0), 2), round(float(x1), 2)],
                walkable_area_m2=round(wm.area_m2(), 2))


def umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Similarity (s, R, t) with dst ~ s R src + t for point sets [N, 3]."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    S, D = src - mu_s, dst - mu_d
    U, sig, Vt = np.linalg.svd(D.T @ S / len(src))
    E = np.eye(3)
    E[2, 2] = np.sign(np.linalg.det(U @ Vt))
    R = U @ E @ Vt
    s = float((sig * np.diag(E)).sum() / (S ** 2).sum() * len(src))
    return s, R, mu_d - s * R @ mu_s


def run_from_splats(args) -> dict:
    from pathlib import Path

    from vid2sim.factory.posed import PosedClip
    from vid2sim.factory.splat_views import SplatViewConfig, render_views
    from vid2sim.factory.synthetic.config import StreetConfig
    from vid2sim.splats.ply import read_ply

    work = Path(args.from_splats)
    clip_dir = sorted(p for p in (work / "clips").iterdir() if (p / "recon/splats.ply").exists())[0]
    clip = PosedClip.load(clip_dir / "metric")
    gt_clip = PosedClip.load(work / "synthetic")
    gt_info = json.loads((work / "synthetic/ground_truth.json").read_text())
    cfg = {k: tuple(v) if isinstance(v, list) else v for k, v in gt_info["config"].items()}
    scene = generate_street(StreetConfig(**cfg))
    by_t = {round(f.timestamp, 3): f.cam_to_world[:3, 3] for f in gt_clip.frames}
    src = np.array([f.cam_to_world[:3, 3] for f in clip.frames])  # [T, 3] metric
    s, R, t = umeyama(src, np.array([by_t[round(f.timestamp, 3)] for f in clip.frames]))
    vconf, mconf, wconf = SplatViewConfig(scale=args.scale, every=args.every), MeshingConfig(), WalkableConfig()
    model = read_ply(clip_dir / "recon/splats.ply")
    t0 = time.perf_counter()
    res = build_meshes(render_views(model, clip, vconf), mconf)
    t_mesh = time.perf_counter() - t0
    wm = walkable_map(res.ground_points, res.collision, src, wconf)
    wm = WalkableMap(wm.grid, wm.origin + t[:2], wm.resolution)  # metric -> GT (R ~ I, s ~ 1)
    rec = s * sample_surface(*mesh_arrays(res.collision), 200_000) @ R.T + t
    gt_ng = sample_surface(*scene.without_ground(), 400_000, seed=1)
    acc = chamfer_points(rec, gt_ng).a_to_b
    path = s * src @ R.T + t
    near = (np.linalg.norm(gt_ng[:, None, :2] - path[None, ::5, :2], axis=-1).min(1) < 6.0) & \
        (gt_ng[:, 2] < 2.0)
    comp = chamfer_points(rec, gt_ng[near]).b_to_a  # GT non-ground within 6 m of the walk, below 2 m
    g, o, r = scene.walkable_grid(pad=wconf.robot_radius_m)
    gt = erode_walkable(WalkableMap(g, o, r), wconf.robot_radius_m)
    x0, x1 = path[:, 0].min() + args.unseen_m, path[:, 0].max()
    return dict(source=str(clip_dir), views=res.summary["n_views"], scale=vconf.scale,
                every=vconf.every, sim3_scale=round(s, 4), mesh_s=round(t_mesh, 2),
                collision_faces=res.summary["collision_faces"],
                accuracy_m=round(acc, 4), completeness_near_walk_m=round(comp, 4),
                # collision surface near z = 0 and > 0.2 m from any GT obstacle: ground left in
                ground_left_frac=round(float(np.mean((rec[:, 2] < 0.15) & (_dist(rec, gt_ng) > 0.2))), 4),
                walkable_iou=round(grid_iou(_crop(wm, x0, x1), _crop(gt, x0, x1)), 4),
                iou_x_range=[round(float(x0), 2), round(float(x1), 2)],
                walkable_area_m2=round(wm.area_m2(), 2))


def _dist(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    from scipy.spatial import cKDTree

    return cKDTree(b).query(a, workers=-1)[0]


def _crop(wm: WalkableMap, x0: float, x1: float) -> WalkableMap:
    c = wm.world_to_cell(np.array([x0, x1]), np.zeros(2))[1]
    c0 = max(int(c[0]), 0)
    return WalkableMap(wm.grid[:, c0:int(c[1])], wm.origin + [c0 * wm.resolution, 0], wm.resolution)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--from-splats", default="", metavar="WORKDIR",
                    help="evaluate a pipeline work folder (splats + synthetic GT) instead")
    ap.add_argument("--preset", default="demo")
    ap.add_argument("--every", type=int, default=4)
    ap.add_argument("--scale", type=float, default=0.5)
    ap.add_argument("--noise", type=float, default=0.0)
    ap.add_argument("--noise-deg", type=float, default=5.0)
    ap.add_argument("--unseen-m", type=float, default=4.0, help="skip this much after the start")
    args = ap.parse_args()
    if args.from_splats:
        args.scale = 0.3 if args.scale == 0.5 else args.scale  # SplatViewConfig defaults
        args.every = 2 if args.every == 4 else args.every
    print(json.dumps(run_from_splats(args) if args.from_splats else run(args), indent=2))


if __name__ == "__main__":
    main()
