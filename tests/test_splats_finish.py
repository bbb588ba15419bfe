"""The fused finish (`splats/cpu/finish.py`) against `render.finish_reference`: values and
gradients, with the edge cases of the clamps (uncovered pixels, alpha below 1e-6, zero and
tiny normals)."""

from __future__ import annotations

import pytest
import torch

from vid2sim.splats.cpu.finish import finish_images
from vid2sim.splats.render import finish, finish_reference
from vid2sim.splats.types import RasterOutput


def raw_images(seed: int, h: int = 23, w: int = 31, dtype=torch.float32) -> list[torch.Tensor]:
    """color [H, W, 3], alpha, depth [H, W], normal [H, W, 3] with every clamp case present."""
    g = torch.Generator().manual_seed(seed)
    a = torch.rand(h, w, generator=g, dtype=torch.float64)
    a[a < 0.15] = 0.0  # uncovered
    a[0, :4] = torch.tensor([1e-7, 5e-7, 1e-6, 2e-6], dtype=torch.float64)  # around the alpha clamp
    color = torch.rand(h, w, 3, generator=g, dtype=torch.float64) * a[..., None]
    depth = torch.rand(h, w, generator=g, dtype=torch.float64) * 8 * a
    normal = torch.randn(h, w, 3, generator=g, dtype=torch.float64)
    normal[1, :3] = 0.0  # covered, zero normal
    normal[2, 0] = torch.tensor([1e-14, 0.0, 0.0])  # below the length clamp
    a[1, :3] = 0.5
    a[2, 0] = 0.5
    return [t.to(dtype) for t in (color, a, depth, normal)]


def as_raw(images: list[torch.Tensor]) -> RasterOutput:
    color, a, depth, normal = images
    return RasterOutput(color_accum=color, alpha=a, depth_accum=depth, normal_accum=normal,
                        median_depth=depth, means2d=None, radii=None)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fused_finish_equals_the_reference_in_value_and_gradient(seed: int) -> None:
    bg = torch.tensor([0.2, 0.5, 0.9])
    weights = [torch.randn(s, generator=torch.Generator().manual_seed(seed + 10)) for s in
               ((23, 31, 3), (23, 31), (23, 31, 3))]
    grads = {}
    for name in ("fused", "reference"):
        images = [t.clone().requires_grad_(True) for t in raw_images(seed)]
        if name == "fused":
            outs = finish_images(*images, bg)
        else:
            out = finish_reference(as_raw(images), bg)
            outs = (out.rgb, out.depth, out.normal)
        sum((w * o).sum() for w, o in zip(weights, outs)).backward()
        grads[name] = ([o.detach() for o in outs], [t.grad for t in images])
    for got, want in zip(*(grads[k][0] for k in ("fused", "reference"))):
        torch.testing.assert_close(got, want, rtol=1e-6, atol=1e-6)
    for got, want in zip(*(grads[k][1] for k in ("fused", "reference"))):
        torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-6)


def test_render_finish_takes_the_fused_pass_for_float32_cpu_and_the_reference_otherwise() -> None:
    raw32 = as_raw(raw_images(3))
    out = finish(raw32, (0.1, 0.2, 0.3))
    ref = finish_reference(raw32, (0.1, 0.2, 0.3))
    assert out.rgb.grad_fn is None and out.alpha is raw32.alpha and out.median_depth is raw32.median_depth
    for k in ("rgb", "depth", "normal"):
        torch.testing.assert_close(getattr(out, k), getattr(ref, k), rtol=1e-6, atol=1e-6)
    raw64 = as_raw(raw_images(3, dtype=torch.float64))
    out64 = finish(raw64)
    assert out64.rgb.dtype == torch.float64  # float64 goes through the torch reference
    torch.testing.assert_close(out64.depth, finish_reference(raw64).depth)
    with pytest.raises(ValueError, match="float32 CPU"):
        finish_images(*raw_images(0, dtype=torch.float64), torch.zeros(3))
