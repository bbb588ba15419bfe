"""The `cpu` backend against the torch reference: every output and every gradient.

Tolerances (float32 both sides; the kernels use float64 for per-splat projection and
float32 for compositing, the reference float32 throughout):
- images: |cpu - torch| <= 2e-4 + 2e-4 |torch| on >= 99.8% of pixel values, and <= 0.05
  everywhere (a pixel may legitimately flip across a threshold: alpha >= 1/255, sigma <= 4.5,
  T >= 1e-4, T <= 0.5 for the median, under float32 rounding);
- means2d: 1e-3 px (+1e-5 relative); radii equal on >= 99% of splats and never off by > 1;
- gradients (means, quats, log_scales, opacity_logits, sh, grad2d, absgrad):
  ||g_cpu - g_torch|| <= 2e-3 ||g_torch|| per tensor, and per element
  |diff| <= 1e-2 max|g_torch| on all but 0.5% of the elements.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest
import torch

from vid2sim.splats.camera import Camera, look_at
from vid2sim.splats.cpu import rasterize as cpu_rasterize
from vid2sim.splats.reference import rasterize as ref_rasterize
from vid2sim.splats.types import RasterSettings

IMAGES = ("color_accum", "alpha", "depth_accum", "normal_accum", "median_depth")
PARAMS = ("means", "quats", "log_scales", "opacity_logits", "sh")


def random_scene(seed: int, n: int = 240, sh_degree: int = 3) -> dict[str, torch.Tensor]:
    """Splats around a camera at the origin looking down +z, with the awkward cases mixed in:
    behind the camera, straddling the near plane, partly off-screen, tiny and huge."""
    g = torch.Generator().manual_seed(seed)
    k = n // 6
    means = torch.randn(n, 3, generator=g) * torch.tensor([1.2, 0.9, 1.5]) + torch.tensor([0, 0, 4.0])
    means[:k, 2] = -torch.rand(k, generator=g) * 3  # behind the camera
    means[k:k + 8, 2] = torch.rand(8, generator=g) * 0.02  # at the near plane
    means[2 * k:3 * k, 0] += torch.sign(torch.randn(k, generator=g)) * 3.5  # off-screen sides
    log_scales = torch.randn(n, 3, generator=g) * 0.6 - 2.2
    log_scales[3 * k:3 * k + k // 2] = -7.0 + torch.randn(k // 2, 3, generator=g)  # tiny
    log_scales[4 * k:4 * k + 6] = 0.5 + torch.rand(6, 3, generator=g)  # huge
    means[4 * k:4 * k + 6, 2] = 1.0 + torch.rand(6, generator=g)
    quats = torch.randn(n, 4, generator=g)
    opacity_logits = torch.randn(n, generator=g) * 1.5 + 0.5
    sh = torch.randn(n, (sh_degree + 1) ** 2, 3, generator=g) * 0.4
    return dict(means=means, quats=quats, log_scales=log_scales,
                opacity_logits=opacity_logits, sh=sh)


def random_camera(seed: int, width: int = 48, height: int = 32) -> Camera:
    """A camera near the origin looking roughly down +z, with an off-centre principal point."""
    rng = np.random.default_rng(seed)
    eye = rng.normal(0, 0.3, 3)
    target = np.array([0.0, 0.0, 4.0]) + rng.normal(0, 0.5, 3)
    f = width * rng.uniform(0.7, 1.3)
    return Camera(f, f * rng.uniform(0.9, 1.1), width * rng.uniform(0.4, 0.6),
                  height * rng.uniform(0.4, 0.6), width, height,
                  look_at(eye, target, up=(0.0, -1.0, 0.0)))


def run(fn, scene, camera, settings, weights):
    params = {k: v.clone().requires_grad_(True) for k, v in scene.items()}
    out = fn(*(params[k] for k in PARAMS), camera, settings, absgrad=True)
    loss = sum((w * getattr(out, k)).sum() for k, w in weights.items())
    loss.backward()
    return out, {k: params[k].grad for k in PARAMS}


def loss_weights(seed: int, h: int, w: int) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    shapes = dict(color_accum=(h, w, 3), alpha=(h, w), depth_accum=(h, w),
                  normal_accum=(h, w, 3), median_depth=(h, w))
    return {k: torch.randn(s, generator=g) for k, s in shapes.items()}


def assert_image_close(a: torch.Tensor, b: torch.Tensor, name: str) -> None:
    err = (a - b).abs()
    bad = err > 2e-4 + 2e-4 * b.abs()
    assert bad.float().mean() <= 2e-3, f"{name}: {int(bad.sum())}/{bad.numel()} values off, max {err.max():.3g}"
    assert err.max() <= 0.05, f"{name}: max error {err.max():.3g}"


def assert_grad_close(a: torch.Tensor, b: torch.Tensor, name: str) -> None:
    scale = b.abs().max().clamp_min(1e-12)
    rel = (a - b).norm() / b.norm().clamp_min(1e-12)
    assert rel <= 2e-3, f"{name}: relative error {rel:.3g}"
    bad = (a - b).abs() > 1e-2 * scale
    assert bad.float().mean() <= 5e-3, f"{name}: {int(bad.sum())} elements off"


CASES = [  # (scene seed, camera seed, cov_cull_alpha, active degree, image size, model degree)
    (0, 0, None, 3, (48, 32), 3),
    (1, 1, None, 1, (40, 40), 3),
    (2, 2, 0.02, 3, (48, 32), 3),
    (3, 3, None, 0, (33, 21), 3),
    (4, 4, 0.005, 2, (48, 32), 3),
    (5, 5, None, 3, (48, 32), 2),  # fewer SH rows than the active degree asks for
    (6, 6, None, 1, (48, 32), 1),
]


@pytest.mark.parametrize("scene_seed,cam_seed,cov_alpha,degree,size,model_degree", CASES)
def test_cpu_matches_reference(scene_seed, cam_seed, cov_alpha, degree, size, model_degree):
    w, h = size
    scene = random_scene(scene_seed, sh_degree=model_degree)
    camera = random_camera(cam_seed, w, h)
    settings = RasterSettings(w, h, cov_cull_alpha=cov_alpha, active_sh_degree=degree)
    weights = loss_weights(scene_seed + 100, h, w)
    out_c, grads_c = run(cpu_rasterize, scene, camera, settings, weights)
    out_r, grads_r = run(ref_rasterize, scene, camera, settings, weights)

    assert (out_r.alpha > 0.5).float().mean() > 0.1, "scene should cover the image"
    for k in IMAGES:
        assert_image_close(getattr(out_c, k), getattr(out_r, k), k)
    vis = out_r.radii > 0
    assert 20 < int(vis.sum()) < scene["means"].shape[0], "scene should mix culled and visible"
    torch.testing.assert_close(out_c.means2d, out_r.means2d, atol=1e-3, rtol=1e-5)
    diff = (out_c.radii - out_r.radii).abs()
    assert int(diff.max()) <= 1 and (diff > 0).float().mean() <= 0.01
    assert ((out_c.radii > 0) == vis).all()
    for k in PARAMS:
        assert_grad_close(grads_c[k], grads_r[k], k)
    assert_grad_close(out_c.grad2d, out_r.grad2d, "grad2d")
    assert_grad_close(out_c.absgrad, out_r.absgrad, "absgrad")
    assert (out_c.absgrad + 1e-6 >= out_c.grad2d.abs()).all()
    assert (out_c.grad2d[~vis] == 0).all()
    if degree < 3:
        assert (grads_c["sh"][:, (degree + 1) ** 2:] == 0).all()


def test_cov_culling_drops_big_splats():
    scene = random_scene(5)
    camera = random_camera(5)
    off = cpu_rasterize(*scene.values(), camera, RasterSettings(48, 32))
    on = cpu_rasterize(*scene.values(), camera, RasterSettings(48, 32, cov_cull_alpha=0.002))
    ref = ref_rasterize(*scene.values(), camera, RasterSettings(48, 32, cov_cull_alpha=0.002))
    assert int((on.radii > 0).sum()) < int((off.radii > 0).sum())
    assert torch.equal(on.radii > 0, ref.radii > 0)


def test_partial_grads_and_no_absgrad():
    """Only some outputs in the loss; absgrad=False leaves RasterOutput.absgrad None."""
    scene = {k: v.clone().requires_grad_(True) for k, v in random_scene(6).items()}
    camera = random_camera(6)
    out = cpu_rasterize(*(scene[k] for k in PARAMS), camera, RasterSettings(48, 32))
    assert out.absgrad is None and out.grad2d.shape == (scene["means"].shape[0], 2)
    out.alpha.sum().backward()
    assert scene["means"].grad.abs().sum() > 0
    assert scene["sh"].grad.abs().sum() == 0  # colour does not affect alpha
    first = out.grad2d.clone()
    out2 = cpu_rasterize(*(scene[k] for k in PARAMS), camera, RasterSettings(48, 32))
    (out2.alpha.sum() * 2).backward()
    torch.testing.assert_close(out2.grad2d, 2 * first)


def test_threads_do_not_change_results():
    scene = random_scene(7)
    camera = random_camera(7)
    settings = RasterSettings(48, 32)
    weights = loss_weights(7, 32, 48)
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        o1, g1 = run(cpu_rasterize, scene, camera, settings, weights)
    finally:
        numba.set_num_threads(before)
    o2, g2 = run(cpu_rasterize, scene, camera, settings, weights)
    for k in IMAGES:
        assert torch.equal(getattr(o1, k), getattr(o2, k))
    for k in PARAMS:  # per-instance gradient rows summed in a fixed order: bitwise equal
        assert torch.equal(g1[k], g2[k]), k


def test_tile_size_changes_no_image_and_gradients_by_rounding():
    """Tiles of 1, 5, 16 and the default 32 px (RasterSettings.tile_size None) blend every
    pixel's splats in the same order: equal images; the backward sums per-tile gradients, so
    they differ by float rounding only. Tiles above MAX_TILE are capped to it."""
    from vid2sim.splats.cpu.composite import CPU_TILE, MAX_TILE, kernel_tile

    assert kernel_tile(None) == CPU_TILE and kernel_tile(10 * MAX_TILE) == MAX_TILE
    scene, camera, weights = random_scene(8), random_camera(8, 70, 45), loss_weights(8, 45, 70)
    o0, g0 = run(cpu_rasterize, scene, camera, RasterSettings(70, 45), weights)
    assert float(o0.alpha.max()) > 0.5
    for tile in (1, 5, 16, 4 * MAX_TILE):
        o, g = run(cpu_rasterize, scene, camera, RasterSettings(70, 45, tile_size=tile), weights)
        for k in IMAGES:
            assert torch.equal(getattr(o, k), getattr(o0, k)), (tile, k)
        for k in PARAMS:
            assert_grad_close(g[k], g0[k], f"{k} at {tile} px tiles")


def test_median_depth_off_changes_nothing_else():
    """RasterSettings.median_depth False: the cpu backend leaves median_depth 0 and every other
    image and gradient as with it (a loss that does not read the median)."""
    scene, camera = random_scene(9), random_camera(9)
    weights = {k: w for k, w in loss_weights(9, 32, 48).items() if k != "median_depth"}
    o1, g1 = run(cpu_rasterize, scene, camera, RasterSettings(48, 32), weights)
    o2, g2 = run(cpu_rasterize, scene, camera, RasterSettings(48, 32, median_depth=False), weights)
    assert float(o1.median_depth.abs().max()) > 0.1 and not o2.median_depth.any()
    for k in IMAGES:
        if k != "median_depth":
            assert torch.equal(getattr(o1, k), getattr(o2, k)), k
    for k in PARAMS:
        assert torch.equal(g1[k], g2[k]), k


def test_parallel_binning_equals_serial():
    """Blocked parallel sort/bin (many blocks, many depth ties) == the one-thread version."""
    from vid2sim.splats.cpu.binning import BLOCK, sort_and_bin
    rng = np.random.default_rng(0)
    n = 6 * BLOCK + 123
    fo = np.zeros((n, 16), np.float32)
    fo[:, 7] = rng.integers(0, 50, n)  # depth column F_Z, with ties
    x0, y0 = rng.integers(0, 300, n), rng.integers(0, 170, n)
    box = np.stack([x0, y0, np.minimum(x0 + rng.integers(-3, 40, n), 319),
                    np.minimum(y0 + rng.integers(0, 30, n), 179)], 1).astype(np.int32)
    serial = sort_and_bin(fo, box, n, 16, 20, 240, True, 1)
    parallel = sort_and_bin(fo, box, n, 16, 20, 240, True, 3)
    for a, b in zip(serial, parallel):
        np.testing.assert_array_equal(a, b)
    offsets, inst = serial[0], serial[1]
    t = 37  # a tile's slice is depth-sorted, ties by row
    sl = inst[offsets[t]:offsets[t + 1]]
    key = fo[sl, 7].astype(np.float64) * n + sl
    assert len(sl) > 0 and np.all(np.diff(key) > 0)


def test_empty_and_bad_inputs():
    camera = random_camera(0)
    empty = {k: v[:0] for k, v in random_scene(0).items()}
    out = cpu_rasterize(*empty.values(), camera, RasterSettings(48, 32))
    assert out.color_accum.shape == (32, 48, 3) and float(out.alpha.abs().sum()) == 0.0
    assert out.means2d.shape == (0, 2)
    with pytest.raises(ValueError, match="differs from camera size"):
        cpu_rasterize(*random_scene(0).values(), camera, RasterSettings(50, 32))
    scene = random_scene(0)
    with pytest.raises(ValueError, match="quats"):
        cpu_rasterize(scene["means"], scene["quats"][:, :3], scene["log_scales"],
                      scene["opacity_logits"], scene["sh"], camera, RasterSettings(48, 32))
