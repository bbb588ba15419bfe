"""AbsGS densification and Adam state surgery."""

from __future__ import annotations

import numpy as np
import torch

from vid2sim.factory.recon.config import DensifyConfig
from vid2sim.factory.recon.densify import (DensifyStats, densify_and_prune, quat_to_rotmat,
                                           reset_opacity)
from vid2sim.factory.recon.params import NAMES, SplatParams
from vid2sim.splats.model import GaussianModel

LRS = {k: 1e-2 for k in NAMES}


def _params(n=6, scale=0.01):
    xyz = np.arange(n * 3, dtype=np.float64).reshape(n, 3)
    m = GaussianModel.from_points(xyz, np.full((n, 3), 128, np.uint8), sh_degree=1)
    m.log_scales = torch.full((n, 3), float(np.log(scale)))
    m.opacity_logits = torch.full((n,), 2.0)
    return SplatParams.from_model(m, LRS)


def _step(params):
    loss = sum((v * torch.arange(1, v.shape[0] + 1).reshape(-1, *[1] * (v.dim() - 1))).sum()
               for v in params.p.values())
    loss.backward()
    params.opt.step()
    params.opt.zero_grad()


def test_keep_and_append_carry_adam_moments_row_by_row():
    p = _params()
    _step(p)
    before = p.opt.state[p.p["means"]]["exp_avg"].clone()  # row r ~ r + 1
    keep = torch.tensor([True, False, True, True, False, True])
    p.keep(keep)
    assert p.n == 4
    assert torch.allclose(p.opt.state[p.p["means"]]["exp_avg"], before[keep])
    p.append({k: v.detach()[:2] for k, v in p.p.items()})
    st = p.opt.state[p.p["sh0"]]
    assert p.n == 6 and st["exp_avg"].shape[0] == 6 and float(st["exp_avg"][4:].abs().sum()) == 0
    _step(p)  # the optimizer still drives the new leaves
    assert all(p.opt.param_groups[i]["params"][0] is p.p[k] for i, k in enumerate(NAMES))


def test_clone_small_split_large_prune_transparent():
    p = _params(n=4)
    with torch.no_grad():
        p.p["log_scales"][1] = float(np.log(0.5))  # large
        p.p["opacity_logits"][3] = -10.0  # transparent
    stats = DensifyStats.zeros(4)
    W = H = 100
    # Gaussian 0: plain gradient above threshold (small -> clone);
    # Gaussian 1: absolute gradient above threshold, plain gradient ~0 (large -> split)
    grad2d = torch.tensor([[0.001, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 0.0]])
    absgrad = torch.tensor([[0.001, 0.0], [0.01, 0.0], [0.0, 0.0], [0.0, 0.0]])
    stats.accumulate(grad2d, absgrad, torch.tensor([3, 3, 3, 3]), W, H)
    conf = DensifyConfig(grad_threshold=0.0002 * 100, absgrad_threshold=0.0008 * 10,
                         percent_dense=0.01, min_opacity=0.005)
    parent = p.p["means"][1].detach().clone()
    counts = densify_and_prune(p, stats, conf, extent=10.0, prune_large=False)
    assert counts["cloned"] == 1 and counts["split"] == 1
    assert p.n == 4 + 1 + 2 - 1 - 1  # + clone + 2 children - split parent - transparent
    scales = torch.exp(p.p["log_scales"].detach())
    children = torch.isclose(scales[:, 0], torch.tensor(0.5 / 1.6))
    assert int(children.sum()) == 2
    assert float((p.p["means"].detach()[children] - parent).norm(dim=1).max()) < 0.5 * 5


def test_cap_limits_growth():
    p = _params(n=10)
    stats = DensifyStats.zeros(10)
    g = torch.linspace(0.001, 0.002, 10)[:, None].repeat(1, 2)
    stats.accumulate(g, g, torch.full((10,), 2), 100, 100)
    conf = DensifyConfig(grad_threshold=1e-6, absgrad_threshold=1e-6, max_gaussians=13)
    densify_and_prune(p, stats, conf, extent=10.0, prune_large=False)
    assert p.n == 13


def test_prune_large_on_screen():
    p = _params(n=3)
    stats = DensifyStats.zeros(3)
    stats.accumulate(torch.zeros(3, 2), torch.zeros(3, 2), torch.tensor([5, 50, 0]), 100, 100)
    conf = DensifyConfig(max_screen_radius=20)
    densify_and_prune(p, stats, conf, extent=10.0, prune_large=True)
    assert p.n == 2


def test_opacity_reset_clamps_and_zeroes_moments():
    p = _params(n=3)
    _step(p)
    reset_opacity(p, 0.01)
    assert torch.allclose(torch.sigmoid(p.p["opacity_logits"].detach()), torch.full((3,), 0.01), atol=1e-6)
    assert float(p.opt.state[p.p["opacity_logits"]]["exp_avg"].abs().sum()) == 0


def test_quat_to_rotmat_is_orthonormal():
    R = quat_to_rotmat(torch.randn(5, 4))
    assert torch.allclose(R @ R.transpose(1, 2), torch.eye(3).expand(5, 3, 3), atol=1e-5)
    assert torch.allclose(torch.linalg.det(R), torch.ones(5), atol=1e-5)
    assert torch.allclose(quat_to_rotmat(torch.tensor([[2.0, 0, 0, 0]]))[0], torch.eye(3))


def test_the_numba_accumulation_equals_the_torch_ops():
    """float32 statistics with int32 radii go through one numba pass; the same sums as the torch
    ops every other input takes (equal bit for bit where both contract x x + y y into an FMA)."""
    g = torch.Generator().manual_seed(0)
    n = 5000
    fast, ref = DensifyStats.zeros(n), DensifyStats.zeros(n)
    for scale in (1e-6, 1e-3, 1.0):
        grad2d, absgrad = torch.randn(n, 2, generator=g) * scale, torch.randn(n, 2, generator=g).abs() * scale
        radii = torch.randint(-1, 30, (n,), generator=g, dtype=torch.int32)  # <= 0: hidden
        radii[:10] = 0  # never seen
        fast.accumulate(grad2d, absgrad, radii, 320, 150)
        ref.accumulate(grad2d, absgrad, radii.long(), 320, 150)  # int64 radii: the torch ops
    torch.testing.assert_close(fast.grad, ref.grad, rtol=1e-6, atol=0.0)
    torch.testing.assert_close(fast.absgrad, ref.absgrad, rtol=1e-6, atol=0.0)
    assert torch.equal(fast.count, ref.count) and torch.equal(fast.max_radius, ref.max_radius)
    assert fast.count.max() == 3 and (fast.count == 0).any()
