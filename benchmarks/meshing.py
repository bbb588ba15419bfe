"""Meshing + walkable-map benchmark on the synthetic street with ground-truth depth.

Renders GT depth / normals / colour along the synthetic walk (ray casting the GT mesh), fuses
them (TSDF, ground removal, cleanup), builds the walkable map and prints: time per view, face
counts, Chamfer accuracy (collision mesh -> GT mesh without ground), completeness (visible GT
non-ground points -> collision mesh), walkable IoU vs the GT grid (obstacles padded and edges
eroded by the robot radius, i.e. valid robot-centre positions). `--noise` perturbs depth
(relative sigma) and normals (degrees) to mimic splat renders.

  .venv/bin/python benchmarks/meshing.py [--preset demo] [--every 4] [--scale 0.5] [--noise 0.01]

`--from-splats WORKDIR` instead evaluates a pipeline run (any work folder with a clip's
metric/ and recon/splats.ply; a `vid2sim demo` folder also has the GT under WORKDIR/synthetic/):
renders the splats once (SplatViewConfig defaults), meshes, builds the walkable map and reports
the ground-truth-free corridor check (walked path on walkable cells, components, collision area
in the body corridor) and, with GT, collision accuracy / completeness near the path, ground left
and walkable IoU; the metric frame is aligned to the GT frame by a similarity fit of the camera
centres (matched by timestamp), the walkable grid by its xy translation. `--ablation` meshes the
same renders with every variant of VARIANTS and prints a markdown table.

Variants go by name: `--variant NAME`, `--only NAME,NAME,...` (e.g. `--only map_0.05m,no_lump_rule,default`);
`--list-variants` prints them with what each changes (docs/benchmarks/meshing-variants.md).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import NamedTuple

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import Run, add_run_args  # noqa: E402  (benchmarks/common.py)

from vid2sim.factory.evaluation.corridor import corridor_check  # noqa: E402
from vid2sim.factory.geometry.map_evidence import path_miss_causes  # noqa: E402
from vid2sim.factory.geometry.carving import CarveConfig  # noqa: E402
from vid2sim.factory.geometry.kerbs import KerbConfig  # noqa: E402
from vid2sim.factory.evaluation.geometry_metrics import chamfer_points, erode_walkable, grid_iou  # noqa: E402
from vid2sim.factory.geometry.meshing import DepthView, MeshingConfig, backproject, build_meshes
from vid2sim.factory.geometry.raycast import RaycastRenderer, mesh_arrays
from vid2sim.factory.geometry.surface_sampling import sample_surface
from vid2sim.factory.synthetic.config import preset
from vid2sim.factory.synthetic.geometry import GROUND_MATERIALS, MATERIAL_NAMES
from vid2sim.factory.synthetic.render import intrinsics
from vid2sim.factory.synthetic.street import generate_street
from vid2sim.factory.synthetic.trajectory import walking_poses
from vid2sim.factory.geometry.walkable import WalkableConfig, physical_layer
from vid2sim.formats.walkable import WalkableGrid


def noisy(depth, normal, rel, deg, rng):
    if rel <= 0:
        return depth, normal
    d = depth * (1 + rel * rng.standard_normal(depth.shape)).astype(np.float32)
    n = normal + np.deg2rad(deg) * rng.standard_normal(normal.shape).astype(np.float32)
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-9)
    return np.where(depth > 0, d, 0).astype(np.float32), np.where(depth[..., None] > 0, n, 0)


def run_gt(args) -> dict:
    """One variant on ground-truth depth rendered from the synthetic street's mesh."""
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
    mconf = replace(MeshingConfig(), **VARIANTS[args.variant].meshing)
    wconf = replace(WalkableConfig(), **VARIANTS[args.variant].walkable)
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
    t0 = time.perf_counter()
    layer = physical_layer(res.ground_points, res.collision, T[:, :3, 3], wconf, res.carved_points)
    wm, collision = layer.walkable, (layer.vertices, layer.faces)  # what the bundle ships
    t_walk = time.perf_counter() - t0
    rec = sample_surface(*mesh_arrays(collision), 200_000)
    gv = np.concatenate(gt_vis)
    gt_ng = sample_surface(*scene.without_ground(), 400_000, seed=1)
    acc = chamfer_points(rec, gt_ng).a_to_b
    comp = chamfer_points(rec, gv[rng.choice(len(gv), min(len(gv), 200_000), replace=False)]).b_to_a
    g, o, r = scene.walkable_grid()  # footprints only: erode_walkable adds the robot radius
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
                walkable_s=round(t_walk, 2), collision_faces=len(layer.faces), step_m=round(layer.step_m, 3),
                visual_faces=res.summary["visual_faces"],
                accuracy_m=round(acc, 4), completeness_visible_m=round(comp, 4),
                chamfer_m=round((acc + comp) / 2, 4),
                walkable_iou=round(grid_iou(wm_crop, gt_crop), 4),
                iou_x_range=[round(float(x0), 2), round(float(x1), 2)],
                walkable_area_m2=round(wm.area_m2(), 2), variant=args.variant,
                **corridor_check(wm, collision, T[:, :3, 3]).to_dict(), **miss_row(layer, T[:, :3, 3], wconf))


def miss_row(layer, path: np.ndarray, wconf: WalkableConfig) -> dict:
    """Why walked samples are off the map (geometry.map_evidence.path_miss_causes), prefixed miss_."""
    out = path_miss_causes(layer.walkable, layer.evidence, path, wconf.robot_radius_m)
    return {f"miss_{k}": round(v, 4) for k, v in out.items()}


class Variant(NamedTuple):
    """One meshing ablation row: its label (in words) and the config fields it changes."""
    label: str
    meshing: dict  # MeshingConfig changes
    walkable: dict  # WalkableConfig changes
    views: dict  # SplatViewConfig changes (--from-splats)


NO_CULL = dict(cov_cull_alpha=None)
# before the physical layer: the fused mesh shipped as is, obstacles inflated cell to cell
OLD = dict(trim_collision=False, exact_inflation=False, kerb=None, max_step_m=0.08, fill_to_obstacles=False,
           map_resolution_m=0.1)
LOCAL_STEPS = dict(kerb=None, max_step_m=0.08, fill_to_obstacles=False)  # the map before kerb profiles (752e2eb)
NO_EDGE = dict(edge_rel=0.0)  # rows measured before the depth-edge filter became the default
VARIANTS: dict[str, Variant] = {  # short stable name -> what it changes (docs/benchmarks/meshing-variants.md)
    "baseline": Variant("baseline (fuse every pixel, no ground growth)",
        dict(carve=None, **NO_EDGE), dict(fill_holes=False, walked_radius_m=0.0, **OLD), NO_CULL),
    "growth": Variant("+ ground growth", dict(carve=None, **NO_EDGE), dict(walked_radius_m=0.0, **OLD), NO_CULL),
    "growth_rays": Variant("+ growth + ray carving", dict(carve=CarveConfig(body=False, rays=True), **NO_EDGE), dict(walked_radius_m=0.0, **OLD), NO_CULL),
    "growth_body": Variant("+ growth + body carving", dict(carve=CarveConfig(), **NO_EDGE), dict(walked_radius_m=0.0, **OLD), NO_CULL),
    "growth_body_walked": Variant("+ growth + body carving + walked ground", dict(carve=CarveConfig(), **NO_EDGE), OLD, NO_CULL),
    "growth_body_walked_cull": Variant("+ growth + body carving + walked ground + cov. culling 1e-3", dict(carve=CarveConfig(), **NO_EDGE), OLD, {}),
    "default": Variant("+ collision trimmed below the step (physical layer, default)", dict(carve=CarveConfig()), {}, {}),
    "no_trim": Variant("default without trimming (exact inflation only)", dict(carve=CarveConfig(), **NO_EDGE), dict(trim_collision=False, **LOCAL_STEPS), {}),
    "bases_kept": Variant("default + obstacle bases kept (0.1 m)", dict(carve=CarveConfig(), **NO_EDGE), dict(base_radius_m=0.1), {}),
    "growth_body_walked_rays": Variant("+ growth + body + walked ground + ray carving", dict(carve=CarveConfig(rays=True), **NO_EDGE), OLD, NO_CULL),
    "growth_body_walked_2view": Variant("+ growth + body + walked ground + 2-view consistency", dict(carve=CarveConfig(min_hit_views=2), **NO_EDGE), OLD, NO_CULL),
    "opacity_0.2": Variant("default + opacity >= 0.2", dict(carve=CarveConfig(), **NO_EDGE), {}, dict(min_opacity=0.2)),
    "growth_body_walked_opacity_0.2": Variant("+ growth + body + walked ground + opacity >= 0.2", dict(carve=CarveConfig(), **NO_EDGE), OLD, dict(min_opacity=0.2, cov_cull_alpha=None)),
    # kerbs from profiles across the walk (default since 752e2eb) vs the local step test
    "local_steps": Variant("physical layer, local step test (no kerb profiles)", dict(carve=CarveConfig(), **NO_EDGE), LOCAL_STEPS, {}),
    "kerbs_local_steps": Variant("physical layer, kerb profiles + local step test", dict(carve=CarveConfig(), **NO_EDGE), dict(max_step_m=0.08), {}),
    "rays_no_edge_filter": Variant("kerb profiles (default) + ray carving", dict(carve=CarveConfig(rays=True), **NO_EDGE), {}, {}),
    "edge_0.2": Variant("default + depth-edge filter 0.2", dict(carve=CarveConfig(), edge_rel=0.2), {}, {}),
    "no_edge_filter": Variant("default without the depth-edge filter", dict(carve=CarveConfig(), edge_rel=0.0), {}, {}),
    "no_fill_to_obstacles": Variant("default without growth up to obstacles and kerbs", dict(carve=CarveConfig(), **NO_EDGE), dict(fill_to_obstacles=False), {}),
    # the clearance test on finer map cells (default, 75d15d2) vs the ground model's 0.1 m
    "map_0.1m": Variant("default with 0.1 m map cells", dict(carve=CarveConfig()), dict(map_resolution_m=0.1), {}),
    "rays": Variant("default + ray carving", dict(carve=CarveConfig(rays=True)), {}, {}),
    # unsupported small components of the collision mesh (floaters) dropped (off by default)
    "floaters_dropped": Variant("default + floaters dropped (< 0.4 m^2, lowest point > max(0.1, 3 sigma) above ground)",
        dict(carve=CarveConfig()), dict(floater_max_area_m2=0.4), {}),
    # the map's obstacle ceiling at the robot's height (box top 0.75 m) plus a margin,
    # instead of a person's 1.8 m (a canopy the robot drives under does not block it)
    "obstacles_1.0m": Variant("default, obstacles up to 1.0 m (robot top 0.75 + 0.25)", dict(carve=CarveConfig()), dict(obstacle_max_z_m=1.0), {}),
    "obstacles_1.2m": Variant("default, obstacles up to 1.2 m (robot top 0.75 + 0.45)", dict(carve=CarveConfig()), dict(obstacle_max_z_m=1.2), {}),
    # default since 2fc8cd1: above 1.2 m only over unseen ground; this row is the map without it
    "no_overhead_rule": Variant("default without the overhead rule (every surface up to 1.8 m blocks)",
        dict(carve=CarveConfig()), dict(overhead_clear_m=None), {}),
    # default since fef55cf: what the trim leaves of a lump peaking < 2 sigma above the step
    # goes with it; this row is the map without that rule
    "no_lump_rule": Variant("default without the lump-top rule",
        dict(carve=CarveConfig()), dict(lump_noise_k=0.0), {}),
    # default since 143fbfa: 0.025 m map cells; this row is the 0.05 m map before it
    "map_0.05m": Variant("default with 0.05 m map cells", dict(carve=CarveConfig()), dict(map_resolution_m=0.05), {}),
    # default since 5614713: kerb drops found across up to 2 m of bins without ground (a planter
    # hides the outer sidewalk); these rows are 1 m and the adjoining-bins rule before it
    "kerb_gap_1m": Variant("default, kerb drops across gaps up to 1 m", dict(carve=CarveConfig()), dict(kerb=KerbConfig(max_gap_m=1.0)), {}),
    "kerb_gap_0": Variant("default without kerb drops across gaps", dict(carve=CarveConfig()), dict(kerb=KerbConfig(max_gap_m=0.0)), {}),
    # meshing depth rendered without the screen-space covariance culling
    "no_cov_cull": Variant("default without covariance culling", dict(carve=CarveConfig()), {}, NO_CULL),
    # default since d77ba5f: TSDF truncation 3.5 voxels (0.35 m); these rows are the 4 voxels
    # before it and a narrower 3
    "trunc_4vox": Variant("default with 4-voxel TSDF truncation", dict(carve=CarveConfig(), trunc_voxels=4.0), {}, {}),
    "trunc_3vox": Variant("default with 3-voxel TSDF truncation", dict(carve=CarveConfig(), trunc_voxels=3.0), {}, {}),
    # default since 171ad22: after the trim, pieces under 0.1 m^2 and small pieces the carving cut
    # are dropped; these rows are the map without either rule, and without each
    "no_piece_rules": Variant("default without the post-trim piece rules",
        dict(carve=CarveConfig()), dict(cut_max_area_m2=0.0, min_piece_area_m2=0.0), {}),
    "no_cut_piece_rule": Variant("default without the carved-piece rule", dict(carve=CarveConfig()), dict(cut_max_area_m2=0.0), {}),
    "no_small_piece_rule": Variant("default without the small-piece rule", dict(carve=CarveConfig()), dict(min_piece_area_m2=0.0), {}),
    # the collision volume on open3d's tensor voxel-block grid (`block_tsdf`),
    # without and with the free-space fill-in of unobserved voxels
    "blocks": Variant("default, collision TSDF on voxel blocks",
        dict(carve=CarveConfig(), collision_tsdf="blocks", fill_free_views=0), {}, {}),
    "blocks_fill": Variant("default, collision TSDF on voxel blocks + free-space fill-in",
        dict(carve=CarveConfig(), collision_tsdf="blocks", fill_free_views=1), {}, {}),
    # default since 484c1ae: `blocks` / `blocks_fill` with the map clearing the walker's body
    # radius (0.25 m);
    # these rows are the legacy engine, the 0.3 m map, and both (the default before 484c1ae)
    "legacy": Variant("default on the legacy collision TSDF",
        dict(carve=CarveConfig(), collision_tsdf="legacy"), {}, {}),
    "clear_0.3m": Variant("default with the map cleared for 0.3 m",
        dict(carve=CarveConfig()), dict(robot_radius_m=0.3), {}),
    "legacy_clear_0.3m": Variant("default on the legacy TSDF, map cleared for 0.3 m",
        dict(carve=CarveConfig(), collision_tsdf="legacy"), dict(robot_radius_m=0.3), {}),
}
DEFAULT_VARIANT = "default"


def find_clip(work: Path) -> Path:
    """The first clip folder under a pipeline work folder holding recon/splats.ply."""
    found = sorted(p.parent.parent for p in work.glob("**/recon/splats.ply"))
    if not found:
        raise SystemExit(f"no */recon/splats.ply under {work}")
    return found[0]


def run_from_splats(args) -> list[dict]:
    from vid2sim.factory.sfm.posed import PosedClip
    from vid2sim.factory.geometry.splat_views import SplatViewConfig, render_views
    from vid2sim.factory.evaluation.synthetic_gt import scene_errors
    from vid2sim.splats.ply import read_ply

    work = Path(args.from_splats)
    clip_dir = find_clip(work)
    synth = work / "synthetic" if (work / "synthetic" / "ground_truth.json").is_file() else None
    clip = PosedClip.load(clip_dir / "metric")
    src = np.array([f.cam_to_world[:3, 3] for f in clip.frames])  # [T, 3] metric
    model = read_ply(clip_dir / "recon/splats.ply")
    rendered: dict[str, tuple[list, float]] = {}
    rows = []
    for name in variant_names(args):
        _, mchg, wchg, vchg = VARIANTS[name]
        vkey = json.dumps(vchg, sort_keys=True)
        if vkey not in rendered:  # render once per view config
            t0 = time.perf_counter()
            vconf = replace(SplatViewConfig(scale=args.scale, every=args.every), **vchg)
            rendered[vkey] = (list(render_views(model, clip, vconf)), time.perf_counter() - t0)
        views, t_render = rendered[vkey]
        mconf, wconf = replace(MeshingConfig(), **mchg), replace(WalkableConfig(), **wchg)
        t0 = time.perf_counter()
        res = build_meshes(views, mconf)
        t_mesh = time.perf_counter() - t0
        t0 = time.perf_counter()
        layer = physical_layer(res.ground_points, res.collision, src, wconf, res.carved_points)
        t_walk = time.perf_counter() - t0
        wm, collision = layer.walkable, (layer.vertices, layer.faces)  # what the bundle ships
        row = dict(variant=name, label=VARIANTS[name].label, views=res.summary["n_views"],
                   render_s=round(t_render, 2), mesh_s=round(t_mesh, 2), carve_s=res.summary.get("carve_seconds", 0.0),
                   walkable_s=round(t_walk, 2), step_m=round(layer.step_m, 3),
                   collision_faces=len(layer.faces),
                   walkable_area_m2=round(wm.area_m2(), 2), **corridor_check(wm, collision, src).to_dict(),
                   **miss_row(layer, src, wconf))
        if synth is not None:
            err = scene_errors(clip, synth, collision, wm, wconf.robot_radius_m, args.unseen_m,
                               evidence=layer.evidence)
            row.update({k: round(v, 4) if isinstance(v, float) else v for k, v in err.items()})
        rows.append(row)
        record_row(args.run, f"{work.name} splats: {name}", row)
        print(json.dumps(row), flush=True)
    return rows


def variant_names(args) -> list[str]:
    """The variants to run: --only NAME,NAME (by name), every one (--ablation), or --variant."""
    if args.only:
        names = [n.strip() for n in args.only.split(",") if n.strip()]
        unknown = [n for n in names if n not in VARIANTS]
        if unknown:
            raise SystemExit(f"unknown variant(s) {', '.join(unknown)}; known: {', '.join(VARIANTS)}")
        return names
    return list(VARIANTS) if args.ablation else [args.variant]


CONFIG_KEYS = ("variant", "label", "preset", "width", "height", "noise", "iou_x_range", "views")


def unit_of(key: str) -> str:
    for suffix, unit in (("_ms_per_view", "ms"), ("_m2", "m2"), ("_s", "s"), ("_m", "m"), ("_deg", "deg")):
        if key.endswith(suffix):
            return unit
    return ""


def record_row(run: Run, case: str, row: dict) -> None:
    """Every figure of one variant's result row as harness rows (settings into the config)."""
    conf = {k: row[k] for k in CONFIG_KEYS if k in row}
    conf["changes"] = changes(VARIANTS[row["variant"]])
    for k, val in row.items():
        if k not in CONFIG_KEYS:
            run.record(case, k, val, unit_of(k), conf)


def brief(v) -> str:
    """A config value as text; a dataclass shows only its fields that differ from the defaults."""
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        base = type(v)()
        diff = [f"{f.name}={getattr(v, f.name)!r}" for f in dataclasses.fields(v)
                if getattr(v, f.name) != getattr(base, f.name)]
        return f"{type(v).__name__}({', '.join(diff)})"
    return repr(v) if isinstance(v, str) else str(v)


def changes(v: Variant) -> dict:
    return {part: {k: brief(x) for k, x in d.items()}
            for part, d in (("meshing", v.meshing), ("walkable", v.walkable), ("views", v.views))}


def variants_markdown() -> str:
    """Markdown table of VARIANTS: name, label, the config fields each changes."""
    def show(d: dict) -> str:
        return ", ".join(f"{k}={brief(v)}" for k, v in d.items()) or "-"

    lines = ["| name | what it measures | MeshingConfig | WalkableConfig | SplatViewConfig |", "|---|---|---|---|---|"]
    for n, v in VARIANTS.items():
        cells = [f"`{n}`", v.label, show(v.meshing), show(v.walkable), show(v.views)]
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(lines)


TABLE_KEYS = [("walkable_fraction", "path walkable"), ("path_components", "components"),
              ("corridor_area_m2", "corridor area m2"), ("walkable_iou", "walkable IoU"),
              ("near_path_accuracy_median_m", "acc. median <5 m"),
              ("near_path_completeness", "compl. <5 m"),
              *((f"near_path_completeness_{name}", f"compl. {name}")
                for mat, name in MATERIAL_NAMES.items() if mat not in GROUND_MATERIALS),
              ("ground_left_frac", "ground left"),
              ("collision_accuracy_m", "acc. mean"), ("walkable_area_m2", "walkable m2"),
              ("gt_walkable_fraction", "GT map: path walkable"), ("gt_clearance_min_m", "GT path clearance m"),
              ("path_clearance_min_m", "our path clearance m"),
              ("path_within_robot_radius", "path within robot radius"),
              ("iou_missed_left_m2", "IoU missed left m2"), ("iou_missed_right_m2", "missed right m2"),
              ("iou_extra_left_m2", "extra left m2"), ("iou_extra_right_m2", "extra right m2"),
              ("iou_missed_obstacle_m2", "IoU missed by: obstacle clearance m2"),
              ("iou_missed_kerb_m2", "kerb m2"), ("iou_missed_unseen_m2", "unseen m2"),
              ("iou_missed_component_m2", "other component m2"),
              ("miss_obstacle_within_radius", "path missed: surface within radius"),
              ("miss_obstacle_cell", "cell discretisation"), ("miss_kerb", "kerb"),
              ("miss_unseen", "unseen"), ("miss_component", "other component"),
              ("step_m", "step m"), ("mesh_s", "meshing s"), ("carve_s", "of which carving s"),
              ("walkable_s", "physical layer s")]


def print_table(rows: list[dict]) -> None:
    """Markdown ablation table (one row per variant)."""
    keys = [(k, h) for k, h in TABLE_KEYS if k in rows[0]]
    print("| variant | " + " | ".join(h for _, h in keys) + " |")
    print("|---" * (len(keys) + 1) + "|")
    for r in rows:
        vals = [f"{r[k]:.3f}" if isinstance(r[k], float) else str(r[k]) for k, _ in keys]
        print(f"| {r['variant']} | " + " | ".join(vals) + " |")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--from-splats", default="", metavar="WORKDIR",
                    help="evaluate a pipeline work folder (splats + synthetic GT) instead")
    ap.add_argument("--preset", default="demo")
    ap.add_argument("--every", type=int, default=4)
    ap.add_argument("--scale", type=float, default=0.5)
    ap.add_argument("--noise", type=float, default=0.0)
    ap.add_argument("--noise-deg", type=float, default=5.0)
    ap.add_argument("--ablation", action="store_true", help="every variant in VARIANTS")
    ap.add_argument("--only", default="", metavar="NAME,NAME",
                    help="comma-separated variant names (--list-variants shows them)")
    ap.add_argument("--variant", default=DEFAULT_VARIANT, choices=list(VARIANTS), metavar="NAME")
    ap.add_argument("--list-variants", action="store_true", help="print the variants as a markdown table")
    ap.add_argument("--unseen-m", type=float, default=4.0, help="skip this much after the start")
    add_run_args(ap)
    args = ap.parse_args()
    if args.list_variants:
        print(variants_markdown())
        return
    names = variant_names(args)
    with Run("meshing", args) as run:
        args.run = run
        if args.from_splats:
            args.scale = 0.3 if args.scale == 0.5 else args.scale  # SplatViewConfig defaults
            args.every = 2 if args.every == 4 else args.every
            print_table(run_from_splats(args))
        else:
            for name in names:
                args.variant = name
                row = run_gt(args)
                noise = f", noise {args.noise:g}" if args.noise > 0 else ""
                record_row(run, f"GT depth {args.preset} every {args.every} x{args.scale:g}{noise}: {name}", row)
                print(json.dumps(row, indent=2))

if __name__ == "__main__":
    main()
