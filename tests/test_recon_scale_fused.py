"""The fused flat-Gaussian (scale) loss against its torch reference."""

from __future__ import annotations

import pytest
import torch

from vid2sim.factory.recon.losses import scale_loss
from vid2sim.factory.recon.scale_fused import scale_loss_fused


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 1e-6)])
def test_fused_scale_loss_equals_its_reference_ties_included(dtype, tol):
    g = torch.Generator().manual_seed(0)
    log_scales = torch.randn(5000, 3, generator=g) * 0.7 - 4.0
    log_scales[:100] = log_scales[:100, :1]  # isotropic Gaussians (as initialised): three-way ties
    log_scales[100:200, 2] = log_scales[100:200, 1]  # two-way ties
    a = log_scales.to(dtype).requires_grad_(True)
    b = log_scales.to(dtype).requires_grad_(True)
    fused, ref = scale_loss_fused(a), scale_loss(b, fused=False)
    assert fused.dtype == dtype and abs(float(fused.detach()) - float(ref.detach())) <= tol * float(ref.detach())
    (3.0 * fused).backward()
    (3.0 * ref).backward()
    torch.testing.assert_close(a.grad, b.grad, rtol=tol, atol=0.0)  # the tied rows' gradient on one axis alike
    assert (a.grad[:200] != 0).sum(dim=1).eq(1).all()


def test_scale_loss_dispatch_and_bad_input():
    x = torch.randn(10, 3, requires_grad=True)
    assert scale_loss(x).grad_fn.__class__.__name__.startswith("_FusedScale")
    assert float(scale_loss(torch.zeros(0, 3))) == 0.0  # an empty model: the reference's zero
    with pytest.raises(ValueError, match="scale_loss_fused"):
        scale_loss_fused(torch.zeros(4, 2))
