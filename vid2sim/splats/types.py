"""Data handed between the splat model, the backends and callers.

The math every backend implements is specified once in docs/splat_renderer.md;
the torch reference (`reference.py`) is the executable form of that spec.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import torch


@dataclass(frozen=True)
class RasterSettings:
    """Per-render options (see docs/splat_renderer.md)."""

    width: int
    height: int
    near: float = 0.01
    far: float = 1e10
    # Screen-space covariance culling: drop a splat if max|Sigma2d| > alpha * H * W.
    # None = off (training default); envs turn it on.
    cov_cull_alpha: Optional[float] = None
    active_sh_degree: int = 3
    # px, tile edge; None: the backend's own (cpu 32, cuda and torch 16). Images do not depend
    # on it; the cpu backward's gradients change by float rounding (per-tile sums).
    tile_size: Optional[int] = None
    # False: the caller does not read median_depth, and a backend may leave it 0 (the cpu one
    # then skips a per-pixel plane in its forward composite)
    median_depth: bool = True

    def tile(self, default: int) -> int:
        """tile_size, or `default` (the backend's own) when None."""
        return default if self.tile_size is None else int(self.tile_size)


@dataclass
class RasterOutput:
    """Raw per-pixel accumulations from a backend; all [H, W, ...] float32 tensors.

    color_accum  [H, W, 3]  sum_i w_i c_i            (no background)
    alpha        [H, W]     1 - T_final
    depth_accum  [H, W]     sum_i w_i z_i            (camera z)
    normal_accum [H, W, 3]  sum_i w_i n_i            (camera frame, OpenCV axes)
    median_depth [H, W]     z of the first splat where T drops to <= 0.5, else 0 (may be
                            all 0 with RasterSettings.median_depth False)
    means2d      [N, 2]     projected centres (pixels); zeros for culled splats
    radii        [N]        int32 pixel radius, 0 = culled
    absgrad      [N, 2]     filled by backward: sum over pixels of |dL/dmeans2d| (AbsGS)
    grad2d       [N, 2]     filled by backward: dL/dmeans2d (pixels)
    """

    color_accum: torch.Tensor
    alpha: torch.Tensor
    depth_accum: torch.Tensor
    normal_accum: torch.Tensor
    median_depth: torch.Tensor
    means2d: torch.Tensor
    radii: torch.Tensor
    absgrad: Optional[torch.Tensor] = None
    grad2d: Optional[torch.Tensor] = None


@dataclass
class RenderOutput:
    """What `render()` returns; images are [H, W, C] float32.

    rgb          [H, W, 3]  color_accum + (1 - alpha) * background
    alpha        [H, W]
    depth        [H, W]     expected z-depth = depth_accum / max(alpha, 1e-6); 0 where alpha == 0
    median_depth [H, W]
    normal       [H, W, 3]  normal_accum normalised to unit length (camera frame); 0 where alpha == 0
    raw          the backend's RasterOutput (means2d, radii, absgrad/grad2d after backward)
    """

    rgb: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor
    median_depth: torch.Tensor
    normal: torch.Tensor
    raw: RasterOutput = field(repr=False)
