"""The patch-NCC depth loss with a hand-written backward, for the training loss (numba; CPU).

The same loss as `losses.ncc_depth_loss` (K x K patches every `stride` pixels, per-patch Pearson
correlation over the valid pixels, patches with too few valid pixels or a flat prior left out),
which stays the reference: tests/test_recon_ncc_fused.py checks that the two agree in value and
gradient. torch builds the reference from three unfolded [K^2, P] copies and about fifteen
intermediate arrays for autograd (~4 ms per 320x150 view, forward and backward, one thread);
here one pass over the patches forms each correlation and its gradient (~2 ms; sums in
float64, the gradient in the map's own dtype). Per patch p with valid pixels k (n of them),
rendered depth r, prior d:

  ncc_p = sum_k (r_k - mr)(d_k - md) / (n s_r s_d),  s^2 = sum_k (x_k - mx)^2 / n + eps
  d ncc_p / d r_k = ((d_k - md) / s_d - ncc_p (r_k - mr) / s_r) / (n s_r)

(the mean's own derivative drops out: the centred values sum to 0), and the loss is
1 - mean over kept patches of ncc_p.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit, prange

from vid2sim.factory.recon.fused_grad import PrecomputedGrad, as_numpy, loss_with_grad, ordered_sums


@njit(cache=True, parallel=True)
def _ncc_patches(r, d, m, patch, stride, min_valid, eps, grad):
    """Sum of the kept patches' correlations and their count; grad [H, W] (zeroed by the caller)
    accumulates the sum of d ncc_p / d r over the kept patches. Rows of patches run in parallel,
    in phases whose rows' pixels do not overlap (rows p, p + phases, ...: patch <= phases x
    stride); per-row sums are added in row order, so the result does not depend on the threads."""
    H, W = r.shape
    n_rows = max((H - patch) // stride + 1, 0)
    phases = -(-patch // stride)  # ceil: rows that far apart share no pixel
    row_total = np.zeros(n_rows)
    row_kept = np.zeros(n_rows, np.int64)
    for phase in range(phases):
        for k in prange((n_rows - phase + phases - 1) // phases):
            row = phase + k * phases
            row_total[row], row_kept[row] = _ncc_row(r, d, m, row * stride, patch, stride, min_valid, eps,
                                                     grad)
    return ordered_sums(row_total, row_kept)


@njit(cache=True)
def _ncc_row(r, d, m, i0, patch, stride, min_valid, eps, grad):
    """The patches of one row (top at i0): (sum of kept correlations, kept); adds their gradient."""
    W = r.shape[1]
    total, kept = 0.0, 0
    need = min_valid * patch * patch
    for j0 in range(0, W - patch + 1, stride):
        n, sr, sd = 0, 0.0, 0.0
        for i in range(i0, i0 + patch):
            for j in range(j0, j0 + patch):
                if m[i, j]:
                    n += 1
                    sr += r[i, j]
                    sd += d[i, j]
        ns = max(n, 1)
        mr, md = sr / ns, sd / ns
        vr, vd, cv = 0.0, 0.0, 0.0
        for i in range(i0, i0 + patch):
            for j in range(j0, j0 + patch):
                if m[i, j]:
                    a, b = r[i, j] - mr, d[i, j] - md
                    vr += a * a
                    vd += b * b
                    cv += a * b
        if n < need or not math.sqrt(vd / ns) > 1e-4 * max(abs(md), 1e-6):
            continue
        s_r, s_d = math.sqrt(vr / ns + eps), math.sqrt(vd / ns + eps)
        ncc = cv / ns / (s_r * s_d)
        total += ncc
        kept += 1
        scale = 1.0 / (ns * s_r)
        for i in range(i0, i0 + patch):
            for j in range(j0, j0 + patch):
                if m[i, j]:
                    grad[i, j] += ((d[i, j] - md) / s_d - ncc * (r[i, j] - mr) / s_r) * scale
    return total, kept


class _FusedNCC(PrecomputedGrad):
    """The patch-NCC depth loss's autograd node."""


def ncc_applies(rendered: torch.Tensor, prior: torch.Tensor) -> bool:
    """The fused loss serves CPU depth maps [H, W] of one shape whose prior needs no gradient."""
    return (rendered.device.type == "cpu" and prior.device.type == "cpu" and rendered.dim() == 2
            and rendered.shape == prior.shape and not prior.requires_grad
            and rendered.dtype in (torch.float32, torch.float64))


def ncc_depth_loss_fused(rendered: torch.Tensor, prior: torch.Tensor, valid: torch.Tensor,
                         patch: int = 8, stride: int = 4, min_valid: float = 0.8,
                         eps: float = 1e-6) -> torch.Tensor:
    """`losses.ncc_depth_loss(rendered, prior, valid, ...)` (a scalar in [0, 2]; 0 when no patch
    qualifies), differentiable in rendered only; CPU tensors (see `ncc_applies`)."""
    if not ncc_applies(rendered, prior) or valid.shape != rendered.shape:
        raise ValueError("ncc_depth_loss_fused: CPU depth maps [H, W] of one shape, prior without grad")
    r = as_numpy(rendered)
    grad = np.zeros(r.shape, r.dtype)
    total, kept = _ncc_patches(r, as_numpy(prior.to(rendered.dtype)), as_numpy(valid.to(torch.bool)),
                               int(patch), int(stride), float(min_valid), float(eps), grad)
    grad *= -1.0 / max(kept, 1)
    return loss_with_grad(_FusedNCC, rendered, 1.0 - total / kept if kept else 0.0, grad)
