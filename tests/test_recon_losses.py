"""Reconstruction losses: each checked against its defining property or a direct reference."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from vid2sim.factory.recon import losses as L


def _img(h=24, w=32, seed=0):
    g = torch.Generator().manual_seed(seed)
    return torch.rand(h, w, 3, generator=g)


def test_ssim_identical_is_one_and_drops_with_noise():
    a = _img()
    assert torch.allclose(L.ssim_map(a, a), torch.ones(24, 32), atol=1e-5)
    noisy = (a + 0.2 * torch.randn_like(a)).clamp(0, 1)
    s = float(L.ssim_map(a, noisy, same=False).mean())
    assert 0.0 < s < 0.9
    assert math.isclose(s, float(L.ssim_map(noisy, a, same=False).mean()), rel_tol=1e-5)  # symmetric


def test_ssim_matches_direct_formula_on_constant_images():
    a = torch.full((16, 16, 3), 0.3)
    b = torch.full((16, 16, 3), 0.6)
    # constant images: SSIM = (2 mu_x mu_y + C1) / (mu_x^2 + mu_y^2 + C1)
    c1 = 0.01 ** 2
    expect = (2 * 0.3 * 0.6 + c1) / (0.3 ** 2 + 0.6 ** 2 + c1)
    assert torch.allclose(L.ssim_map(a, b, same=False), torch.full((6, 6), expect), atol=5e-4)


def test_rgb_loss_ignores_dynamic_pixels():
    gt = _img()
    pred = gt.clone()
    mask = torch.ones(24, 32, dtype=torch.bool)
    mask[5:12, 8:20] = False
    pred[5:12, 8:20] = 1.0 - pred[5:12, 8:20]  # a "moving object" differs
    assert float(L.rgb_loss(pred, gt, mask, lambda_dssim=0.0)) == pytest.approx(0.0, abs=1e-7)
    full = float(L.rgb_loss(pred, gt, None))
    masked = float(L.rgb_loss(pred, gt, mask))
    assert full > 0.05 and masked < 0.3 * full


def _ncc_reference(a, b, k, s):
    scores = []
    for i in range(0, a.shape[0] - k + 1, s):
        for j in range(0, a.shape[1] - k + 1, s):
            pa, pb = a[i:i + k, j:j + k].ravel(), b[i:i + k, j:j + k].ravel()
            da, db = pa - pa.mean(), pb - pb.mean()
            scores.append(np.sum(da * db) / (k * k) / (pa.std() * pb.std()))
    return 1.0 - np.mean(scores)


def test_ncc_is_scale_shift_invariant_and_sign_sensitive():
    d = torch.rand(32, 40) * 5 + 1
    assert float(L.ncc_depth_loss(3.0 * d + 7.0, d)) == pytest.approx(0.0, abs=1e-4)
    assert float(L.ncc_depth_loss(-d, d)) == pytest.approx(2.0, abs=1e-4)


def test_ncc_matches_per_patch_reference():
    rng = np.random.default_rng(1)
    a, b = rng.random((20, 28)) + 1, rng.random((20, 28)) + 1
    got = float(L.ncc_depth_loss(torch.tensor(a), torch.tensor(b), patch=6, stride=3, eps=0.0))
    assert got == pytest.approx(_ncc_reference(a, b, 6, 3), abs=1e-6)


def test_ncc_ignores_invalid_pixels_and_has_gradient():
    d = torch.rand(24, 24) + 1
    valid = torch.ones(24, 24, dtype=torch.bool)
    valid[:, 12] = False
    corrupted = d.clone()
    corrupted[:, 12] = 100.0
    r = (2 * d + 1).requires_grad_()
    loss = L.ncc_depth_loss(r, corrupted, valid, patch=8, stride=4, min_valid=0.5)
    assert float(loss) == pytest.approx(0.0, abs=1e-4)
    L.ncc_depth_loss(r + torch.rand(24, 24), d).backward()
    assert r.grad is not None and float(r.grad.abs().sum()) > 0


def _plane_depth(K, n, offset, h, w):
    """z-depth of the plane n . X = offset seen by a camera at the origin."""
    j, i = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    rays = np.stack([(j - K[0, 2]) / K[0, 0], (i - K[1, 2]) / K[1, 1], np.ones_like(j)], -1)
    return offset / (rays @ n)


def test_pca_normals_recover_a_tilted_plane_and_face_the_camera():
    K = np.array([[30.0, 0, 16], [0, 30.0, 12], [0, 0, 1]])
    n = np.array([0.2, -0.6, -0.77])
    n /= np.linalg.norm(n)
    depth = torch.tensor(_plane_depth(K, n, -3.0, 24, 32))  # plane in front of the camera
    assert (depth > 0).all()
    normals, ok = L.normals_from_depth_pca(depth, torch.tensor(K), window=5)
    assert ok[2:-2, 2:-2].all()
    cos = (normals[ok] * torch.tensor(n, dtype=torch.float32)).sum(-1)
    assert float(cos.min()) > 0.999  # same direction, facing the camera (n . X < 0)


def test_pca_normals_do_not_mix_across_depth_edges():
    K = torch.tensor([[30.0, 0, 16], [0, 30.0, 12], [0, 0, 1]])
    depth = torch.full((24, 32), 2.0)
    depth[:, 16:] = 6.0  # two fronto-parallel planes
    normals, ok = L.normals_from_depth_pca(depth, K, window=5)
    assert float(normals[ok][:, 2].max()) < -0.999  # every normal points back to the camera


def test_pca_normals_are_zero_where_the_depth_is_not_valid():
    K = torch.tensor([[30.0, 0, 16], [0, 30.0, 12], [0, 0, 1]])
    depth = torch.full((24, 32), 3.0)
    valid = torch.ones(24, 32, dtype=torch.bool)
    valid[5:15, 4:12] = False  # a hole in the prior
    normals, ok = L.normals_from_depth_pca(depth, K, window=5, valid=valid)
    assert not ok[5:15, 4:12].any() and ok[~valid].sum() == 0
    assert float(normals[~ok].abs().max()) == 0.0
    assert float(normals[ok][:, 2].max()) < -0.999
    empty, none_ok = L.normals_from_depth_pca(depth, K, window=5, valid=torch.zeros(24, 32, dtype=torch.bool))
    assert not none_ok.any() and float(empty.abs().max()) == 0.0


def test_normal_loss_values():
    n = torch.nn.functional.normalize(torch.randn(8, 8, 3), dim=-1)
    assert float(L.normal_loss(n, 2.5 * n)) == pytest.approx(0.0, abs=1e-6)
    assert float(L.normal_loss(n, -n)) == pytest.approx(2.0, abs=1e-6)
    valid = torch.zeros(8, 8, dtype=torch.bool)
    valid[:4] = True
    other = n.clone()
    other[4:] = -other[4:]
    assert float(L.normal_loss(n, other, valid)) == pytest.approx(0.0, abs=1e-6)


def test_depth_edge_weights_follow_the_gradient():
    d = torch.zeros(4, 5)
    d[:, 3:] = 2.0  # step between columns 2 and 3
    w = L.depth_edge_weights(d)
    assert w.shape == (3, 4)
    assert torch.allclose(w[:, 2], torch.zeros(3)) and torch.allclose(w[:, :2], torch.ones(3, 2))
    d2 = torch.arange(5.0)[None].repeat(4, 1) * 0.6  # grad_x = 0.6 everywhere
    assert torch.allclose(L.depth_edge_weights(d2), torch.full((3, 4), 0.4))


def test_geo_loss_is_zero_for_smooth_normals_and_ignores_depth_edges():
    up = torch.tensor([0.0, 0.0, -1.0])
    side = torch.tensor([1.0, 0.0, 0.0])
    normals = up.repeat(10, 10, 1)
    flat = torch.ones(10, 10)
    assert float(L.geo_consistency_loss(normals, flat)) == pytest.approx(0.0, abs=1e-7)
    normals[:, 5:] = side  # a crease between columns 4 and 5
    crease_flat = float(L.geo_consistency_loss(normals, flat))
    assert crease_flat == pytest.approx(0.5 * 9 / 81, rel=1e-5)  # right-neighbour term at 9 pixels
    edge = flat.clone()
    edge[:, 5:] = 5.0  # the crease coincides with a depth step -> weight 0
    assert float(L.geo_consistency_loss(normals, edge)) == pytest.approx(0.0, abs=1e-7)


def test_scale_loss_is_mean_of_min_scale():
    s = torch.tensor([[0.1, 0.2, 0.3], [0.5, 0.05, 1.0]])
    ls = torch.log(s).requires_grad_()
    loss = L.scale_loss(ls)
    assert float(loss) == pytest.approx((0.1 + 0.05) / 2)
    loss.backward()
    assert ls.grad[0, 0] > 0 and ls.grad[0, 1] == 0 and ls.grad[1, 1] > 0


def test_psnr():
    a = torch.zeros(4, 4, 3)
    assert L.psnr(a + 0.1, a) == pytest.approx(20.0, abs=1e-4)


def test_separable_ssim_matches_2d_window_reference():
    """ssim_map uses two 1D passes; a direct 2D-window convolution must agree."""
    import torch.nn.functional as F

    from vid2sim.factory.recon.losses import gaussian_window, ssim_map

    torch.manual_seed(0)
    a, b = torch.rand(23, 31, 3), torch.rand(23, 31, 3)
    x, y = a.permute(2, 0, 1)[None], b.permute(2, 0, 1)[None]
    w = gaussian_window(11, 1.5)[None, None].expand(3, 1, 11, 11)

    def filt(t):
        return F.conv2d(t, w, padding=5, groups=3)

    mx, my = filt(x), filt(y)
    sxx, syy, sxy = filt(x * x) - mx ** 2, filt(y * y) - my ** 2, filt(x * y) - mx * my
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    ref = ((2 * mx * my + c1) * (2 * sxy + c2) / ((mx ** 2 + my ** 2 + c1) * (sxx + syy + c2)))[0].mean(0)
    assert torch.allclose(ssim_map(a, b), ref, atol=1e-5)
