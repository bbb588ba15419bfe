"""`vid2sim demo`: the whole chain on data it makes itself (no downloads).

1. Generate a procedural street and render a hand-held walking video with ground truth.
2. Ingest the video with the `fast` preset on an embedded local Ray runtime
   (decode -> masks -> SfM -> metric frame -> splats -> mesh/walkable -> bundle -> commit).
3. Print the registry listing and a summary of the scene's metrics and its errors against
   ground truth (all figures in WORKDIR/summary.json), and write a preview image.
`vid2sim demo` then drives the scripted expert through the scene (`vid2sim.cli.demo`).
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path
from typing import Optional

from rich.console import Console
from rich.table import Table


def run_demo(registry: Optional[str] = None, workdir: str = "vid2sim-work", seed: int = 0) -> dict:
    from vid2sim.factory.runtime.pipeline import STEP_NAMES, bundle_path, ingest, preset
    from vid2sim.factory.runtime.progress import IngestProgress
    from vid2sim.factory.runtime.runner import local_outputs
    from vid2sim.factory.synthetic.config import preset as street_preset
    from vid2sim.factory.synthetic.make_street import main as make_street
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
                        "p", IngestProgress(ids, list(STEP_NAMES), console=console).__enter__()),
                    on_update=lambda s: holder["p"].update(s) if "p" in holder else None)
    if "p" in holder:
        holder["p"].__exit__(None, None, None)
        console.print()
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
    scene_dir = bundle_path(result.work)
    metrics = json.loads((scene_dir / "scene.json").read_text())["metrics"]
    import trimesh

    from vid2sim.factory.sfm.posed import PosedClip
    from vid2sim.factory.evaluation.synthetic_gt import scene_errors
    from vid2sim.factory.runtime.steps import metric
    from vid2sim.formats.bundle import COLLISION_PLY
    from vid2sim.formats.walkable import WALKABLE_NPZ, load_walkable

    gt = scene_errors(PosedClip.load(local_outputs(result.work, metric.NAME).dir), synth_dir,
                      trimesh.load(scene_dir / COLLISION_PLY, force="mesh"),
                      load_walkable(scene_dir / WALKABLE_NPZ))
    preview = work / "preview.png"
    shutil.copyfile(scene_dir / "preview.png", preview)
    summary = {"scene_id": result.work.job.scene_id, "seconds": round(time.perf_counter() - t0, 1),
               "stage_seconds": {k: round(v, 1) for k, v in result.seconds.items()},
               "metrics": {k: v for k, v in metrics.items() if isinstance(v, (int, float))},
               "ground_truth": gt, "preview": str(preview)}
    (work / "summary.json").write_text(json.dumps(summary, indent=2, default=float))
    console.print(summary_table(summary))
    console.print(f"all figures: {work / 'summary.json'}")
    return summary


SUMMARY_ROWS = (("metrics", "recon.psnr", "held-out PSNR (dB)"),
                ("ground_truth", "ate_pct_of_path", "pose ATE (% of path)"),
                ("ground_truth", "metric_scale_error_pct", "metric scale error (%)"),
                ("ground_truth", "collision_accuracy_m", "collision mesh accuracy (m)"),
                ("ground_truth", "walkable_iou", "walkable map IoU"),
                ("metrics", "corridor.walkable_fraction", "walked path walkable"))


def summary_table(summary: dict) -> Table:
    """The demo's headline figures: wall time, reconstruction and errors against ground truth."""
    table = Table(title=f"demo scene {summary['scene_id']}: {summary['seconds']:.0f} s")
    table.add_column("figure")
    table.add_column("value", justify="right")
    for group, key, label in SUMMARY_ROWS:
        v = summary.get(group, {}).get(key)
        if isinstance(v, (int, float)):
            table.add_row(label, f"{v:.4g}")
    table.add_row("preview", str(summary["preview"]))
    return table
