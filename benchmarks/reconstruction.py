"""Ablation: plain 3DGS vs geometry-consistent reconstruction at the same iteration budget.

Synthetic street (GT depth): renders a walk (vid2sim.factory.synthetic), replaces its exact
surface points by an SfM-like sparse cloud (random subset, Gaussian jitter: the benchmark must
not start from perfect geometry), then trains both variants with the `fast` preset and reports
held-out PSNR / SSIM, depth abs-rel and RMSE (median and expected rendered depth vs GT),
normal error and time. Target: geometry-consistent cuts depth abs-rel by >= 30% with held-out
PSNR within 0.3 dB (or better).
Real clip (../shared/data/gopro_max_sidewalk): decode -> masks -> SfM -> metric alignment (the
factory's stages) then both variants; skipped with a message when a stage is unavailable.

  .venv/bin/python benchmarks/reconstruction.py [--iterations 2000] [--seconds 6] [--width 320]
      [--points 4000] [--jitter 0.03] [--skip-real] [--work vid2sim-work/bench-recon]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path
from typing import Optional

import numpy as np

from common import Run, add_run_args  # benchmarks/common.py
from vid2sim.factory.sfm.posed import PosedClip
from vid2sim.factory.recon import config as C
from vid2sim.factory.recon.trainer import work as recon_work
from vid2sim.factory.runtime.runner import run_stage

ROOT = Path(__file__).resolve().parent.parent
REAL = ROOT.parent / "shared" / "data" / "gopro_max_sidewalk"
COLUMNS = ("psnr", "ssim", "depth_median_abs_rel", "depth_expected_abs_rel", "depth_median_rmse",
           "normal_err_deg", "n_gaussians", "train_seconds", "seconds")
UNITS = {"psnr": "dB", "depth_median_rmse": "m", "normal_err_deg": "deg", "train_seconds": "s", "seconds": "s",
         "wall_seconds": "s"}
RUN: Run  # the current run (set in main)


def skipped(reason: str) -> None:
    RUN.note(f"skipped real: {reason}")
    print(f"[real] skipped: {reason}")


def synthetic_clip(work: Path, seconds: float, width: int, n_points: int, jitter: float,
                   seed: int) -> tuple[Path, Path]:
    """Render the street (cached) and write an SfM-like PosedClip beside it; returns (posed, depth dir)."""
    from vid2sim.factory.synthetic.config import preset
    from vid2sim.factory.synthetic.make_street import main as synth

    height = int(round(width * 9 / 16 / 2) * 2)
    conf = preset("default", duration_s=seconds, width=width, height=height, write_frames=True,
                  write_depth=True, seed=seed)
    street = synth(conf, work / "street")
    clip = PosedClip.load(street)
    rng = np.random.default_rng(seed)
    keep = rng.choice(len(clip.points_xyz), min(n_points, len(clip.points_xyz)), replace=False)
    clip.points_xyz = clip.points_xyz[keep] + rng.normal(0, jitter, (len(keep), 3))
    clip.points_rgb = clip.points_rgb[keep]
    clip.frame_info["sparse_points"] = f"GT surface subset ({len(keep)}) + N(0, {jitter} m) jitter"
    return clip.save(work / "street_posed"), street / "depth"


def real_clip(work: Path) -> Optional[Path]:
    """The factory's front half on the GoPro sidewalk clip; None (with a message) if unavailable."""
    if not REAL.exists():
        skipped(f"{REAL} is absent")
        return None
    try:
        from vid2sim.factory.ingest import decode, masks
        from vid2sim.factory.sfm import metric, sfm
        from vid2sim.factory.runtime.pipeline import preset as pipeline_preset
    except ImportError as e:
        skipped(f"SfM/metric stages not available ({e})")
        return None
    video = next(iter(sorted(REAL.glob("*.mp4"))), None)
    if video is None:
        skipped(f"no video in {REAL}")
        return None
    try:
        pc = pipeline_preset("fast")
        t0 = time.perf_counter()
        dec = run_stage(decode.work(pc.decode, video), work / "real" / "decode")
        msk = run_stage(masks.work(pc.masks, dec), work / "real" / "masks")
        sfm_dir = run_stage(sfm.work(pc.sfm, dec / "images", msk / "masks"), work / "real" / "sfm")
        posed = run_stage(metric.work(pc.metric, sfm_dir), work / "real" / "metric")
        secs = RUN.record("real: front half (decode, masks, SfM, metric)", "seconds", time.perf_counter() - t0, "s")
        print(f"[real] front half (decode, masks, SfM, metric) {secs:.0f} s")
        return Path(posed)
    except Exception as e:  # a failing upstream stage must not hide the synthetic result
        skipped(f"front half failed: {type(e).__name__}: {e}")
        return None


def run_pair(name: str, posed: Path, work: Path, conf: C.ReconConfig, gt_depth: Optional[Path]) -> dict:
    rows = {}
    for variant, c in (("3dgs", C.baseline(conf)), ("geometry", conf)):
        t0 = time.perf_counter()
        out = run_stage(recon_work(c, posed, gt_depth_dir=gt_depth), work / f"{name}_{variant}")
        m = json.loads((out / "metrics.json").read_text())
        m.pop("per_frame", None)
        m["wall_seconds"] = time.perf_counter() - t0
        rows[variant] = m
        RUN.record_all(f"{name}: {variant}", {k: m.get(k) for k in (*COLUMNS, "wall_seconds")}, UNITS,
                       {"iterations": c.iterations, "prior": c.prior.kind})
        print(f"[{name}] {variant}: " + ", ".join(f"{k}={_fmt(m.get(k))}" for k in COLUMNS), flush=True)
    return rows


def _fmt(v) -> str:
    if v is None:
        return "-"
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def report(name: str, rows: dict) -> dict:
    b, g = rows["3dgs"], rows["geometry"]
    print(f"\n{name}: {'metric':<24}{'3DGS':>12}{'geometry':>12}")
    for k in COLUMNS:
        print(f"{'':>{len(name) + 2}}{k:<24}{_fmt(b.get(k)):>12}{_fmt(g.get(k)):>12}")
    out = {"psnr_delta_db": g["psnr"] - b["psnr"]}
    if b.get("depth_median_abs_rel"):
        for which in ("median", "expected"):
            key = f"depth_{which}_abs_rel"
            out[f"{which}_depth_error_cut"] = 1.0 - g[key] / b[key]
        out["target_met"] = bool(out["median_depth_error_cut"] >= 0.30 and out["psnr_delta_db"] >= -0.3)
    RUN.record_all(f"{name}: geometry vs 3dgs", out, {"psnr_delta_db": "dB"})
    print(f"  {json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in out.items()})}")
    return out


def main(argv: Optional[list[str]] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--iterations", type=int, default=None, help="default: the fast preset's")
    ap.add_argument("--seconds", type=float, default=6.0, help="synthetic walk duration")
    ap.add_argument("--width", type=int, default=320, help="synthetic render width")
    ap.add_argument("--points", type=int, default=4000)
    ap.add_argument("--jitter", type=float, default=0.03, help="sparse point noise (m)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--skip-real", action="store_true")
    ap.add_argument("--work", type=Path, default=ROOT / "vid2sim-work" / "bench-recon")
    add_run_args(ap)
    a = ap.parse_args(argv)
    global RUN
    with Run("reconstruction", a, argv=None if argv is None else ["benchmarks/reconstruction.py", *argv]) as RUN:
        return bench(a)


def bench(a: argparse.Namespace) -> int:
    conf = C.preset("fast")
    if a.iterations:
        conf = dataclasses.replace(conf, iterations=a.iterations)
    print(f"preset fast: {a.iterations or conf.iterations} iterations, max width {conf.max_width}, "
          f"prior {conf.prior.kind}")
    results = {"config": conf.to_dict()}
    t0 = time.perf_counter()
    posed, depth = synthetic_clip(a.work, a.seconds, a.width, a.points, a.jitter, a.seed)
    secs = RUN.record("synthetic: clip", "seconds", time.perf_counter() - t0, "s",
                      {"seconds": a.seconds, "width": a.width, "points": a.points, "jitter_m": a.jitter})
    print(f"[synthetic] clip ready in {secs:.0f} s")
    results["synthetic"] = run_pair("synthetic", posed, a.work, conf, depth)
    results["synthetic_summary"] = report("synthetic", results["synthetic"])
    if not a.skip_real:
        real = real_clip(a.work)
        if real is not None:
            results["real"] = run_pair("real", real, a.work, conf, None)
            results["real_summary"] = report("real", results["real"])
    (a.work / "results.json").write_text(json.dumps(results, indent=2, default=str))
    print(f"\nresults: {a.work / 'results.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
