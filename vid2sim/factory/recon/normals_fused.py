"""The normal and geometry-consistency losses with hand-written backwards (numba; CPU).

The same losses as `losses.normal_loss` and `losses.geo_consistency_loss`, which stay the
references: tests/test_recon_normals_fused.py checks value and gradient against them. torch
builds each from a dozen whole-image ops and their autograd nodes (~5.4 ms per 320x150 view
for the two, forward and backward, on one thread); here each is one pass that also writes the
gradient (~1.6 ms for the two; sums in float64, the gradient in the maps' own dtype).

normal:  L = 1 - sum_valid u(r) . u(p) / max(#valid, 1),  u(x) = x / max(|x|, eps)
         (torch's cosine_similarity, whose gradient (u(p) - cos r / |r|) / max(|r|, eps) keeps
         the norm's derivative below eps too)
geo:     L = sum w (1 - (n . n_right + n . n_below) / 2) / sum w  over pixels with a right and
         a bottom neighbour, w = clamp(1 - |grad D|, 0, 1) x (the three pixels valid); 0 when
         sum w is 0. Only the normals take a gradient.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit, prange

from vid2sim.factory.recon.fused_grad import PrecomputedGrad, as_numpy, loss_with_grad, ordered_sums

EPS = 1e-8  # losses.normal_loss's cosine eps


@njit(cache=True, parallel=True)
def _normal_terms(r, p, valid, eps, grad):
    """(sum of cosines over valid pixels, their count); grad [H, W, 3] (zeroed by the caller)
    = d cos / d r there. Rows in parallel; their sums are added in row order (no dependence on
    the thread count)."""
    H = r.shape[0]
    row_total = np.zeros(H)
    row_count = np.zeros(H, np.int64)
    for i in prange(H):
        row_total[i], row_count[i] = _normal_row(r, p, valid, eps, grad, i)
    return ordered_sums(row_total, row_count)


@njit(cache=True)
def _normal_row(r, p, valid, eps, grad, i):
    """Row i of `_normal_terms`: (sum of cosines, count)."""
    W = r.shape[1]
    total, count = 0.0, 0
    for j in range(W):
        if not valid[i, j]:
            continue
        rx, ry, rz = float(r[i, j, 0]), float(r[i, j, 1]), float(r[i, j, 2])
        px, py, pz = float(p[i, j, 0]), float(p[i, j, 1]), float(p[i, j, 2])
        nr = math.sqrt(rx * rx + ry * ry + rz * rz)
        npp = max(math.sqrt(px * px + py * py + pz * pz), eps)
        vx, vy, vz = px / npp, py / npp, pz / npp
        d = max(nr, eps)
        cos = (rx * vx + ry * vy + rz * vz) / d
        ux, uy, uz = (rx / nr, ry / nr, rz / nr) if nr > 0.0 else (0.0, 0.0, 0.0)
        grad[i, j, 0] = (vx - cos * ux) / d  # torch's: the norm's derivative even when clamped
        grad[i, j, 1] = (vy - cos * uy) / d
        grad[i, j, 2] = (vz - cos * uz) / d
        total += cos
        count += 1
    return total, count


@njit(cache=True, parallel=True)
def _geo_terms(n, depth, valid, grad):
    """(sum w (1 - dots), sum w); grad [H, W, 3] accumulates d sum w (1 - dots) / d n. Row i
    writes rows i and i + 1: even rows in parallel, then odd rows; the row sums are added in row
    order (no dependence on the thread count)."""
    H = n.shape[0]
    row_num = np.zeros(max(H - 1, 0))
    row_den = np.zeros(max(H - 1, 0))
    for phase in range(2):
        for k in prange((H - 1 - phase + 1) // 2):
            i = phase + 2 * k
            row_num[i], row_den[i] = _geo_row(n, depth, valid, grad, i)
    return ordered_sums(row_num, row_den)


@njit(cache=True)
def _geo_row(n, depth, valid, grad, i):
    """Row i of `_geo_terms`: (sum w (1 - dots), sum w)."""
    W = n.shape[1]
    num, den = 0.0, 0.0
    for j in range(W - 1):
        if not (valid[i, j] and valid[i, j + 1] and valid[i + 1, j]):
            continue
        gx = depth[i, j + 1] - depth[i, j]
        gy = depth[i + 1, j] - depth[i, j]
        w = min(max(1.0 - math.sqrt(float(gx) * gx + float(gy) * gy), 0.0), 1.0)
        if w == 0.0:
            continue
        dots = 0.0
        for c in range(3):
            dots += 0.5 * float(n[i, j, c]) * (float(n[i, j + 1, c]) + float(n[i + 1, j, c]))
        num += w * (1.0 - dots)
        den += w
        for c in range(3):
            grad[i, j, c] -= 0.5 * w * (n[i, j + 1, c] + n[i + 1, j, c])
            grad[i, j + 1, c] -= 0.5 * w * n[i, j, c]
            grad[i + 1, j, c] -= 0.5 * w * n[i, j, c]
    return num, den


class _FusedNormal(PrecomputedGrad):
    """The normal loss's autograd node."""


class _FusedGeo(PrecomputedGrad):
    """The geometry-consistency loss's autograd node."""


def normals_apply(normals: torch.Tensor, other: torch.Tensor) -> bool:
    """The fused losses serve CPU maps (normals [H, W, 3] with `other` [H, W, 3] or [H, W])
    whose `other` needs no gradient."""
    return (normals.device.type == "cpu" and other.device.type == "cpu" and normals.dim() == 3
            and normals.shape[-1] == 3 and other.shape[:2] == normals.shape[:2]
            and not other.requires_grad and normals.dtype in (torch.float32, torch.float64))


def normal_loss_fused(rendered: torch.Tensor, prior: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """`losses.normal_loss(rendered, prior, valid)`, differentiable in rendered only."""
    if not normals_apply(rendered, prior) or prior.shape != rendered.shape or valid.shape != rendered.shape[:2]:
        raise ValueError("normal_loss_fused: CPU normal maps [H, W, 3] of one shape, prior without grad")
    r = as_numpy(rendered)
    grad = np.zeros(r.shape, r.dtype)
    total, count = _normal_terms(r, as_numpy(prior), as_numpy(valid.to(torch.bool)), EPS, grad)
    grad *= -1.0 / max(count, 1)
    return loss_with_grad(_FusedNormal, rendered, 1.0 - total / max(count, 1), grad)


def geo_loss_fused(normals: torch.Tensor, depth: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """`losses.geo_consistency_loss(normals, depth, valid)`, differentiable in normals only."""
    if not normals_apply(normals, depth) or depth.dim() != 2 or valid.shape != depth.shape:
        raise ValueError("geo_loss_fused: CPU normals [H, W, 3] with depth and valid [H, W]")
    n = as_numpy(normals)
    grad = np.zeros(n.shape, n.dtype)
    num, den = _geo_terms(n, as_numpy(depth), as_numpy(valid.to(torch.bool)), grad)
    grad *= 1.0 / den if den > 0 else 0.0
    return loss_with_grad(_FusedGeo, normals, num / den if den > 0 else 0.0, grad)
