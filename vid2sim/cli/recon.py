"""`vid2sim recon`: train splats for one PosedClip folder (the `recon` stage)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Optional

import typer

app = typer.Typer(help="Geometry-consistent Gaussian-splat reconstruction of a PosedClip.",
                  no_args_is_help=True)


@app.command("run")
def run(
    posed_dir: Path = typer.Argument(..., help="PosedClip folder (cameras.parquet, points.npz, frame.json)."),
    out_dir: Path = typer.Argument(..., help="Output folder (splats.ply, metrics.json, config.json)."),
    preset: str = typer.Option("fast", "--preset", help="fast | paper"),
    prior: Optional[str] = typer.Option(None, "--prior", help="Depth prior: mvs | depth_anything | none."),
    checkpoint: Optional[str] = typer.Option(None, "--depth-checkpoint",
                                             help="Local Depth-Anything-V2 folder (with --prior depth_anything)."),
    baseline: bool = typer.Option(False, "--baseline", help="Plain 3DGS: no prior, no geometry losses."),
    iterations: Optional[int] = typer.Option(None, "--iterations", min=1),
    gt_depth: Optional[Path] = typer.Option(None, "--gt-depth", help="GT depth folder for depth/normal error."),
    as_json: bool = typer.Option(False, "--json", help="Print the metrics as JSON."),
) -> None:
    """Train, evaluate on held-out frames (every 8th) and write the result; skips finished work."""
    from vid2sim.cli.inputs import creatable_folder, existing_sources
    from vid2sim.factory.recon import config as C

    existing_sources([str(posed_dir)], "POSED_DIR")
    creatable_folder(str(out_dir), "OUT_DIR")
    from vid2sim.factory.recon.data import OUTPUTS
    from vid2sim.factory.recon.trainer import work
    from vid2sim.factory.runtime.runner import run_stage

    conf = C.preset(preset)
    if iterations:
        conf = dataclasses.replace(conf, iterations=iterations)
    if prior or checkpoint:
        conf.prior = dataclasses.replace(conf.prior, kind=prior or conf.prior.kind,
                                         checkpoint=checkpoint or conf.prior.checkpoint)
    if baseline:
        conf = C.baseline(conf)
    out = run_stage(work(conf, posed_dir, gt_depth_dir=gt_depth), out_dir)
    metrics = json.loads((out / OUTPUTS.metrics).read_text())
    metrics.pop("per_frame", None)
    if as_json:
        typer.echo(json.dumps(metrics, indent=2))
    else:
        typer.echo(f"{out}: PSNR {metrics['psnr']:.2f} dB, SSIM {metrics['ssim']:.3f}, "
                   f"{metrics['n_gaussians']} Gaussians, {metrics['seconds']:.0f} s")
