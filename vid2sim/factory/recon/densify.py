"""AbsGS densification: statistics from every backward pass, then clone / split / prune /
opacity reset on the 3DGS schedule, with a cap on the Gaussian count.

Clone (small Gaussians, under-reconstruction): mean plain 2D gradient norm >= grad_threshold.
Split (large Gaussians, over-reconstruction): mean absolute 2D gradient norm (AbsGS: per-pixel
|dL/dmean2d| summed before the norm, so opposing pixel gradients do not cancel)
>= absgrad_threshold. Gradients are in 3DGS NDC units (pixels * (W/2, H/2)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from numba import njit

from vid2sim.factory.recon.config import DensifyConfig
from vid2sim.factory.recon.params import NAMES, SplatParams


def quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    """q [N, 4] (w, x, y, z), any norm -> R [N, 3, 3]."""
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], -1).reshape(-1, 3, 3)


@dataclass
class DensifyStats:
    """Per-Gaussian accumulators between densification steps (all [N])."""

    grad: torch.Tensor
    absgrad: torch.Tensor
    count: torch.Tensor
    max_radius: torch.Tensor

    @classmethod
    def zeros(cls, n: int) -> "DensifyStats":
        z = torch.zeros(n)
        return cls(z.clone(), z.clone(), z.clone(), z.clone())

    def accumulate(self, grad2d: torch.Tensor, absgrad: torch.Tensor, radii: torch.Tensor,
                   width: int, height: int) -> None:
        """grad2d, absgrad [N, 2] (pixels), radii [N] from one render's backward. float32 CPU
        statistics are summed by one numba pass (`_accumulate`: the same values as the torch ops
        below, which serve every other case)."""
        arrays = (self.grad, self.absgrad, self.count, self.max_radius, grad2d, absgrad)
        if all(t.dtype == torch.float32 and t.device.type == "cpu" and t.is_contiguous() for t in arrays) \
                and radii.dtype == torch.int32 and radii.is_contiguous():
            _accumulate(*(t.detach().numpy() for t in arrays), radii.numpy(),
                        np.float32(width / 2.0), np.float32(height / 2.0))
            return
        vis = radii > 0
        zero = torch.zeros((), dtype=self.grad.dtype)
        scale = torch.tensor([width / 2.0, height / 2.0])
        # dense updates with the hidden splats' terms zeroed: the same sums as indexing by vis,
        # without gathering and scattering [N] arrays every step
        self.grad += torch.where(vis, (grad2d.float() * scale).norm(dim=-1), zero)
        self.absgrad += torch.where(vis, (absgrad.float() * scale).norm(dim=-1), zero)
        self.count += vis
        self.max_radius = torch.maximum(self.max_radius, torch.where(vis, radii.float(), zero))

    def means(self) -> tuple[torch.Tensor, torch.Tensor]:
        c = self.count.clamp_min(1)
        return self.grad / c, self.absgrad / c


@njit(cache=True, fastmath=True)
def _accumulate(grad, absgrad, count, max_radius, g2, a2, radii, sx, sy):
    """In place, for every Gaussian with radius > 0 (float32 [N], g2 / a2 [N, 2], radii int32 [N]):
    grad += |g2 * (sx, sy)|, absgrad += |a2 * (sx, sy)|, count += 1, max_radius = max(., radius).
    fastmath lets LLVM contract x x + y y into an FMA, as torch's float32 norm does: the sums equal
    `DensifyStats.accumulate`'s torch ops bit for bit (tests/test_recon_densify.py)."""
    for i in range(radii.shape[0]):
        r = radii[i]
        if r <= 0:
            continue
        x, y = g2[i, 0] * sx, g2[i, 1] * sy
        grad[i] += np.float32(math.sqrt(x * x + y * y))
        x, y = a2[i, 0] * sx, a2[i, 1] * sy
        absgrad[i] += np.float32(math.sqrt(x * x + y * y))
        count[i] += np.float32(1.0)
        max_radius[i] = max(max_radius[i], np.float32(r))


def _cap(mask: torch.Tensor, score: torch.Tensor, budget: int) -> torch.Tensor:
    """Keep at most `budget` True entries of mask [N], those with the highest score."""
    budget = max(int(budget), 0)
    if int(mask.sum()) <= budget:
        return mask
    idx = torch.nonzero(mask).squeeze(1)
    top = idx[torch.topk(score[idx], budget).indices]
    out = torch.zeros_like(mask)
    out[top] = True
    return out


def _split_rows(params: SplatParams, mask: torch.Tensor, n_children: int = 2) -> dict:
    """Children of the Gaussians in mask: positions sampled from each parent, scales / 1.6."""
    p = {k: v.detach()[mask] for k, v in params.p.items()}
    scales = torch.exp(p["log_scales"])  # [M, 3]
    rot = quat_to_rotmat(p["quats"])  # [M, 3, 3]
    rows = {}
    samples = torch.randn(n_children, *scales.shape) * scales  # [C, M, 3]
    offsets = torch.einsum("mij,cmj->cmi", rot, samples)  # [C, M, 3]
    rows["means"] = (p["means"][None] + offsets).reshape(-1, 3)
    rows["log_scales"] = torch.log(scales / (0.8 * n_children)).repeat(n_children, 1)
    for k in ("quats", "opacity_logits", "sh0", "shN"):
        rows[k] = p[k].repeat(n_children, *([1] * (p[k].dim() - 1)))
    return rows


def densify_and_prune(params: SplatParams, stats: DensifyStats, conf: DensifyConfig, extent: float,
                      prune_large: bool) -> dict:
    """One AbsGS densification step; returns counts {cloned, split, pruned, n}."""
    n0 = params.n
    grad, absgrad = stats.means()
    max_scale = torch.exp(params.p["log_scales"].detach()).max(dim=1).values
    small = max_scale <= conf.percent_dense * extent
    clone = (grad >= conf.grad_threshold) & small
    split = (absgrad >= conf.absgrad_threshold) & ~small
    budget = conf.max_gaussians - n0
    clone = _cap(clone, grad, budget)
    split = _cap(split, absgrad, budget - int(clone.sum()))  # each split adds one net
    clone_rows = {k: v.detach()[clone] for k, v in params.p.items()}
    split_rows = _split_rows(params, split)
    n_clone, n_split = int(clone.sum()), int(split.sum())
    params.append({k: torch.cat([clone_rows[k], split_rows[k]]) for k in NAMES})
    # drop split parents; new rows are never pruned by the parent test
    drop = torch.cat([split, torch.zeros(params.n - n0, dtype=torch.bool)])
    opacity = torch.sigmoid(params.p["opacity_logits"].detach())
    drop |= opacity < conf.min_opacity
    if prune_large:
        radius = torch.cat([stats.max_radius, torch.zeros(params.n - n0)])
        big_world = torch.exp(params.p["log_scales"].detach()).max(dim=1).values > conf.max_world_scale * extent
        drop |= (radius > conf.max_screen_radius) | big_world
    params.keep(~drop)
    return {"cloned": n_clone, "split": n_split, "pruned": int(drop.sum()) - n_split, "n": params.n}


def prune_only(params: SplatParams, conf: DensifyConfig) -> int:
    """Drop transparent Gaussians (used after densification stops); returns how many."""
    drop = torch.sigmoid(params.p["opacity_logits"].detach()) < conf.min_opacity
    params.keep(~drop)
    return int(drop.sum())


def reset_opacity(params: SplatParams, max_opacity: float = 0.01) -> None:
    """3DGS opacity reset: clamp every opacity to <= max_opacity, moments zeroed."""
    logit = torch.logit(torch.tensor(max_opacity))
    params.reset("opacity_logits", torch.minimum(params.p["opacity_logits"].detach(), logit))
