"""Ingest benchmark: decode + masks of the 10.5 s, 848x480 GoPro sidewalk clip (and the Lund folder).

    .venv/bin/python benchmarks/ingest.py [--fps 10] [--workers 2] [--out DIR]

Prints wall and CPU seconds (this process + its worker processes) per stage, the frame
counts, and a breakdown of decode (sampling, filters, face blurring + writing) so the
budget (decode + masks <= 40 s on 2 cores for a 10 s 480p clip) can be checked.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from common import Run, add_run_args  # noqa: E402  (benchmarks/common.py)
from vid2sim.factory.ingest import decode, masks  # noqa: E402
from vid2sim.factory.ingest.privacy import Anonymiser  # noqa: E402
from vid2sim.factory.runtime.runner import run_stage  # noqa: E402

DATA = Path(os.environ.get("VID2SIM_SHARED_DATA", ROOT.parent / "shared" / "data"))


def cpu() -> float:
    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime


RUN: Run  # the current run (set in main)


def timed(label: str, fn):
    w0, c0 = time.perf_counter(), cpu()
    result = fn()
    wall, used = time.perf_counter() - w0, cpu() - c0
    RUN.record_all(label.strip(), {"wall_s": wall, "cpu_s": used}, "s")
    print(f"{label:<34s} wall {wall:6.2f} s   cpu {used:6.2f} s")
    return result


def summary(label: str, d) -> None:
    from vid2sim.factory.runtime.stage_cache import load_record

    s = load_record(d).summary
    RUN.record_all(label, s)
    print(f"{label}:", s)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--fps", type=float, default=10.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None)
    add_run_args(ap)
    args = ap.parse_args()
    global RUN
    with Run("ingest", args, config={"fps": args.fps, "workers": args.workers}) as RUN:
        bench(args)


def bench(args: argparse.Namespace) -> None:
    video = DATA / "gopro_max_sidewalk" / "max-heromode.mp4"
    if not video.exists():
        RUN.skip("gopro", f"{video} is absent (benchmarks read ../shared/data beside the project)")
        return
    out = args.out or Path(tempfile.mkdtemp(prefix="vid2sim-ingest-"))
    conf = replace(decode.DecodeConfig(), fps=args.fps, workers=args.workers)
    print(f"cores {os.cpu_count()}, load {os.getloadavg()[0]:.1f}, fps {args.fps}, workers {args.workers}")

    samples, _ = timed("  read + sample (PyAV)", lambda: decode.sample_video(video, conf, None))
    timed("  sharpness + duplicate flow", lambda: decode.filter_samples(samples, conf))
    blur = Anonymiser(conf.faces, conf.plates)
    timed("  face detection, 10 frames, 1 proc", lambda: [blur(s.image) for s in samples[:10]])
    d = timed("decode stage (total)", lambda: run_stage(decode.work(conf, video), out / "decode"))
    m = timed("masks stage (total)", lambda: run_stage(masks.work(masks.MasksConfig(), d), out / "masks"))
    summary("decode summary", d)
    summary("masks summary", m)
    lund = DATA / "opensfm_lund_street" / "images"
    if lund.exists():
        ld = timed("lund folder decode (29 photos)", lambda: run_stage(decode.work(conf, lund), out / "lund"))
        summary("lund summary", ld)
    if args.out is None:
        shutil.rmtree(out)


if __name__ == "__main__":
    main()
