"""The torch reference rasteriser against analytic cases, finite differences and gradcheck."""

from __future__ import annotations

import math

import pytest
import torch

from vid2sim.splats import Camera, GaussianModel, RasterSettings, render
from vid2sim.splats.reference import rasterize
from vid2sim.splats.render import get_backend
from vid2sim.splats.sh import rgb_to_sh0

D = torch.float64


def logit(p: float) -> float:
    return math.log(p / (1 - p))


def make_model(means, rgbs, opacities, log_scales=None, quats=None, degree=0) -> GaussianModel:
    n = len(means)
    sh = torch.zeros(n, (degree + 1) ** 2, 3, dtype=D)
    sh[:, 0] = rgb_to_sh0(torch.tensor(rgbs, dtype=D))
    q = torch.tensor(quats, dtype=D) if quats is not None else torch.tensor([[1.0, 0, 0, 0]] * n, dtype=D)
    ls = torch.tensor(log_scales, dtype=D) if log_scales is not None else torch.full((n, 3), -1.0, dtype=D)
    return GaussianModel(torch.tensor(means, dtype=D), q, ls,
                         torch.tensor([logit(o) for o in opacities], dtype=D), sh)


def axis_camera(size: int = 21, f: float = 20.0) -> Camera:
    """Camera at the origin looking along +z; the optical axis hits the centre pixel."""
    return Camera(f, f, size / 2, size / 2, size, size, torch.eye(4, dtype=D))


def test_single_gaussian_centre_pixel():
    cam = axis_camera()
    m = make_model([[0, 0, 5.0]], [[0.2, 0.6, 0.9]], [0.7], log_scales=[[-1, -1, -4.0]])
    out = render(m, cam, backend="torch")
    c = 10  # centre pixel (10, 10) has its centre at (10.5, 10.5) = (cx, cy)
    assert out.alpha[c, c].item() == pytest.approx(0.7, abs=1e-12)
    assert out.rgb[c, c].tolist() == pytest.approx([0.7 * 0.2, 0.7 * 0.6, 0.7 * 0.9], abs=1e-12)
    assert out.depth[c, c].item() == pytest.approx(5.0, abs=1e-12)
    assert out.median_depth[c, c].item() == pytest.approx(5.0, abs=1e-12)
    # smallest axis is world z = camera z, pointing away -> flipped towards the camera
    assert out.normal[c, c].tolist() == pytest.approx([0.0, 0.0, -1.0], abs=1e-12)
    assert out.raw.means2d[0].tolist() == pytest.approx([10.5, 10.5])
    # falls off away from the centre, and symmetrically
    assert out.alpha[c, c + 1] < out.alpha[c, c]
    assert out.alpha[c, c + 1].item() == pytest.approx(out.alpha[c, c - 1].item(), abs=1e-12)
    assert out.alpha[0, 0].item() == 0.0


def test_normal_uses_smallest_axis_of_rotated_gaussian():
    cam = axis_camera()
    # 90 deg about x: local z -> world -y; smallest scale on local z
    h = math.sqrt(0.5)
    m = make_model([[0, 0, 5.0]], [[1, 1, 1]], [0.9], log_scales=[[-1, -1, -4.0]],
                   quats=[[h, h, 0, 0]])
    n = render(m, cam, backend="torch").normal[10, 10]
    assert n.tolist() == pytest.approx([0.0, -1.0, 0.0], abs=1e-9) or \
        n.tolist() == pytest.approx([0.0, 1.0, 0.0], abs=1e-9)
    # below the axis (y > 0 in camera) the splat centre is at y>0: pick a splat off-axis
    m.means = torch.tensor([[0, 1.0, 5.0]], dtype=D)
    out = render(m, cam, backend="torch")
    n = out.normal[out.alpha.argmax() // 21, out.alpha.argmax() % 21]
    assert n[1].item() < -0.99  # faces the camera: dot(n, t) < 0 with t_y > 0


def test_gaussian_behind_camera_and_offscreen_contribute_nothing():
    cam = axis_camera()
    front = make_model([[0, 0, 5.0]], [[1, 0, 0]], [0.5])
    extra = make_model([[0, 0, -5.0], [50.0, 0, 5.0], [0, 0, 0.001]],
                       [[0, 1, 0]] * 3, [0.9] * 3, log_scales=[[0.0] * 3] * 3)
    both = GaussianModel.cat([front, extra])
    a, b = render(front, cam, backend="torch"), render(both, cam, backend="torch")
    assert torch.equal(a.rgb, b.rgb) and torch.equal(a.alpha, b.alpha)
    assert b.raw.radii.tolist()[1:] == [0, 0, 0] and b.raw.radii[0] > 0
    assert torch.all(b.raw.means2d[1:] == 0)


def test_covariance_culling_removes_huge_splat():
    cam = axis_camera()
    m = make_model([[0, 0, 5.0]], [[1, 1, 1]], [0.9], log_scales=[[1.0, 1.0, 1.0]])
    on = render(m, cam, RasterSettings(21, 21, cov_cull_alpha=0.1), backend="torch")
    off = render(m, cam, RasterSettings(21, 21), backend="torch")
    assert off.alpha.max() > 0.5 and off.raw.radii[0] > 0
    assert on.alpha.max() == 0 and on.raw.radii[0] == 0
    # a small splat survives the same threshold
    small = make_model([[0, 0, 5.0]], [[1, 1, 1]], [0.9], log_scales=[[-2.0] * 3])
    assert render(small, cam, RasterSettings(21, 21, cov_cull_alpha=0.1), backend="torch").alpha.max() > 0.5


def test_near_far_culling():
    cam = axis_camera()
    m = make_model([[0, 0, 5.0]], [[1, 1, 1]], [0.9])
    assert render(m, cam, RasterSettings(21, 21, far=4.0), backend="torch").alpha.max() == 0
    assert render(m, cam, RasterSettings(21, 21, near=6.0), backend="torch").alpha.max() == 0
    assert render(m, cam, RasterSettings(21, 21, near=4.0, far=6.0), backend="torch").alpha.max() > 0


def test_occlusion_follows_depth_not_index_order():
    cam = axis_camera()
    red_front = make_model([[0, 0, 4.0], [0, 0, 2.0]], [[0, 0, 1], [1, 0, 0]], [0.95, 0.95])
    blue_front = make_model([[0, 0, 2.0], [0, 0, 4.0]], [[0, 0, 1], [1, 0, 0]], [0.95, 0.95])
    r, b = render(red_front, cam, backend="torch"), render(blue_front, cam, backend="torch")
    assert r.rgb[10, 10, 0] > 0.9 and r.rgb[10, 10, 2] < 0.1
    assert b.rgb[10, 10, 2] > 0.9 and b.rgb[10, 10, 0] < 0.1
    assert r.median_depth[10, 10].item() == pytest.approx(2.0)


def test_median_and_expected_depth_two_layers():
    cam = axis_camera()
    m = make_model([[0, 0, 2.0], [0, 0, 3.0]], [[1, 1, 1]] * 2, [0.4, 0.4],
                   log_scales=[[0.0, 0.0, -3]] * 2)
    out = render(m, cam, backend="torch")
    a2 = 0.4 * 0.6
    assert out.alpha[10, 10].item() == pytest.approx(1 - 0.36, abs=1e-12)
    assert out.depth[10, 10].item() == pytest.approx((0.4 * 2 + a2 * 3) / 0.64, abs=1e-12)
    assert out.median_depth[10, 10].item() == pytest.approx(3.0)  # T: 0.6 -> 0.36


def test_early_termination_excludes_the_splat_that_crosses():
    cam = axis_camera()
    m = make_model([[0, 0, 2.0], [0, 0, 3.0], [0, 0, 4.0], [0, 0, 5.0]],
                   [[1, 0, 0]] * 3 + [[0, 1, 0]], [0.95] * 4, log_scales=[[0.5, 0.5, -3]] * 4)
    out = render(m, cam, backend="torch")
    # T after 3 splats = 0.05^3 = 1.25e-4; the 4th would give 6.25e-6 < 1e-4 -> dropped
    assert out.alpha[10, 10].item() == pytest.approx(1 - 0.05 ** 3, abs=1e-12)
    assert out.rgb[10, 10, 1].item() == 0.0
    # opacity 0.99 is clamped: alpha never exceeds 0.99 for one splat
    one = make_model([[0, 0, 2.0]], [[1, 1, 1]], [0.999])
    assert render(one, cam, backend="torch").alpha.max().item() == pytest.approx(0.99)


def test_background_and_derived_outputs():
    cam = axis_camera()
    m = make_model([[0, 0, 5.0]], [[1, 0, 0]], [0.5])
    out = render(m, cam, background=(0.1, 0.2, 0.3), backend="torch")
    assert out.rgb[0, 0].tolist() == pytest.approx([0.1, 0.2, 0.3])
    assert out.depth[0, 0] == 0 and torch.all(out.normal[0, 0] == 0)
    assert out.rgb[10, 10].tolist() == pytest.approx([0.5 + 0.05, 0.1, 0.15])


def _scene(seed: int = 0, n: int = 3, degree: int = 1):
    g = torch.Generator().manual_seed(seed)
    means = torch.stack([torch.rand(n, generator=g) * 1.0 - 0.5,
                         torch.rand(n, generator=g) * 0.8 - 0.4,
                         2.0 + torch.rand(n, generator=g) * 2], dim=1).to(D)
    quats = torch.randn(n, 4, generator=g).to(D)
    log_scales = (torch.rand(n, 3, generator=g) * 0.6 - 1.6).to(D)
    opac = (torch.rand(n, generator=g) * 2 - 0.5).to(D)
    sh = (torch.randn(n, (degree + 1) ** 2, 3, generator=g) * 0.3).to(D)
    return [means, quats, log_scales, opac, sh]


def test_gradcheck_tiny_scene_float64():
    W, H = 6, 5
    cam = Camera(5.0, 5.0, 3.1, 2.4, W, H, torch.eye(4, dtype=D))
    settings = RasterSettings(W, H)
    params = _scene()
    params[2] = params[2] + 0.7  # larger splats cover most of the 6x5 image
    params = [p.requires_grad_() for p in params]

    def f(*ps):
        o = rasterize(*ps, cam, settings)
        return o.color_accum, o.alpha, o.depth_accum, o.normal_accum, o.median_depth

    outs = f(*params)
    assert (outs[1] > 0.05).float().mean() > 0.6  # most pixels covered: compositing is exercised
    assert (outs[4] > 0).any()  # median depth reached somewhere
    assert torch.autograd.gradcheck(f, params, eps=1e-6, atol=1e-6, rtol=1e-4,
                                    nondet_tol=1e-12)


def _loss(out, weights):
    return sum((o * w).sum() for o, w in zip(
        (out.color_accum, out.alpha, out.depth_accum, out.normal_accum), weights))


def test_grad2d_and_absgrad_match_finite_differences():
    """For one splat, moving cx moves mean2d_x one-for-one (the clamp is inactive)."""
    W, H = 9, 7
    params = _scene(seed=3, n=1)
    params[0] = torch.tensor([[0.1, -0.05, 3.0]], dtype=D)
    g = torch.Generator().manual_seed(1)
    weights = [torch.randn(H, W, 3, generator=g, dtype=D), torch.randn(H, W, generator=g, dtype=D),
               torch.randn(H, W, generator=g, dtype=D), torch.randn(H, W, 3, generator=g, dtype=D)]
    cam = lambda cx, cy: Camera(6.0, 6.0, cx, cy, W, H, torch.eye(4, dtype=D))  # noqa: E731
    settings = RasterSettings(W, H)
    leaves = [p.clone().requires_grad_() for p in params]
    out = rasterize(*leaves, cam(4.3, 3.6), settings, absgrad=True)
    _loss(out, weights).backward()

    h = 1e-6
    per_pixel = []
    for dx, dy in ((h, 0), (0, h)):
        hi = rasterize(*params, cam(4.3 + dx, 3.6 + dy), settings)
        lo = rasterize(*params, cam(4.3 - dx, 3.6 - dy), settings)
        # per-pixel loss derivative: sum over channels of w * d(out)/d(shift)
        d = sum(((a - b) * w).reshape(H, W, -1).sum(-1) for a, b, w in zip(
            (hi.color_accum, hi.alpha, hi.depth_accum, hi.normal_accum),
            (lo.color_accum, lo.alpha, lo.depth_accum, lo.normal_accum), weights)) / (2 * h)
        per_pixel.append(d)
    grad2d_fd = torch.stack([p.sum() for p in per_pixel])
    absgrad_fd = torch.stack([p.abs().sum() for p in per_pixel])
    assert torch.allclose(out.grad2d[0], grad2d_fd, rtol=1e-5, atol=1e-7)
    assert torch.allclose(out.absgrad[0], absgrad_fd, rtol=1e-5, atol=1e-7)
    assert (out.absgrad[0] > out.grad2d[0].abs() + 1e-6).all()  # signs differ across pixels


def test_absgrad_off_by_default_and_culled_splats_zero():
    params = [p.requires_grad_() for p in _scene(seed=2, n=4)]
    params[0].data[3] = torch.tensor([0.0, 0.0, -3.0], dtype=D)  # behind the camera
    cam = Camera(5.0, 5.0, 3.0, 2.5, 6, 5, torch.eye(4, dtype=D))
    out = rasterize(*params, cam, RasterSettings(6, 5))
    assert out.absgrad is None
    out.color_accum.sum().backward()
    assert out.grad2d[3].tolist() == [0.0, 0.0] and out.grad2d[:3].abs().sum() > 0
    assert params[0].grad[3].tolist() == [0.0, 0.0, 0.0]


def test_float32_matches_float64():
    params = _scene(seed=5, n=20, degree=3)
    cam = Camera(8.0, 8.0, 8.0, 6.0, 16, 12, torch.eye(4, dtype=D))
    s = RasterSettings(16, 12)
    a = rasterize(*params, cam, s)
    b = rasterize(*[p.float() for p in params], cam, s)
    assert b.color_accum.dtype == torch.float32
    assert torch.allclose(a.color_accum.float(), b.color_accum, atol=1e-4)
    assert torch.allclose(a.depth_accum.float(), b.depth_accum, atol=1e-4)


def test_backend_registry():
    assert get_backend("torch") is rasterize
    with pytest.raises(ValueError, match="unknown splat backend"):
        get_backend("opengl")
    if not torch.cuda.is_available():
        with pytest.raises(RuntimeError, match="CUDA"):
            get_backend("cuda")
    assert callable(get_backend("auto"))


def test_size_mismatch_is_an_error():
    m = make_model([[0, 0, 5.0]], [[1, 1, 1]], [0.5])
    with pytest.raises(ValueError, match="differs from camera"):
        render(m, axis_camera(), RasterSettings(10, 10), backend="torch")


def test_result_is_independent_of_tile_size():
    params = [p.requires_grad_() for p in _scene(seed=11, n=40, degree=2)]
    params[2].data += 0.3
    cam = Camera(9.0, 9.0, 10.2, 7.9, 21, 15, torch.eye(4, dtype=D))
    results = []
    for ts in (1, 5, 16, 1000):
        for p in params:
            p.grad = None
        o = rasterize(*params, cam, RasterSettings(21, 15, tile_size=ts), absgrad=True)
        (o.color_accum.sum() + o.median_depth.sum() + o.depth_accum.sum()).backward()
        results.append([o.color_accum, o.alpha, o.depth_accum, o.normal_accum, o.median_depth,
                        o.grad2d, o.absgrad] + [p.grad.clone() for p in params])
    assert results[0][1].max() > 0.5
    for other in results[1:]:
        for a, b in zip(results[0], other):
            assert torch.allclose(a, b, atol=1e-12, rtol=1e-10)


# ---- model and camera ------------------------------------------------------------

def test_from_points_scales_colours_and_opacity():
    xyz = [[0, 0, 0], [1, 0, 0], [0, 2, 0], [0, 0, 3], [10, 10, 10]]
    rgb = [[255, 0, 0], [0, 255, 0], [0, 0, 255], [128, 128, 128], [0, 0, 0]]
    import numpy as np
    m = GaussianModel.from_points(np.array(xyz), np.array(rgb, dtype=np.uint8), sh_degree=2)
    assert m.num == 5 and m.sh_degree == 2 and m.sh.shape == (5, 9, 3)
    assert torch.allclose(m.opacities, torch.full((5,), 0.1))
    assert torch.allclose(m.scales[0], torch.full((3,), 2.0))  # mean of 1, 2, 3
    from vid2sim.splats.sh import sh0_to_rgb
    assert torch.allclose(sh0_to_rgb(m.sh[:, 0]), torch.tensor(rgb, dtype=torch.float32) / 255)
    assert torch.all(m.sh[:, 1:] == 0)
    sub = GaussianModel.cat([m.index(m.means[:, 0] > 0.5), m.index(torch.tensor([0]))])
    assert sub.num == 3 and torch.equal(sub.means[-1], m.means[0])
    assert m.to(torch.float64).means.dtype == torch.float64
    m.requires_grad_()
    assert all(t.requires_grad for t in m.params().values())
    assert not any(t.requires_grad for t in m.detach().params().values())
    with pytest.raises(ValueError, match="rgb"):
        GaussianModel.from_points(np.zeros((3, 3)), np.zeros((2, 3)))


def test_camera_pose_helpers():
    from vid2sim.splats.camera import look_at
    w2c = look_at([1.0, 2.0, 3.0], [1.0, 7.0, 3.0], up=[0, 0, 1])
    cam = Camera(100, 100, 64, 36, 128, 72, w2c)
    assert cam.center.tolist() == pytest.approx([1, 2, 3])
    # a point ahead on the view axis projects to the principal point at its distance
    p = cam.world_to_cam @ torch.tensor([1.0, 6.0, 3.0, 1.0], dtype=D)
    assert p[:3].tolist() == pytest.approx([0, 0, 4])
    # world up maps to image up (negative camera y)
    up = cam.world_to_cam[:3, :3] @ torch.tensor([0, 0, 1.0], dtype=D)
    assert up.tolist() == pytest.approx([0, -1, 0])
    again = Camera.from_cam_to_world(cam.K, cam.cam_to_world, 128, 72)
    assert torch.allclose(again.world_to_cam, cam.world_to_cam)
    half = cam.scaled(0.5)
    assert (half.width, half.height, half.fx, half.cx) == (64, 36, 50.0, 32.0)
    # same point, same normalised image position at half resolution
    assert torch.equal(half.world_to_cam, cam.world_to_cam)
