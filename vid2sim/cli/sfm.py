"""`vid2sim sfm ...`: run the SfM and metric-alignment stages on a frame folder."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Optional

import typer

from vid2sim.cli.errors import InputError
from vid2sim.cli.inputs import creatable_folder, existing_sources

app = typer.Typer(help="Structure from motion and the metric, gravity-aligned frame.",
                  no_args_is_help=True)


def _floats(text: str) -> list[float]:
    """--camera-params: comma-separated finite numbers."""
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise InputError("--camera-params", f"expected comma-separated numbers, got {text!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise InputError("--camera-params", f"values must be finite, got {text!r}")
    return values


@app.command("run")
def run(
    images: Path = typer.Option(..., "--images", help="Ordered folder of frames."),
    out: Path = typer.Option(..., "--out", help="Output folder (sparse/0, undistorted/, transforms.json)."),
    masks: Optional[Path] = typer.Option(None, "--masks", help="Masks folder (<image>.png, 0 = ignore)."),
    preset: str = typer.Option("fast", "--preset", help="fast | accurate"),
    camera_model: str = typer.Option("auto", "--camera-model",
                                     help="auto | OPENCV | OPENCV_FISHEYE | SIMPLE_RADIAL | PINHOLE"),
    camera_params: str = typer.Option("", "--camera-params", help="Known intrinsics, comma separated (COLMAP order)."),
    wide: Optional[bool] = typer.Option(None, "--wide/--not-wide", help="Lens hint: wide action camera."),
    as_json: bool = typer.Option(False, "--json", help="Print quality.json."),
) -> None:
    """SIFT + sequential matching + global mapper (incremental fallback) with a quality gate."""
    from vid2sim.factory.runtime.runner import run_stage
    from vid2sim.factory.sfm import sfm

    existing_sources([str(images)], "--images")
    creatable_folder(str(out), "--out")
    from vid2sim.factory.sfm.camera_model import LensHint

    conf = sfm.preset(preset, camera_model=camera_model, camera_params=_floats(camera_params),
                      lens=LensHint(wide=wide))
    out_dir = run_stage(sfm.work(conf, images, masks), out)
    q = sfm.load_quality(out_dir)
    typer.echo(json.dumps(q, indent=2) if as_json else
               f"{out_dir}: {q['num_registered']}/{q['num_frames']} registered, "
               f"reprojection {q['mean_reproj_error_px']:.3f} px, track length {q['mean_track_length']:.2f}")


@app.command("metric")
def metric_cmd(
    sfm_dir: Path = typer.Option(..., "--sfm", help="A finished `vid2sim sfm run` output."),
    out: Path = typer.Option(..., "--out", help="PosedClip output folder."),
    height: float = typer.Option(1.5, "--height", min=0.05, max=100.0, help="Capture height above the ground (m)."),
    gps_csv: str = typer.Option("", "--gps-csv", help="GoPro GPS5 CSV: scale from the walked distance."),
) -> None:
    """Ground plane -> z up, ground z = 0, metric scale; writes a PosedClip."""
    from vid2sim.factory.runtime.runner import run_stage
    from vid2sim.factory.sfm import metric

    existing_sources([str(sfm_dir)], "--sfm")
    creatable_folder(str(out), "--out")

    out_dir = run_stage(metric.work(metric.MetricConfig(capture_height_m=height, gps_csv=gps_csv), sfm_dir), out)
    info = json.loads((out_dir / "frame.json").read_text())
    typer.echo(f"{out_dir}: scale from {info['scale_source']} ({info['scale']:.4f}), plane inliers "
               f"{info['plane_inliers']}, residual {info['plane_residual_rms_m']:.3f} m")
