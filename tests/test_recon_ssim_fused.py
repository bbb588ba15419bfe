"""The fused SSIM map (recon/ssim_fused.py) against the torch reference `losses.ssim_map`:
values and gradients, odd and tiny image sizes, and the loss that uses it."""

from __future__ import annotations

import pytest
import torch

from vid2sim.factory.recon import losses as L
from vid2sim.factory.recon.ssim_fused import fused_applies, ssim_map_fused


def _pair(seed: int, h: int, w: int, c: int = 3) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    gt = torch.rand(h, w, c, generator=g)
    pred = (gt + 0.15 * torch.randn(h, w, c, generator=g)).clamp(0, 1)
    return pred, gt


def _map_and_grad(fn, pred, gt, upstream):
    p = pred.clone().requires_grad_(True)
    m = fn(p, gt)
    (m * upstream).sum().backward()
    return m.detach(), p.grad


@pytest.mark.parametrize("h,w,c", [(150, 320, 3), (37, 53, 3), (7, 9, 3), (20, 31, 1)])
def test_fused_map_and_gradient_match_reference(h, w, c):
    pred, gt = _pair(h * w, h, w, c)
    upstream = torch.randn(h, w, generator=torch.Generator().manual_seed(1))
    m_ref, g_ref = _map_and_grad(L.ssim_map, pred, gt, upstream)
    m_fus, g_fus = _map_and_grad(ssim_map_fused, pred, gt, upstream)
    assert m_fus.shape == (h, w)
    assert (m_fus - m_ref).abs().max() <= 2e-6
    assert (g_fus - g_ref).norm() <= 1e-5 * g_ref.norm()
    assert (g_fus - g_ref).abs().max() <= 1e-5 * g_ref.abs().max()


def test_rgb_loss_takes_the_fused_map_and_keeps_its_value_and_gradient():
    pred, gt = _pair(3, 40, 60)
    mask = torch.ones(40, 60, dtype=torch.bool)
    mask[10:25, 20:45] = False
    p1, p2 = pred.clone().requires_grad_(True), pred.double().clone().requires_grad_(True)
    assert fused_applies(p1, gt) and not fused_applies(p2, gt.double())
    l1 = L.rgb_loss(p1, gt, mask)  # fused
    l2 = L.rgb_loss(p2, gt.double(), mask)  # float64: the reference path
    l1.backward()
    l2.backward()
    assert float(l1.detach()) == pytest.approx(float(l2.detach()), rel=1e-5)
    assert (p1.grad.double() - p2.grad).norm() <= 1e-4 * p2.grad.norm()


def test_identical_images_give_one_and_zero_gradient():
    _, gt = _pair(5, 24, 32)
    m, g = _map_and_grad(ssim_map_fused, gt, gt, torch.ones(24, 32))
    assert torch.allclose(m, torch.ones(24, 32), atol=1e-5)
    assert g.abs().max() <= 1e-4  # SSIM is at its maximum


def test_bad_inputs_are_refused_by_name():
    pred, gt = _pair(0, 8, 8)
    with pytest.raises(ValueError, match="ssim_map_fused"):
        ssim_map_fused(pred.double(), gt.double())
    with pytest.raises(ValueError, match="ssim_map_fused"):
        ssim_map_fused(pred, gt[:4])
