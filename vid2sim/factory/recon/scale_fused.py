"""The flat-Gaussian (scale) loss with a hand-written backward (numba; CPU).

The same loss as `losses.scale_loss`, which stays the reference (tests/test_recon_scale_fused.py
checks value and gradient against it): L = 1/N sum_i exp(min_k log_scales[i, k]); the gradient
1/N exp(m_i) goes to the first smallest axis of each Gaussian, as torch's `min` routes it. torch
spends ~1.5-3 ms per call on an 88k-Gaussian model (the min along the axes with its indices, then
its backward's scatter); one pass that also writes the gradient takes ~0.3-0.8 ms.
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit

from vid2sim.factory.recon.fused_grad import PrecomputedGrad, as_numpy, loss_with_grad


@njit(cache=True)
def _scale_terms(log_scales, grad):
    """sum_i exp(min_k log_scales[i, k]) (float64); grad [N, 3] = exp(m_i) at each row's first
    smallest axis, 0 elsewhere (in log_scales' dtype; the caller divides by N)."""
    total = 0.0
    for i in range(log_scales.shape[0]):
        k, m = 0, log_scales[i, 0]
        if log_scales[i, 1] < m:
            k, m = 1, log_scales[i, 1]
        if log_scales[i, 2] < m:
            k, m = 2, log_scales[i, 2]
        e = np.exp(m)
        total += e
        grad[i, 0] = 0.0
        grad[i, 1] = 0.0
        grad[i, 2] = 0.0
        grad[i, k] = e
    return total


class _FusedScale(PrecomputedGrad):
    """The scale loss's autograd node."""


def scale_applies(log_scales: torch.Tensor) -> bool:
    """The fused loss serves CPU log scales [N, 3] (N > 0) in float32 or float64."""
    return (log_scales.device.type == "cpu" and log_scales.dim() == 2 and log_scales.shape[1] == 3
            and log_scales.shape[0] > 0 and log_scales.dtype in (torch.float32, torch.float64))


def scale_loss_fused(log_scales: torch.Tensor) -> torch.Tensor:
    """`losses.scale_loss(log_scales)`, log_scales [N, 3] -> scalar."""
    if not scale_applies(log_scales):
        raise ValueError(f"scale_loss_fused: CPU log scales [N, 3] (N > 0), got {tuple(log_scales.shape)} "
                         f"{log_scales.dtype} on {log_scales.device}")
    ls = as_numpy(log_scales)
    grad = np.empty(ls.shape, ls.dtype)
    n = ls.shape[0]
    total = _scale_terms(ls, grad)
    grad *= ls.dtype.type(1.0 / n)
    return loss_with_grad(_FusedScale, log_scales, total / n, grad)
