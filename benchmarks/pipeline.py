"""Pipeline benchmark: end-to-end ingest timings on an embedded local Ray runtime.

    .venv/bin/python benchmarks/pipeline.py gopro       # 10 s GoPro clip -> registered scene (fast preset)
    .venv/bin/python benchmarks/pipeline.py parallel    # 4 synthetic clips: 2 workers vs one after another

`gopro` reads ../shared/data (skips with a message when absent). `parallel` compares
ingesting N clips in one call (clips share the CPUs: each clip's tasks get CPUs/N, so two
clips run at once on 2 cores) against N calls of one clip each (each clip gets every CPU).
Each run uses a fresh work folder and registry, so nothing is cached between runs.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from common import Run, add_run_args  # noqa: E402  (benchmarks/common.py)
from vid2sim.factory.runtime.pipeline import ingest, preset  # noqa: E402

DATA = Path(os.environ.get("VID2SIM_SHARED_DATA", ROOT.parent / "shared" / "data"))


def run_ingest(inputs: list[str], work: Path, **kw) -> tuple[float, dict]:
    t0 = time.perf_counter()
    report = ingest(inputs, str(work / "registry"), workdir=work / "clips", conf=preset("fast"), num_cpus=2, **kw)
    seconds = time.perf_counter() - t0
    return seconds, report.to_json()


def bench_gopro(run: Run, args: argparse.Namespace) -> None:
    video = DATA / "gopro_max_sidewalk" / "max-heromode.mp4"
    if not video.is_file():
        run.skip("gopro", f"{video} is absent (benchmarks read ../shared/data beside the project)")
        return
    work = Path(tempfile.mkdtemp(prefix="bench-gopro-"))
    seconds, rep = run_ingest([str(video)], work, licence="Apache-2.0 OR MIT", capture_height=1.5)
    clip = rep["clips"][0]
    case = "gopro 10.5 s 848x480, fast preset"
    run.record_all(case, {"ok": clip["ok"], "reason": clip["reason"]})
    run.record_all(case, {f"{k} s": v for k, v in clip["stage_seconds"].items()}, "s")
    print(json.dumps({"clip": clip["clip"], "ok": clip["ok"], "reason": clip["reason"],
                      "stage_seconds": clip["stage_seconds"]}, indent=2))
    if clip["ok"]:
        from vid2sim.registry import Registry

        rec = Registry(str(work / "registry")).show(clip["scene_id"])
        keys = ("recon.psnr", "recon.ssim", "sfm.registered_fraction", "sfm.mean_reproj_error_px",
                "recon.n_gaussians", "walkable.walkable_area_m2", "meshing.collision_faces")
        run.record_all(case, {k: rec.metrics.get(k) for k in keys},
                       {"walkable.walkable_area_m2": "m2", "sfm.mean_reproj_error_px": "px", "recon.psnr": "dB"})
        print({k: rec.metrics.get(k) for k in keys})
    corridor = next(work.glob("clips/*/walkable/corridor.json"), None)  # written even when gated
    if corridor is not None:
        c = json.loads(corridor.read_text())
        run.record_all(case, {"corridor walkable_fraction": c["walkable_fraction"],
                              "corridor path_components": c["path_components"],
                              "corridor_area_m2": c["corridor_area_m2"], "corridor gate passed": c["passed"]},
                       {"corridor_area_m2": "m2"})
        print(f"corridor: {c['walkable_fraction']:.1%} of the walked path walkable (target >= 99 %), "
              f"{c['path_components']} component(s) (target 1), {c['corridor_area_m2']:.3f} m^2 of "
              f"collision surface in the body corridor (target < 0.05); gate "
              f"{'passed' if c['passed'] else 'failed: ' + c['reasons']}")
    run.record(case, "wall_s (target <= 1200)", seconds, "s")
    print(f"gopro 10.5 s 848x480 -> registered scene: {seconds:.0f} s wall (target <= 1200 s)")
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)


def synthetic_clips(n: int, seconds: float, root: Path) -> list[str]:
    from vid2sim.factory.synthetic.config import preset as street_preset
    from vid2sim.factory.synthetic.make_street import main as make_street

    out = []
    for seed in range(n):
        conf = street_preset("demo", seed=seed, duration_s=seconds, width=640, height=360)
        out.append(str(make_street(conf, root / f"street-{seed}") / "video.mp4"))
    return out


def bench_parallel(run: Run, args: argparse.Namespace) -> None:
    root = Path(tempfile.mkdtemp(prefix="bench-parallel-"))
    videos = synthetic_clips(args.clips, args.seconds, root / "videos")
    seq = 0.0
    for i, v in enumerate(videos):
        s, rep = run_ingest([v], root / f"seq-{i}", licence="CC0", capture_height=1.5)
        seq += s
        run.record_all(f"sequential clip {i} of {args.seconds:g} s", {"wall_s": s, "ok": rep["clips"][0]["ok"]},
                       {"wall_s": "s"}, {"clips": args.clips})
        print(f"sequential clip {i}: {s:.0f} s ok={rep['clips'][0]['ok']} {rep['clips'][0]['reason'] or ''}")
    par, rep = run_ingest(videos, root / "par", licence="CC0", capture_height=1.5)
    ok = sum(c["ok"] for c in rep["clips"])
    run.record_all(f"{args.clips} clips of {args.seconds:g} s",
                   {"one after another s": seq, "in one ingest s": par, "ok": ok,
                    "ratio (target <= 0.60)": par / seq}, {"one after another s": "s", "in one ingest s": "s"})
    print(f"{args.clips} clips of {args.seconds:.0f} s: one after another {seq:.0f} s; "
          f"in one ingest (2 at a time) {par:.0f} s ({ok}/{args.clips} ok); ratio {par / seq:.2f} (target <= 0.60)")
    if not args.keep:
        shutil.rmtree(root, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("what", choices=["gopro", "parallel"])
    ap.add_argument("--clips", type=int, default=4)
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--keep", action="store_true", help="keep the work folders")
    add_run_args(ap)
    args = ap.parse_args()
    with Run("pipeline", args) as run:
        {"gopro": bench_gopro, "parallel": bench_parallel}[args.what](run, args)


if __name__ == "__main__":
    main()
