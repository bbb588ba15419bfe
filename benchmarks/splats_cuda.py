"""Splat engine benchmark, GPU half: the gsplat `cuda` backend's speed and its agreement with the spec.

Run: python benchmarks/splats_cuda.py [--quick]   (needs CUDA and gsplat==1.5.3: pip install -e '.[cuda]')
Prints measured figures only (no assertions); without CUDA or gsplat it records a skip and exits.
The first call JIT-compiles gsplat's kernels (minutes); that call is timed on its own row.
Timings synchronise the GPU around each call (wall ms per call, median of repeats, after warm-up).
The CPU half, with the fwd+bwd and env-frame targets, is benchmarks/splats.py.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from common import Run, add_run_args  # benchmarks/common.py
from vid2sim.splats.cpu.synthetic import front_camera, random_blob_scene, robot_camera, street_scene
from vid2sim.splats.reference import rasterize as ref_rasterize
from vid2sim.splats.types import RasterSettings


def cuda_ms(fn, reps: int = 20, min_time: float = 0.3) -> float:
    """Median wall ms of fn() with the GPU synchronised around each call (after 2 warm-ups)."""
    for _ in range(2):
        fn()
    torch.cuda.synchronize()
    times, t_end = [], time.perf_counter() + min_time
    while len(times) < reps or time.perf_counter() < t_end:
        t0 = time.perf_counter()
        fn()
        torch.cuda.synchronize()
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3


def gpu_params(model, grad: bool) -> list[torch.Tensor]:
    """[means [N,3], quats [N,4], log_scales [N,3], opacity_logits [N], sh [N,16,3]] on the GPU."""
    ps = (model.means, model.quats, model.log_scales, model.opacity_logits, model.sh)
    return [p.detach().to("cuda", torch.float32).requires_grad_(grad) for p in ps]


def fwd_bwd(rasterize, ps, cam, st) -> None:
    """One training-style step, as in benchmarks/splats.py: forward, loss on rgb/depth/alpha, backward."""
    for p in ps:
        p.grad = None
    out = rasterize(*ps, cam, st, absgrad=True)
    loss = out.color_accum.square().mean() + out.depth_accum.mean() + out.alpha.mean()
    loss.backward()


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    mse = float(((a - b) ** 2).mean())
    return float("inf") if mse == 0 else 10.0 * torch.log10(torch.tensor(1.0 / mse)).item()


def first_call(run: Run, rasterize) -> None:
    """Time the first gsplat call of the process (JIT build, or loading a cached build)."""
    ps = gpu_params(random_blob_scene(1000, seed=0), grad=True)
    w, h = 64, 36
    t0 = time.perf_counter()
    fwd_bwd(rasterize, ps, front_camera(w, h), RasterSettings(w, h))
    torch.cuda.synchronize()
    s = run.record("first call (gsplat JIT build or cached load)", "wall_s", time.perf_counter() - t0, "s")
    print(f"first gsplat call (JIT build or cached load): {s:.1f} s")


def agreement(run: Run, rasterize, n: int, res: tuple[int, int]) -> None:
    """cuda vs the torch reference (run on the GPU too): PSNR of rgb, max |alpha| difference."""
    w, h = res
    cam, st = front_camera(w, h), RasterSettings(w, h)
    ps = gpu_params(random_blob_scene(n, seed=5), grad=False)
    with torch.no_grad():
        ref, gpu = ref_rasterize(*ps, cam, st), rasterize(*ps, cam, st)
    q = psnr(ref.color_accum.clamp(0, 1), gpu.color_accum.clamp(0, 1))
    da = float((ref.alpha - gpu.alpha).abs().max())
    run.record_all(f"cuda vs torch reference {n} splats {w}x{h}", {"rgb_psnr_db": q, "alpha_max_abs_diff": da},
                   {"rgb_psnr_db": "dB", "alpha_max_abs_diff": ""}, {"scene": "random blobs", "sh_degree": 3})
    print(f"  cuda vs reference, {n} splats {w}x{h}: rgb PSNR {q:.1f} dB, max |alpha diff| {da:.4f}")


def raster_table(run: Run, rasterize, cases) -> None:
    print("\n## rasterize: forward, forward+backward (absgrad on), random scene, SH degree 3")
    for n, (w, h) in cases:
        cam, st = front_camera(w, h), RasterSettings(w, h)
        ps = gpu_params(random_blob_scene(n, seed=2), grad=True)
        with torch.no_grad():
            fw = cuda_ms(lambda: rasterize(*ps, cam, st))
        fb = cuda_ms(lambda: fwd_bwd(rasterize, ps, cam, st))
        run.record_all(f"cuda {n} splats {w}x{h}", {"forward_ms": fw, "forward_backward_ms": fb}, "ms",
                       {"scene": "random blobs", "sh_degree": 3})
        print(f"  {n:>7} splats {w:>4}x{h:<4} forward {fw:7.2f} ms   forward+backward {fb:7.2f} ms")


def batch_table(run: Run, render_batch, n: int, res: tuple[int, int], counts) -> None:
    """Env frames: C robot cameras on one street scene in one gsplat call (SH degree 0, as the env)."""
    w, h = res
    model = street_scene(n, seed=4).to("cuda", torch.float32)
    st = RasterSettings(w, h, active_sh_degree=0)
    print(f"\n## env frames (render_batch), street scene {n} splats, {w}x{h}, SH0")
    for c in counts:
        cams = [robot_camera(w, h, x=-50.0 + 100.0 * i / max(c - 1, 1), yaw_deg=(i % 7) * 5.0) for i in range(c)]
        ms = cuda_ms(lambda: render_batch([model], cams, [0] * c, st), reps=10)
        fps = run.record(f"env frames street {n} splats {w}x{h}, {c} cameras", "frames_per_s",
                         c * 1e3 / ms, "frames/s", {"sh_degree": 0})
        print(f"  {c:>4} cameras per call: {ms:8.2f} ms per call, {fps:9.0f} frames/s")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="smaller sizes (smoke run)")
    add_run_args(ap)
    args = ap.parse_args()
    with Run("splats_cuda", args) as run:
        if not torch.cuda.is_available():
            run.skip("all", "CUDA is not available")
            return
        try:
            from vid2sim.splats.cuda import rasterize, render_batch, require_gsplat
            gsplat = require_gsplat()
        except ImportError as exc:
            run.skip("all", str(exc))
            return
        run.config.update(gpu=torch.cuda.get_device_name(), gsplat=gsplat.__version__, torch=torch.__version__,
                          cuda=torch.version.cuda)
        print(f"GPU {torch.cuda.get_device_name()}, torch {torch.__version__} (CUDA {torch.version.cuda}), "
              f"gsplat {gsplat.__version__}")
        first_call(run, rasterize)
        agreement(run, rasterize, 2_000 if args.quick else 20_000, (160, 90))
        cases = [(100_000, (320, 180))] if args.quick else [
            (100_000, (320, 180)), (500_000, (960, 540)), (1_000_000, (1280, 720))]
        raster_table(run, rasterize, cases)
        batch_table(run, render_batch, 200_000, (128, 72), (1, 16) if args.quick else (1, 16, 64, 256))


if __name__ == "__main__":
    main()
