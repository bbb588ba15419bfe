"""The render's finish as one numba pass with a hand-written backward (float32, CPU).

Reads a backend's raw accumulations (colour, alpha, depth, normal) and writes what
`render.finish_reference` writes with torch ops, which stays the reference
(tests/test_splats_finish.py checks value and gradient):

  rgb    = C + (1 - a) bg
  depth  = D / max(a, 1e-6) where a > 0, else 0
  normal = N / max(|N|, 1e-12) where a > 0 and |N| > 0, else 0

The backward follows torch's rules at the clamps (no gradient through max(a, 1e-6) below
1e-6, nor through max(|N|, 1e-12) below 1e-12). One pass each way instead of about ten torch
ops and their autograd nodes: the training loop calls it once per iteration.
"""

from __future__ import annotations

import numpy as np
import torch
from numba import njit, prange

F32 = np.float32
ZERO, ONE = F32(0.0), F32(1.0)
EPS_A, EPS_N = F32(1e-6), F32(1e-12)


@njit(cache=True, inline="always")
def _put3(out, i, j, x, y, z):
    """out[i, j, :] = (x, y, z)."""
    out[i, j, 0] = x
    out[i, j, 1] = y
    out[i, j, 2] = z


@njit(cache=True, error_model="numpy", parallel=True)
def _forward(C, a, D, N, bg, rgb, depth, normal):
    """C, N [H, W, 3], a, D [H, W], bg [3] -> rgb, normal [H, W, 3], depth [H, W] (rows in parallel)."""
    h, w = a.shape
    for i in prange(h):
        for j in range(w):
            al = a[i, j]
            om = ONE - al
            for c in range(3):
                rgb[i, j, c] = C[i, j, c] + om * bg[c]
            covered = al > ZERO
            depth[i, j] = D[i, j] / max(al, EPS_A) if covered else ZERO
            nx, ny, nz = N[i, j, 0], N[i, j, 1], N[i, j, 2]
            n = np.sqrt(nx * nx + ny * ny + nz * nz)
            if covered and n > ZERO:
                m = max(n, EPS_N)
                _put3(normal, i, j, nx / m, ny / m, nz / m)
            else:
                _put3(normal, i, j, ZERO, ZERO, ZERO)


@njit(cache=True, error_model="numpy", parallel=True)
def _backward(a, D, N, bg, g_rgb, g_depth, g_normal, dC, da, dD, dN):
    """Gradients of C, a, D, N from those of rgb, depth, normal (rows in parallel)."""
    h, w = a.shape
    for i in prange(h):
        for j in range(w):
            al = a[i, j]
            gr0, gr1, gr2 = g_rgb[i, j, 0], g_rgb[i, j, 1], g_rgb[i, j, 2]
            _put3(dC, i, j, gr0, gr1, gr2)
            ga = -(gr0 * bg[0] + gr1 * bg[1] + gr2 * bg[2])
            covered = al > ZERO
            gd = g_depth[i, j]
            if covered:
                ca = max(al, EPS_A)
                dD[i, j] = gd / ca
                if al >= EPS_A:
                    ga -= gd * D[i, j] / (ca * ca)
            else:
                dD[i, j] = ZERO
            da[i, j] = ga
            nx, ny, nz = N[i, j, 0], N[i, j, 1], N[i, j, 2]
            n = np.sqrt(nx * nx + ny * ny + nz * nz)
            gx, gy, gz = g_normal[i, j, 0], g_normal[i, j, 1], g_normal[i, j, 2]
            if covered and n > ZERO:
                m = max(n, EPS_N)
                if n >= EPS_N:  # d(N / |N|) = (g - u (u . g)) / |N|, u = N / |N|
                    ux, uy, uz = nx / n, ny / n, nz / n
                    ug = ux * gx + uy * gy + uz * gz
                    _put3(dN, i, j, (gx - ux * ug) / n, (gy - uy * ug) / n, (gz - uz * ug) / n)
                else:  # the clamp holds the length: N / 1e-12
                    _put3(dN, i, j, gx / m, gy / m, gz / m)
            else:
                _put3(dN, i, j, ZERO, ZERO, ZERO)


def _np(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().numpy())


class _Finish(torch.autograd.Function):
    @staticmethod
    def forward(ctx, color, alpha, depth_acc, normal_acc, bg):
        C, a, D, N, b = (_np(t) for t in (color, alpha, depth_acc, normal_acc, bg))
        rgb, normal = np.empty_like(C), np.empty_like(N)
        depth = np.empty_like(a)
        _forward(C, a, D, N, b, rgb, depth, normal)
        ctx.saved = (a, D, N, b)
        return torch.from_numpy(rgb), torch.from_numpy(depth), torch.from_numpy(normal)

    @staticmethod
    def backward(ctx, g_rgb, g_depth, g_normal):
        a, D, N, b = ctx.saved
        grads = [np.zeros(s, np.float32) if g is None else _np(g)
                 for g, s in ((g_rgb, N.shape), (g_depth, a.shape), (g_normal, N.shape))]
        dC, dN = np.empty_like(N), np.empty_like(N)
        da, dD = np.empty_like(a), np.empty_like(a)
        _backward(a, D, N, b, *grads, dC, da, dD, dN)
        return (torch.from_numpy(dC), torch.from_numpy(da), torch.from_numpy(dD), torch.from_numpy(dN),
                None)


def fused_applies(*images: torch.Tensor) -> bool:
    """The fused finish serves float32 CPU images."""
    return all(t.dtype == torch.float32 and t.device.type == "cpu" for t in images)


def finish_images(color: torch.Tensor, alpha: torch.Tensor, depth_acc: torch.Tensor, normal_acc: torch.Tensor,
                  bg: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(rgb [H, W, 3], depth [H, W], normal [H, W, 3]) from the raw images and the background
    bg [3]; differentiable in the four raw images (float32 CPU tensors, see `fused_applies`)."""
    if not fused_applies(color, alpha, depth_acc, normal_acc):
        raise ValueError("finish_images: float32 CPU images")
    return _Finish.apply(color, alpha, depth_acc, normal_acc, bg.detach().to(torch.float32))
