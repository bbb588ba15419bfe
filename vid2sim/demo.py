"""`vid2sim demo`: the whole chain on data it makes itself (no downloads).

1. Generate a procedural street and render a hand-held walking video with ground truth.
2. Ingest the video with the `fast` preset on an embedded local Ray runtime
   (decode -> masks -> SfM -> metric frame -> splats -> mesh/walkable -> bundle -> commit).
3. Print the registry listing, the scene's metrics and errors against ground truth,
   and write a preview image.
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path
from typing import Optional

import numpy as np
from rich.console import Console
from rich.table import Table


def _ground_truth_errors(scene_dir: Path, synthetic_dir: Path, posed_dir: Path, street) -> dict:
    """Pose ATE vs GT, collision-mesh accuracy vs the GT mesh (no ground), walkable IoU."""
    import trimesh

    from vid2sim.factory.eval_poses import ate
    from vid2sim.factory.geometry_metrics import chamfer_distance, grid_iou
    from vid2sim.factory.posed import PosedClip
    from vid2sim.factory.synthetic.street import generate_street
    from vid2sim.factory.walkable import WalkableMap

    est, gt = PosedClip.load(posed_dir), PosedClip.load(synthetic_dir)
    gt_by_t = {round(f.timestamp, 2): f for f in gt.frames}
    pairs = [(e, gt_by_t[round(e.timestamp, 2)]) for e in est.frames if round(e.timestamp, 2) in gt_by_t]
    out: dict = {"matched_frames": len(pairs)}
    if len(pairs) >= 3:
        p_est = np.array([e.cam_to_world[:3, 3] for e, _ in pairs])  # [T, 3]
        p_gt = np.array([g.cam_to_world[:3, 3] for _, g in pairs])
        sim3 = ate(p_est, p_gt, with_scale=True)
        out.update(ate_m=sim3["rmse"], ate_pct_of_path=sim3["rmse_pct_of_path"],
                   metric_scale_error_pct=100 * abs(sim3["scale"] - 1.0))
    verts, tris = generate_street(street).without_ground()
    ch = chamfer_distance(trimesh.load(scene_dir / "collision.ply", force="mesh"),
                          trimesh.Trimesh(verts, tris, process=False), 20000)
    out["collision_accuracy_m"] = ch.a_to_b  # reconstruction -> GT (GT extends beyond the view)
    gt_walk = synthetic_dir / "walkable_gt.npz"
    if gt_walk.is_file():
        out["walkable_iou"] = grid_iou(WalkableMap.load(scene_dir / "walkable.npz"), WalkableMap.load(gt_walk))
    return out


def run_demo(registry: Optional[str] = None, workdir: str = "vid2sim-work", seed: int = 0) -> dict:
    from vid2sim.factory.pipeline import ingest, preset
    from vid2sim.factory.progress import IngestProgress
    from vid2sim.factory.pipeline import STAGES
    from vid2sim.factory.synthetic.config import preset as street_preset
    from vid2sim.factory.synthetic.stage import main as make_street
    from vid2sim.registry import Registry

    console = Console()
    work = Path(workdir).resolve()
    t0 = time.perf_counter()
    console.rule("1/3 synthetic street video (procedural, with ground truth)")
    street = street_preset("demo", seed=seed)
    synth_dir = make_street(street, work / "synthetic")
    video = synth_dir / "video.mp4"
    console.print(f"video: {video} ({street.duration_s:.0f} s, {street.width}x{street.height}, "
                  f"{time.perf_counter() - t0:.0f} s)")

    console.rule("2/3 ingest (local Ray, fast preset)")
    holder: dict = {}
    report = ingest([str(video)], registry, workdir=work / "clips", conf=preset("fast"),
                    licence="CC0-synthetic", capture_height=street.capture_height,
                    on_plan=lambda ids: holder.setdefault(
                        "p", IngestProgress(ids, [n for n, _ in STAGES], console=console).__enter__()),
                    on_update=lambda s: holder["p"].update(s) if "p" in holder else None)
    if "p" in holder:
        holder["p"].__exit__(None, None, None)
    result = report.results[0]
    if not result.ok:
        console.print(f"[red]clip failed at {result.failed_stage}: {result.reason}[/red]\n{result.detail}")
        raise SystemExit(1)

    console.rule("3/3 registry")
    reg = Registry(registry)
    table = Table(title=f"registry {reg.root}")
    for col in ("scene", "version", "frames", "splats", "walkable m2", "PSNR test"):
        table.add_column(col)
    for rec in reg.list():
        table.add_row(rec.scene_id, str(rec.version), str(rec.num_frames), f"{rec.num_splats:,}",
                      f"{rec.walkable_area_m2:.1f}", f"{rec.metrics.get('recon.psnr', float('nan')):.2f}")
    console.print(table)
    scene_dir = Path(result.context["bundle_dir"])
    metrics = json.loads((scene_dir / "scene.json").read_text())["metrics"]
    gt = _ground_truth_errors(scene_dir, synth_dir, Path(result.context["posed_dir"]), street)
    preview = work / "preview.png"
    shutil.copyfile(scene_dir / "preview.png", preview)
    summary = {"scene_id": result.context["scene_id"], "seconds": round(time.perf_counter() - t0, 1),
               "stage_seconds": {k: round(v, 1) for k, v in result.seconds.items()},
               "metrics": {k: v for k, v in metrics.items() if isinstance(v, (int, float))},
               "ground_truth": gt, "preview": str(preview)}
    console.print_json(json.dumps(summary, default=float))
    return summary
