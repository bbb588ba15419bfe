"""Splat engine benchmark: cpu backend speed, cpu vs torch, and the static env path.

Run: .venv/bin/python benchmarks/splats.py [--quick]
Prints measured figures only (no assertions). Single-thread rows also give CPU time
(process_time), which is less distorted than wall time on a shared machine.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time

import numba
import torch

from vid2sim.splats.cpu import StaticScene, rasterize
from vid2sim.splats.cpu.synthetic import front_camera, random_blob_scene, robot_camera, street_scene
from vid2sim.splats.reference import rasterize as ref_rasterize
from vid2sim.splats.types import RasterSettings

ALL = numba.config.NUMBA_NUM_THREADS


def cpu_model() -> str:
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def timeit(fn, min_reps: int = 3, min_time: float = 0.5) -> tuple[float, float]:
    """(wall s, cpu s) per call, after one warm-up call."""
    fn()
    reps, t0, c0 = 0, time.perf_counter(), time.process_time()
    while reps < min_reps or time.perf_counter() - t0 < min_time:
        fn()
        reps += 1
    return (time.perf_counter() - t0) / reps, (time.process_time() - c0) / reps


def params(model):
    return model.means, model.quats, model.log_scales, model.opacity_logits, model.sh


def forward_table(sizes, resolutions) -> None:
    print("\n## forward (rasterize, no grad), random scene, SH degree 3")
    print(f"{'N':>7} {'res':>8} {'1 thread fps':>13} {'(cpu-time fps)':>15} {f'{ALL} threads fps':>14} {'visible':>8}")
    for n in sizes:
        model = random_blob_scene(n, seed=1)
        for w, h in resolutions:
            cam = front_camera(w, h)
            st = RasterSettings(w, h)
            run = lambda: rasterize(*params(model), cam, st)  # noqa: E731
            with torch.no_grad():
                numba.set_num_threads(1)
                w1, c1 = timeit(run)
                numba.set_num_threads(ALL)
                wa, _ = timeit(run)
                vis = int((run().radii > 0).sum())
            print(f"{n:>7} {w:>4}x{h:<3} {1 / w1:>13.1f} {1 / c1:>15.1f} {1 / wa:>14.1f} {vis:>8}")


def fwd_bwd(fn, model, cam, st):
    ps = [p.detach().clone().requires_grad_(True) for p in params(model)]
    out = fn(*ps, cam, st, absgrad=True)
    loss = out.color_accum.square().mean() + out.depth_accum.mean() + out.alpha.mean()
    loss.backward()


def backward_table(n: int, res: tuple[int, int]) -> None:
    w, h = res
    model = random_blob_scene(n, seed=2)
    cam, st = front_camera(w, h), RasterSettings(w, h)
    print(f"\n## forward+backward (loss on rgb, depth, alpha; absgrad on), {n} splats, {w}x{h}")
    for threads in (1, ALL):
        numba.set_num_threads(threads)
        wall, cpu = timeit(lambda: fwd_bwd(rasterize, model, cam, st))
        print(f"  {threads} thread(s): {wall * 1e3:8.1f} ms wall   {cpu * 1e3:8.1f} ms cpu-time")
    numba.set_num_threads(ALL)
    ps = [p.detach().clone() for p in params(model)]
    with torch.no_grad():
        fw, _ = timeit(lambda: rasterize(*ps, cam, st))
    print(f"  forward only ({ALL} threads): {fw * 1e3:.1f} ms")


def ratio_table(n: int, res: tuple[int, int]) -> None:
    w, h = res
    model = random_blob_scene(n, seed=3)
    cam, st = front_camera(w, h), RasterSettings(w, h)
    print(f"\n## cpu vs torch reference: forward+backward, {n} splats, {w}x{h}, {ALL} threads")
    numba.set_num_threads(ALL)
    tc, _ = timeit(lambda: fwd_bwd(rasterize, model, cam, st))
    tt, _ = timeit(lambda: fwd_bwd(ref_rasterize, model, cam, st), min_reps=1, min_time=0.0)
    print(f"  torch {tt * 1e3:.0f} ms   cpu {tc * 1e3:.1f} ms   speed-up x{tt / tc:.1f}")


def static_table(n: int, res: tuple[int, int]) -> None:
    w, h = res
    model = street_scene(n, seed=4)
    t0 = time.perf_counter()
    scene = StaticScene(model)
    print(f"\n## static env path: street scene {n} splats (ground + 2 facades, 120 m x 12 m), "
          f"robot forward camera 0.5 m high, 90 deg fov, {w}x{h}; cache build {time.perf_counter() - t0:.1f} s")
    poses = [dict(x=x, yaw_deg=yaw) for x in (-40.0, -10.0, 20.0) for yaw in (0.0, 15.0)]
    cams = [robot_camera(w, h, **p) for p in poses]
    for label, st in (("SH deg 0, no cov cull", RasterSettings(w, h, active_sh_degree=0)),
                      ("SH deg 3, no cov cull", RasterSettings(w, h, active_sh_degree=3)),
                      ("SH deg 0, cov cull 0.01", RasterSettings(w, h, active_sh_degree=0,
                                                                  cov_cull_alpha=0.01))):
        def run():
            for c in cams:
                scene.render(c, st)
        numba.set_num_threads(1)
        w1, c1 = timeit(run)
        numba.set_num_threads(ALL)
        wa, _ = timeit(run)
        k = len(cams)
        vis = sum(int((scene.render(c, st).raw.radii > 0).sum()) for c in cams) // k
        print(f"  {label:<24} 1 thread {k / w1:7.1f} fps (cpu-time {k / c1:7.1f} fps/core)   "
              f"{ALL} threads {k / wa:7.1f} fps   ~{vis} splats projected+visible")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="smaller sizes (smoke run)")
    args = ap.parse_args()
    print(f"# splat engine benchmark\ncommand: {' '.join([sys.executable] + sys.argv)}")
    print(f"hardware: {cpu_model()}, {os.cpu_count()} logical cores; numba {numba.__version__} "
          f"threads={ALL} layer={numba.config.THREADING_LAYER}; torch {torch.__version__} "
          f"threads={torch.get_num_threads()}")
    print(f"load average at start: {os.getloadavg()}")
    sizes = (10_000, 100_000) if args.quick else (10_000, 100_000, 500_000)
    forward_table(sizes, ((128, 72), (640, 360)))
    backward_table(100_000, (320, 180))
    ratio_table(20_000, (160, 90))
    static_table(200_000, (128, 72))
    print(f"\nload average at end: {os.getloadavg()}")
    print("targets: static 128x72 >= 300 fps per core; fwd+bwd 320x180 100k <= 150 ms on 2 cores;"
          " cpu >= 20x torch")


if __name__ == "__main__":
    main()
