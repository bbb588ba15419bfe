"""The fused normal and geometry-consistency losses against their torch references."""

from __future__ import annotations

import pytest
import torch

from vid2sim.factory.recon.losses import geo_consistency_loss, normal_loss
from vid2sim.factory.recon.normals_fused import geo_loss_fused, normal_loss_fused


def _maps(h: int, w: int, dtype: torch.dtype, seed: int):
    g = torch.Generator().manual_seed(seed)
    n = torch.nn.functional.normalize(torch.randn(h, w, 3, generator=g), dim=-1)
    n = n * torch.empty(h, w, 1).uniform_(0.5, 1.5, generator=g)  # any length
    n[0, 0] = 0.0  # a zero normal (torch's eps branch)
    n[0, 1] = torch.tensor([3e-9, 0.0, 4e-9])
    prior = torch.nn.functional.normalize(n + 0.4 * torch.randn(h, w, 3, generator=g), dim=-1)
    prior[1, 1] = 0.0
    depth = torch.log(2.0 + torch.rand(h, w, generator=g))
    depth[h // 2:, :] += torch.linspace(0, 3, w)  # steep relative steps: weights clamp to 0 there
    valid = torch.rand(h, w, generator=g) > 0.2
    valid[0, :2] = True
    return n.to(dtype), prior.to(dtype), depth.to(dtype), valid


@pytest.mark.parametrize("dtype,h,w,tol", [(torch.float64, 23, 37, 1e-10), (torch.float32, 150, 320, 2e-5)])
def test_fused_normal_and_geo_losses_equal_their_references(dtype, h, w, tol):
    n, prior, depth, valid = _maps(h, w, dtype, seed=h)
    for fused_fn, ref_fn, other in ((normal_loss_fused, normal_loss, prior),
                                    (geo_loss_fused, geo_consistency_loss, depth)):
        a = n.clone().requires_grad_(True)
        b = n.clone().requires_grad_(True)
        f = fused_fn(a, other, valid)
        r = ref_fn(b, other, valid, fused=False)
        assert f.dtype == dtype and 0.0 < float(r.detach()) < 2.0
        assert abs(float(f.detach()) - float(r.detach())) <= tol
        (2.0 * f).backward()
        (2.0 * r).backward()
        scale = float(b.grad.abs().max())
        assert scale > 0
        torch.testing.assert_close(a.grad, b.grad, rtol=tol, atol=tol * scale)


def test_losses_dispatch_to_the_fused_kernels_and_handle_empty_masks():
    n, prior, depth, valid = _maps(12, 15, torch.float64, seed=1)
    none = torch.zeros_like(valid)
    a = n.clone().requires_grad_(True)
    (normal_loss(a, prior, none) + geo_consistency_loss(a, depth, none)).backward()
    assert float(a.grad.abs().max()) == 0.0
    assert float(normal_loss(n, prior, none)) == float(normal_loss(n, prior, none, fused=False)) == 1.0
    assert float(geo_consistency_loss(n, depth, none)) == 0.0
    assert normal_loss(n.clone().requires_grad_(True), prior, valid).grad_fn.name() == "_FusedNormalBackward"
    with pytest.raises(ValueError, match="normal_loss_fused"):
        normal_loss_fused(n, prior[:-1], valid)
    with pytest.raises(ValueError, match="geo_loss_fused"):
        geo_loss_fused(n, depth[:, :-1], valid)


def test_fused_normal_and_geo_losses_do_not_depend_on_the_thread_count():
    """Rows run in parallel (the geo loss's in two phases) and their sums are added in row order:
    one thread and two give the same losses and gradients bit for bit."""
    import numba
    n, prior, depth, valid = _maps(150, 320, torch.float32, seed=3)
    before, out = numba.get_num_threads(), []
    try:
        for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(threads)
            got = []
            for fn, other in ((normal_loss_fused, prior), (geo_loss_fused, depth)):
                x = n.clone().requires_grad_(True)
                loss = fn(x, other, valid)
                loss.backward()
                got.append((float(loss.detach()), x.grad))
            out.append(got)
    finally:
        numba.set_num_threads(before)
    for (l1, g1), (l2, g2) in zip(*out):
        assert l1 == l2 and torch.equal(g1, g2)
