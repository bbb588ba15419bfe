"""The fused patch-NCC depth loss against its torch reference (`losses.ncc_depth_loss`)."""

from __future__ import annotations

import pytest
import torch

from vid2sim.factory.recon.losses import ncc_depth_loss
from vid2sim.factory.recon.ncc_fused import ncc_depth_loss_fused


def _maps(h: int, w: int, dtype: torch.dtype, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(torch.linspace(0, 1, h), torch.linspace(0, 1, w), indexing="ij")
    prior = 3.0 + 2.0 * xx + torch.sin(6 * yy) + 0.05 * torch.rand(h, w, generator=g)
    prior[: h // 3, : w // 3] = 4.0  # a flat prior region: its patches are left out
    rendered = prior + 0.3 * torch.randn(h, w, generator=g)
    valid = torch.rand(h, w, generator=g) > 0.1
    valid[h // 2:, w // 2: w // 2 + 9] = False  # a hole: patches with too few valid pixels
    return rendered.to(dtype), prior.to(dtype), valid


@pytest.mark.parametrize("dtype,h,w,patch,stride,tol", [
    (torch.float64, 37, 53, 8, 4, 1e-10), (torch.float32, 150, 320, 8, 4, 2e-5),
    (torch.float64, 20, 31, 7, 3, 1e-10), (torch.float64, 16, 13, 8, 4, 1e-10)])
def test_fused_ncc_equals_reference_in_value_and_gradient(dtype, h, w, patch, stride, tol):
    rendered, prior, valid = _maps(h, w, dtype, seed=h + w)
    a = rendered.clone().requires_grad_(True)
    b = rendered.clone().requires_grad_(True)
    fused = ncc_depth_loss_fused(a, prior, valid, patch, stride)
    ref = ncc_depth_loss(b, prior, valid, patch, stride, fused=False)
    f, r = float(fused.detach()), float(ref.detach())
    assert fused.dtype == dtype and 0.0 < r < 2.0
    assert abs(f - r) <= tol * max(1.0, abs(r))
    (3.0 * fused).backward()
    (3.0 * ref).backward()
    scale = float(b.grad.abs().max())
    assert scale > 0
    torch.testing.assert_close(a.grad, b.grad, rtol=0, atol=tol * 10 * scale)
    assert float(a.grad[~valid].abs().max()) == 0.0  # invalid pixels take no gradient


def test_no_qualifying_patch_gives_zero_and_no_gradient():
    rendered, prior, valid = _maps(24, 24, torch.float64, seed=0)
    valid[:] = False
    a = rendered.clone().requires_grad_(True)
    loss = ncc_depth_loss(a, prior, valid)  # dispatches to the fused loss on CPU
    loss.backward()
    assert float(loss) == 0.0 and float(a.grad.abs().max()) == 0.0
    assert float(ncc_depth_loss(rendered, prior, valid, fused=False)) == 0.0


def test_fused_refuses_what_it_cannot_serve():
    r = torch.zeros(8, 8)
    with pytest.raises(ValueError, match="ncc_depth_loss_fused"):
        ncc_depth_loss_fused(r, torch.zeros(8, 9), torch.ones(8, 8, dtype=torch.bool))
    with pytest.raises(ValueError, match="ncc_depth_loss_fused"):
        ncc_depth_loss_fused(r, torch.zeros(8, 8, requires_grad=True), torch.ones(8, 8, dtype=torch.bool))


def test_fused_ncc_does_not_depend_on_the_thread_count():
    """Rows of patches run in parallel phases and their sums are added in row order: one thread
    and two give the same loss and gradient bit for bit."""
    import numba
    g = torch.Generator().manual_seed(0)
    r = 2.0 + torch.rand(150, 320, generator=g)
    d = 1.1 * r + 0.05 * torch.rand(150, 320, generator=g)
    valid = torch.rand(150, 320, generator=g) > 0.1
    before, out = numba.get_num_threads(), []
    try:
        for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(threads)
            x = r.clone().requires_grad_(True)
            loss = ncc_depth_loss_fused(x, d, valid)
            loss.backward()
            out.append((float(loss.detach()), x.grad))
    finally:
        numba.set_num_threads(before)
    assert out[0][0] == out[1][0] and torch.equal(out[0][1], out[1][1])
