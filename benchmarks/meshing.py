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

from vid2sim.factory.evaluation.geometry_metrics import (
    chamfer_points, erode_walkable, grid_iou, sample_surface)
from vid2sim.factory.geometry.meshing import DepthView, MeshingConfig, backproject, build_meshes
from vid2sim.factory.geometry.raycast import RaycastRenderer, mesh_arrays
from vid2sim.factory.synthetic.config import preset
from vid2sim.factory.synthetic.render import intrinsics
from vid2sim.factory.synthetic.street import generate_street
from vid2sim.factory.synthetic.trajectory import walking_poses
from vid2sim.factory.geometry.walkable import WalkableConfig, walkable_map
from vid2sim.formats.walkable import WalkableGrid


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
    gt = erode_walkable(WalkableGrid(g, o, r), wconf.robot_radius_m)
    # compare on the stretch the walk covers and sees: the GT grid spans the whole modelled
    # street, and a forward camera 1.5 m up first sees the ground about 3-4 m ahead
    x0, x1 = T[:, 0, 3].min() + args.unseen_m, T[:, 0, 3].max()
    c0, c1 = (np.floor((np.array([x0, x1]) - gt.origin[0]) / gt.resolution)).astype(int)
    gt_crop = WalkableGrid(gt.grid[:, c0:c1], gt.origin + [c0 * gt.resolution, 0], gt.resolution)
    wc = wm.world_to_cell(np.array([x0, x1]), np.zeros(2))[1]
    wm_crop = WalkableGrid(wm.grid[:, max(wc[0], 0):wc[1]],
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


def run_from_splats(args) -> dict:
    from pathlib import Path

    from vid2sim.factory.sfm.posed import PosedClip
    from vid2sim.factory.geometry.splat_views import SplatViewConfig, render_views
    from vid2sim.factory.evaluation.synthetic_gt import scene_errors
    from vid2sim.splats.ply import read_ply

    work = Path(args.from_splats)
    clip_dir = sorted(p for p in (work / "clips").iterdir() if (p / "recon/splats.ply").exists())[0]
    clip = PosedClip.load(clip_dir / "metric")
    src = np.array([f.cam_to_world[:3, 3] for f in clip.frames])  # [T, 3] metric
    vconf, mconf, wconf = SplatViewConfig(scale=args.scale, every=args.every), MeshingConfig(), WalkableConfig()
    model = read_ply(clip_dir / "recon/splats.ply")
    t0 = time.perf_counter()
    res = build_meshes(render_views(model, clip, vconf), mconf)
    t_mesh = time.perf_counter() - t0
    wm = walkable_map(res.ground_points, res.collision, src, wconf)
    err = scene_errors(clip, work / "synthetic", res.collision, wm, wconf.robot_radius_m, args.unseen_m)
    return dict(source=str(clip_dir), views=res.summary["n_views"], scale=vconf.scale, every=vconf.every,
                mesh_s=round(t_mesh, 2), collision_faces=res.summary["collision_faces"],
                **{k: round(v, 4) if isinstance(v, float) else v for k, v in err.items()})


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
