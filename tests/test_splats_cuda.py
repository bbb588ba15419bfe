"""gsplat (`cuda`) backend against the torch reference on a small scene; needs CUDA + gsplat."""

from __future__ import annotations

import time

import pytest
import torch

from vid2sim.splats import Camera, RasterSettings
from vid2sim.splats.camera import look_at
from vid2sim.splats.reference import rasterize as ref_rasterize

pytestmark = pytest.mark.gpu

if not torch.cuda.is_available():
    pytest.skip("CUDA is not available", allow_module_level=True)
gsplat = pytest.importorskip("gsplat")

from vid2sim.splats import GaussianModel  # noqa: E402
from vid2sim.splats.cpu import StaticScene  # noqa: E402
from vid2sim.splats.cpu.env_batch import SceneBatch  # noqa: E402
from vid2sim.splats.cuda import rasterize as cuda_rasterize  # noqa: E402
from vid2sim.splats.cuda import render_batch  # noqa: E402


def scene(n: int = 200, seed: int = 0):
    """Opacities <= 0.3: then alpha < 1/255 beyond 3 sigma, where gsplat and the spec agree."""
    g = torch.Generator().manual_seed(seed)
    means = torch.randn(n, 3, generator=g) * torch.tensor([1.5, 1.0, 1.0]) + torch.tensor([0, 0, 5.0])
    quats = torch.randn(n, 4, generator=g)
    log_scales = torch.rand(n, 3, generator=g) * 1.5 - 3.0
    opac = torch.logit(torch.rand(n, generator=g) * 0.25 + 0.05)
    sh = torch.randn(n, 16, 3, generator=g) * 0.2
    means[:5, 2] = -2.0  # some behind the camera
    return [means, quats, log_scales, opac, sh]


def test_cuda_matches_reference_outputs_and_gradients():
    W, H = 64, 48
    cam = Camera(60.0, 60.0, 31.7, 24.2, W, H, look_at([0, 0, 0], [0, 0, 1], up=[0, -1, 0]))
    settings = RasterSettings(W, H)
    outs, grads = [], []
    for fn in (ref_rasterize, cuda_rasterize):
        params = [p.clone().requires_grad_() for p in scene()]
        o = fn(*params, cam, settings, absgrad=True)
        g = torch.Generator().manual_seed(7)
        loss = sum((x * torch.randn(x.shape, generator=g)).sum() for x in
                   (o.color_accum, o.alpha, o.depth_accum, o.normal_accum, o.median_depth))
        loss.backward()
        outs.append(o)
        grads.append([p.grad for p in params])
    ref, gpu = outs
    for name in ("color_accum", "alpha", "depth_accum", "normal_accum", "median_depth"):
        a, b = getattr(ref, name), getattr(gpu, name)
        assert torch.allclose(a, b, atol=2e-4, rtol=1e-3), (name, (a - b).abs().max())
    assert torch.equal(ref.radii > 0, gpu.radii > 0)
    assert torch.allclose(ref.grad2d, gpu.grad2d, atol=1e-3, rtol=1e-2)
    assert torch.allclose(ref.absgrad, gpu.absgrad, atol=1e-3, rtol=1e-2)
    for name, a, b in zip(("means", "quats", "log_scales", "opacity_logits", "sh"), *grads):
        scale = a.abs().max().clamp_min(1e-6)
        assert ((a - b).abs().max() / scale) < 1e-2, name


def test_cuda_speed_is_reported():
    W, H = 320, 180
    params = [p.cuda() for p in scene(100_000, seed=1)]
    cam = Camera(200.0, 200.0, W / 2, H / 2, W, H, torch.eye(4))
    settings = RasterSettings(W, H)
    cuda_rasterize(*params, cam, settings)
    torch.cuda.synchronize()
    t0 = time.perf_counter()
    for _ in range(10):
        o = cuda_rasterize(*params, cam, settings)
    torch.cuda.synchronize()
    dt = (time.perf_counter() - t0) / 10
    print(f"cuda forward 100k Gaussians 320x180: {dt * 1e3:.2f} ms")
    assert o.alpha.max() > 0


def test_cuda_render_batch_equals_cpu_batch():
    """gsplat batched env frames agree with the CPU SceneBatch (same scenes and cameras)."""
    models = [GaussianModel(*scene(300, seed=s)) for s in (0, 1)]
    cams = [Camera(60.0, 60.0, 32.0, 18.0, 64, 36, look_at((dx, 0.0, 0.0), (dx, 0.0, 5.0), (0, -1, 0)))
            for dx in (-0.5, 0.0, 0.5)]
    ids = [0, 1, 0]
    st = RasterSettings(64, 36, active_sh_degree=3)
    gpu = render_batch(models, cams, ids, st, background=(0.2, 0.3, 0.4))
    cpu = SceneBatch([StaticScene(m) for m in models]).render(cams, ids, settings=st,
                                                              background=(0.2, 0.3, 0.4))
    torch.testing.assert_close(gpu["rgb"].cpu(), cpu.rgb, atol=2e-3, rtol=0)
    torch.testing.assert_close(gpu["alpha"].cpu(), cpu.alpha, atol=2e-3, rtol=0)
