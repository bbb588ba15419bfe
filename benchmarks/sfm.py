"""Benchmark: decode -> masks -> SfM -> metric on real and synthetic clips, with pose errors.

Clips (real ones from ../shared/data; skipped when absent):
  gopro      gopro_max_sidewalk/max-heromode.mp4, sampled at 10 fps (every 3rd frame, ~105 frames,
             848x480). Bars: >= 95 % registered, mean reprojection error <= 1 px; relative rotation
             error vs telemetry_orientation_per_frame.csv; scale from 1.5 m vs from GPS5 speed.
  kitti      kitti_rural (51 frames, PINHOLE K from calib.txt P0). Bar: ATE <= 1 % of the path;
             metric scale from the known 1.65 m camera height vs ground truth.
  lund       opensfm_lund_street (29 iPhone photos, EXIF focal): registers and reports.
  synthetic  the procedural street (10 s, 854x480): ATE, metric scale and ground normal vs GT.
Prints registered fraction, reprojection error, track length, ATE, seconds per stage and the
hardware line. `--free-threads` runs COLMAP's matching and mappers on the stage's threads too
(`SfMConfig.deterministic = False`: faster, no longer the same model bit for bit): what
reproducibility costs. `--set FIELD=VALUE` replaces `SfMConfig` fields of every clip's preset
(`vid2sim ingest --set`'s rules, e.g. `--set tracks_per_view=200`). Usage:
    .venv/bin/python benchmarks/sfm.py [--clips gopro,kitti,lund,synthetic] [--preset fast]
                                       [--work /tmp/vid2sim-bench-sfm] [--free-threads] [--set F=V ...]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from common import Run, add_run_args  # benchmarks/common.py
from vid2sim.cli.settings import apply_overrides
from vid2sim.factory.runtime.runner import run_stage
from vid2sim.factory.sfm import sfm

ROOT = Path(__file__).resolve().parent.parent
DATA = Path(os.environ.get("VID2SIM_SHARED_DATA", ROOT.parent / "shared" / "data"))
RUN: Run  # the current run (set in main)
SFM_OVERRIDES: dict = {}  # SfMConfig fields every clip's preset gets (set in main)
SFM_SETS: list[str] = []  # --set FIELD=VALUE items applied after them (set in main)


def sfm_conf(preset: str, **fields: Any) -> "sfm.SfMConfig":
    """A clip's SfM config: the preset with its own fields, --free-threads and --set."""
    return apply_overrides(sfm.preset(preset, **SFM_OVERRIDES, **fields), SFM_SETS)


def timed(times: dict, name: str, fn: Callable[[], Any]) -> Any:
    t0 = time.perf_counter()
    out = fn()
    times[name] = time.perf_counter() - t0
    return out


def decode_and_mask(video: Path, work: Path, times: dict, max_side: int) -> tuple[Path, Path]:
    """The factory's decode (10 fps, faces blurred) and masks stages."""
    from vid2sim.factory.ingest import decode, masks

    dconf = decode.DecodeConfig(fps=10.0, max_side=max_side, workers=2)
    ddir = timed(times, "decode", lambda: run_stage(decode.work(dconf, str(video)), work / "decode"))
    mdir = timed(times, "masks", lambda: run_stage(masks.work(masks.MasksConfig(), ddir), work / "masks"))
    return ddir / "images", mdir / "masks"


def sfm_and_metric(sconf: Any, mconf: Any, images: Path, masks_dir: Any, work: Path,
                   times: dict) -> tuple[Path, Path, dict]:
    from vid2sim.factory.sfm import metric

    sdir = timed(times, "sfm", lambda: run_stage(sfm.work(sconf, images, masks_dir), work / "sfm"))
    pdir = timed(times, "metric", lambda: run_stage(metric.work(mconf, sdir), work / "metric"))
    return sdir, pdir, sfm.load_quality(sdir)


def report(name: str, q: dict, times: dict, extra: dict) -> dict:
    total = sum(times.values())
    if SFM_OVERRIDES.get("deterministic") is False:
        name += ", matching and mappers on the stage's threads"
    if SFM_SETS:
        name += ", " + " ".join(SFM_SETS)
    print(f"\n== {name}")
    print(f"registered {q['num_registered']}/{q['num_frames']} ({q['registered_fraction']:.1%}), "
          f"mapper {q['mapper']}, camera {q['camera_model']} "
          f"{[round(p, 3) for p in q['camera_params']]}")
    print(f"mean reprojection error {q['mean_reproj_error_px']:.3f} px, mean track length "
          f"{q['mean_track_length']:.2f}, {q['num_points']} points, median tri angle "
          f"{q['median_tri_angle_deg']:.2f} deg")
    print("seconds: " + ", ".join(f"{k} {v:.1f}" for k, v in times.items()) + f"; total {total:.1f}")
    print("sfm steps: " + ", ".join(f"{k} {v:.1f}" for k, v in q["seconds"].items()))
    for k, v in extra.items():
        print(f"{k}: {v}")
    record_clip(name, q, times, total, extra)
    return {"clip": name, "quality": q, "seconds": times, "total_s": total, **extra}


def flat(d: dict, prefix: str = "") -> dict:
    """Nested dict -> {"outer inner": value}."""
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flat(v, key + " "))
        else:
            out[key] = v
    return out


def record_clip(name: str, q: dict, times: dict, total: float, extra: dict) -> None:
    """Every figure report() prints, as rows of the run (case: the clip)."""
    keys = ("num_registered", "num_frames", "registered_fraction", "mapper", "camera_model", "camera_params",
            "mean_reproj_error_px", "mean_track_length", "num_points", "median_tri_angle_deg")
    RUN.record_all(name, {k: q[k] for k in keys}, {"mean_reproj_error_px": "px", "median_tri_angle_deg": "deg"})
    RUN.record_all(name, {**{f"{k} s": v for k, v in times.items()}, "total s": total}, "s")
    RUN.record_all(name, {f"sfm step {k} s": v for k, v in q["seconds"].items()}, "s")
    RUN.record_all(name, flat(extra))


def frame_facts(pdir: Path) -> dict:
    info = json.loads((pdir / "frame.json").read_text())
    return {"scale_source": info["scale_source"], "plane_inliers": info["plane_inliers"],
            "plane_residual_rms_m": round(info["plane_residual_rms_m"], 4),
            "gravity_prior_angle_deg": round(info["gravity_prior_angle_deg"], 2),
            "camera_height_m": {k: round(v, 3) for k, v in info["camera_height_m"].items()}}


def run_gopro(work: Path, preset: str) -> dict:
    from vid2sim.factory.sfm import metric
    from vid2sim.factory.sfm.camera_model import LensHint
    from vid2sim.factory.evaluation.poses import gopro_rotation_errors, load_posed_clip

    src = DATA / "gopro_max_sidewalk"
    times: dict = {}
    images, masks_dir = decode_and_mask(src / "max-heromode.mp4", work, times, 848)
    sconf = sfm_conf(preset, lens=LensHint(make="GoPro", model="MAX"))
    _, pdir, q = sfm_and_metric(sconf, metric.MetricConfig(capture_height_m=1.5), images,
                                masks_dir, work, times)
    est = load_posed_clip(pdir)
    rot = gopro_rotation_errors(est, src / "telemetry_orientation_per_frame.csv", deltas=(1, 5, 15),
                                fps=29.97, stride=3)
    gps = run_stage(metric.work(metric.MetricConfig(gps_csv=str(src / "telemetry_gps5.csv")), work / "sfm"),
                    work / "metric_gps")
    s_h = json.loads((pdir / "frame.json").read_text())["scale"]
    s_gps = json.loads((gps / "frame.json").read_text())["scale"]
    extra = {"rotation_error_deg (fitted median per delta)":
             {k: round(v["fitted_median_deg"], 3) for k, v in rot["deltas"].items()},
             "rotation angle gap median deg vs stabilised image (IORI*CORI)": {
                 k: round(v["angle_gap_median_deg"], 3) for k, v in rot["deltas"].items()},
             "scale 1.5 m height / scale GPS": round(s_h / s_gps, 3),
             "gravity vs GRAV median deg": round(gravity_error_deg(
                 pdir, src / "telemetry_orientation_per_frame.csv"), 2),
             "bars": {"registered>=95%": q["registered_fraction"] >= 0.95,
                      "reproj<=1px": q["mean_reproj_error_px"] <= 1.0},
             **frame_facts(pdir)}
    return report("gopro_max_sidewalk (10 fps, 848x480)", q, times, extra)


def gravity_error_deg(pdir: Path, csv_path: Path, fps: float = 29.97) -> float:
    """Median angle between our world down (-z) in camera axes and the GoPro GRAV vector."""
    import csv

    from vid2sim.factory.sfm.posed import PosedClip

    with open(csv_path, newline="") as f:
        grav = {int(r["sample"]): np.array([float(r[f"grav_{a}"]) for a in "xyz"]) for r in csv.DictReader(f)}
    errs = []
    for fr in PosedClip.load(pdir).frames:
        g = grav.get(int(round(fr.timestamp * fps)))
        if g is not None:
            down = fr.cam_to_world[:3, :3].T @ np.array([0.0, 0.0, -1.0])
            errs.append(np.degrees(np.arccos(np.clip(down @ g / np.linalg.norm(g), -1, 1))))
    return float(np.median(errs)) if errs else float("nan")


def kitti_K(calib: Path) -> list[float]:
    P0 = np.array([v for v in calib.read_text().splitlines()[0].split() if ":" not in v],
                  float).reshape(3, 4)
    return [P0[0, 0], P0[1, 1], P0[0, 2], P0[1, 2]]


def run_kitti(work: Path, preset: str) -> dict:
    from vid2sim.factory.sfm import metric
    from vid2sim.factory.evaluation.poses import evaluate, load_kitti_poses, load_posed_clip

    src = DATA / "kitti_rural"
    times: dict = {}
    sconf = sfm_conf(preset, camera_model="PINHOLE", camera_params=kitti_K(src / "calib.txt"),
                       max_image_size=1241)
    _, pdir, q = sfm_and_metric(sconf, metric.MetricConfig(capture_height_m=1.65),
                                src / "image_l", None, work, times)
    ev = evaluate(load_posed_clip(pdir), load_kitti_poses(src / "poses.txt"))
    extra = {"ATE rmse m": round(ev["ate"]["rmse"], 3),
             "ATE % of path": round(ev["ate"]["rmse_pct_of_path"], 3),
             "path m": round(ev["ate"]["path_length"], 2),
             "metric scale error (1.65 m height)": f"{(1 / ev['ate']['scale'] - 1):+.1%}",
             "bars": {"ATE<=1%": ev["ate"]["rmse_pct_of_path"] <= 1.0}, **frame_facts(pdir)}
    return report("kitti_rural (51 frames, known K)", q, times, extra)


def run_lund(work: Path, preset: str) -> dict:
    from vid2sim.factory.sfm import metric

    src = DATA / "opensfm_lund_street"
    times: dict = {}
    _, pdir, q = sfm_and_metric(sfm_conf(preset, max_image_size=1024), metric.MetricConfig(),
                                src / "images", None, work, times)
    return report("opensfm_lund_street (29 photos)", q, times, frame_facts(pdir))


def run_synthetic(work: Path, preset: str) -> dict:
    from vid2sim.factory.sfm import metric
    from vid2sim.factory.evaluation.poses import evaluate, load_posed_clip
    from vid2sim.factory.synthetic import generate_street, render_video
    from vid2sim.factory.synthetic import preset as street_preset

    conf = street_preset("demo", seed=0)
    clip = render_video(generate_street(conf), conf, work / "render")
    times: dict = {}
    images, masks_dir = decode_and_mask(clip.video, work, times, 854)
    _, pdir, q = sfm_and_metric(sfm_conf(preset), metric.MetricConfig(capture_height_m=1.5),
                                images, masks_dir, work, times)
    ev = evaluate(load_posed_clip(pdir), load_posed_clip(work / "render"))
    R = np.asarray(ev["ate"]["rotation"])
    normal_err = float(np.degrees(np.arccos(np.clip((R @ [0, 0, 1.0])[2], -1, 1))))
    extra = {"matched frames": ev["n_matched"], "ATE % of path": round(ev["ate"]["rmse_pct_of_path"], 3),
             "metric scale error (1.5 m height)": f"{(1 / ev['ate']['scale'] - 1):+.1%}",
             "ground normal error deg": round(normal_err, 2),
             "bars": {"ATE<=0.5%": ev["ate"]["rmse_pct_of_path"] <= 0.5,
                      "scale within 10%": abs(1 / ev["ate"]["scale"] - 1) <= 0.1,
                      "normal<=2deg": normal_err <= 2.0,
                      "decode+masks+sfm+metric<=180s": sum(times.values()) <= 180},
             **frame_facts(pdir)}
    return report("synthetic street (10 s, 854x480)", q, times, extra)


RUNNERS = {"gopro": run_gopro, "kitti": run_kitti, "lund": run_lund, "synthetic": run_synthetic}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--clips", default="gopro,kitti,lund,synthetic")
    ap.add_argument("--preset", default="fast")
    ap.add_argument("--work", default="/tmp/vid2sim-bench-sfm")
    ap.add_argument("--keep", action="store_true", help="reuse finished stages in --work")
    ap.add_argument("--free-threads", action="store_true",
                    help="matching and mappers on the stage's threads (not reproducible bit for bit)")
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="FIELD=VALUE",
                    help="an SfMConfig field of every clip's preset (repeatable)")
    add_run_args(ap)
    a = ap.parse_args()
    global RUN
    if a.free_threads:
        SFM_OVERRIDES["deterministic"] = False
    SFM_SETS.extend(a.sets)
    try:  # a bad --set fails before any work
        apply_overrides(sfm.preset(a.preset), SFM_SETS)
    except ValueError as e:  # SettingError, RangeError: the field and the reason
        raise SystemExit(f"--preset {a.preset}: {e}") from None
    with Run("sfm", a) as RUN:
        bench(a)


def bench(a: argparse.Namespace) -> None:
    results = []
    for name in a.clips.split(","):
        work = Path(a.work) / name
        if not a.keep:
            shutil.rmtree(work, ignore_errors=True)
        if name != "synthetic" and not DATA.exists():
            RUN.skip(name, f"{DATA} is absent")
            continue
        try:
            results.append(RUNNERS[name](work, a.preset))
        except Exception as e:  # report and go on with the next clip
            RUN.note(f"{name} failed: {type(e).__name__}: {e}")
            print(f"\n== {name}: FAILED {type(e).__name__}: {e}")
    Path(a.work).mkdir(parents=True, exist_ok=True)
    (Path(a.work) / "results.json").write_text(json.dumps(results, indent=2, default=str))


if __name__ == "__main__":
    main()
