"""Benchmark: render the synthetic street (default 10 s, 854x480, 30 fps) and write the GT bundle.

Prints measured seconds per stage and per frame.  Usage:
    .venv/bin/python benchmarks/synthetic_street.py [--seed 0] [--duration 10] [--out /tmp/syn_bench] [--quick]
        [--threads N]   # frames rendered side by side (default: every CPU this process may use)
"""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

from common import Run, add_run_args
from vid2sim.factory.synthetic import generate_street, preset, render_video, write_ground_truth_bundle
from vid2sim.threads import usable_cpus


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--out", default="/tmp/vid2sim-bench-synthetic")
    ap.add_argument("--quick", action="store_true", help="a 3 s walk (smoke run)")
    ap.add_argument("--threads", type=int, default=None,
                    help="frames rendered side by side (default: every CPU this process may use)")
    add_run_args(ap)
    a = ap.parse_args()
    if a.quick and a.duration == 10.0:
        a.duration = 3.0
    with Run("synthetic_street", a) as run:
        measure(run, a)


def measure(run: Run, a: argparse.Namespace) -> None:
    out = Path(a.out)
    shutil.rmtree(out, ignore_errors=True)
    conf = preset("demo", seed=a.seed, duration_s=a.duration)
    t0 = time.perf_counter()
    scene = generate_street(conf)
    t1 = time.perf_counter()
    threads = a.threads or usable_cpus()
    c1 = time.process_time()
    clip = render_video(scene, conf, out / "clip", threads=threads)
    render_cpu = time.process_time() - c1
    t2 = time.perf_counter()
    write_ground_truth_bundle(scene, clip, out / "bundle")
    t3 = time.perf_counter()
    n = len(clip.cam_to_world)
    case = f"demo preset, {a.duration:g} s walk, {conf.width}x{conf.height}, {threads} render thread(s)"
    cfg = {"seed": a.seed, "fps": conf.fps, "frames": n, "threads": threads}
    run.record_all(case, {"faces": scene.n_faces, "generate_s": t1 - t0, "render_s": t2 - t1,
                          "render_cpu_s": render_cpu, "render_ms_per_frame": (t2 - t1) / n * 1000,
                          "gt_bundle_s": t3 - t2,
                          "video_mb": clip.video.stat().st_size / 1e6,
                          "path_m": clip.ground_truth["path_length"]},
                   {"faces": "", "generate_s": "s", "render_s": "s", "render_cpu_s": "s", "render_ms_per_frame": "ms",
                    "gt_bundle_s": "s", "video_mb": "MB", "path_m": "m"}, cfg)
    print(f"street: {scene.n_faces} faces, generate {t1 - t0:.2f} s")
    print(f"render: {n} frames {conf.width}x{conf.height} in {t2 - t1:.1f} s ({(t2 - t1) / n * 1000:.0f} ms/frame, "
          f"incl. H.264 + depth PNGs; {threads} thread(s), {render_cpu:.1f} CPU-s)")
    print(f"GT bundle: {t3 - t2:.1f} s; video {clip.video.stat().st_size / 1e6:.1f} MB, "
          f"path {clip.ground_truth['path_length']:.2f} m")


if __name__ == "__main__":
    main()
