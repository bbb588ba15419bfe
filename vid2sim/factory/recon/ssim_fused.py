"""SSIM map with a hand-written backward, for the training loss (numba; float32, CPU).

The same map as `losses.ssim_map(pred, gt)` (11-tap Gaussian window, sigma 1.5, zero padding,
channel mean), which stays the reference: tests/test_recon_ssim_fused.py checks that the two
agree in value and gradient. torch builds the reference from two grouped convolutions over five
moment images and keeps about twenty intermediate images for autograd; here one call blurs the
moments and forms the map, and the backward blurs three images per channel:

  S = A1 A2 / (B1 B2),  A1 = 2 mx my + C1,  A2 = 2 (Exy - mx my) + C2,
                        B1 = mx^2 + my^2 + C1,  B2 = Exx - mx^2 + Eyy - my^2 + C2,
  with mx = G * x, Exx = G * x^2, Exy = G * xy (and the same for y, the target, held fixed);
  dL/dx = G * (dS dS/dmx) + 2 x G * (dS dS/dExx) + y G * (dS dS/dExy)

(G * is the zero-padded blur; with a symmetric window it is its own adjoint.)
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import torch
from numba import njit, prange

C1, C2 = np.float32(0.01 ** 2), np.float32(0.03 ** 2)
WINDOW, SIGMA = 11, 1.5  # losses.ssim_map's defaults


def gaussian_window_1d(size: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Normalised 1D Gaussian [size]: the SSIM window of this module and of `losses.ssim_map`."""
    x = torch.arange(size, dtype=torch.float32) - (size - 1) / 2
    g = torch.exp(-(x ** 2) / (2 * sigma ** 2))
    return g / g.sum()


@lru_cache(maxsize=1)
def _taps() -> np.ndarray:
    """The window [WINDOW] as float32 numpy."""
    return gaussian_window_1d(WINDOW, SIGMA).numpy().astype(np.float32)


@njit(cache=True, fastmath=True)
def _blur_plane(src, g, pad, tmp, dst):
    """dst [H, W] = separable zero-padded blur of src [H, W] with the window g [K] (K odd);
    pad [W + K - 1] and tmp [H, W] are scratch. Each row is copied into the zero-padded pad
    first, so every tap's inner loop runs over the whole row at a fixed offset (vectorised)."""
    h, w = src.shape
    k_n = g.shape[0]
    r = k_n // 2
    pad[:] = 0.0
    for i in range(h):
        pad[r:r + w] = src[i]
        trow = tmp[i]
        trow[:] = 0.0
        for k in range(k_n):
            gk = g[k]
            seg = pad[k:k + w]
            for j in range(w):
                trow[j] += gk * seg[j]
    for i in range(h):
        drow = dst[i]
        drow[:] = 0.0
        for k in range(k_n):
            s = i + k - r
            if s < 0 or s >= h:
                continue
            gk = g[k]
            trow = tmp[s]
            for j in range(w):
                drow[j] += gk * trow[j]


@njit(cache=True, parallel=True, fastmath=True)
def _blur(stack, g):
    """Blur every plane of stack [P, H, W] (planes in parallel)."""
    out = np.empty_like(stack)
    for p in prange(stack.shape[0]):
        pad = np.empty(stack.shape[2] + g.shape[0] - 1, np.float32)
        tmp = np.empty_like(stack[p])
        _blur_plane(stack[p], g, pad, tmp, out[p])
    return out


@njit(cache=True, parallel=True, fastmath=True)
def _moments(x, y):
    """x, y [C, H, W] -> the five moment images [5C, H, W]: x, y, x^2, y^2, xy (rows in parallel)."""
    c, h, w = x.shape
    st = np.empty((5 * c, h, w), np.float32)
    for i in prange(h):
        for q in range(c):
            for j in range(w):
                a, b = x[q, i, j], y[q, i, j]
                st[q, i, j] = a
                st[c + q, i, j] = b
                st[2 * c + q, i, j] = a * a
                st[3 * c + q, i, j] = b * b
                st[4 * c + q, i, j] = a * b
    return st


@njit(cache=True, parallel=True, fastmath=True)
def _ssim_terms(m, c):
    """From the blurred moments m [5C, H, W]: the map [H, W] (channel mean) and, per channel,
    the partial derivatives of S by mx, Exx and Exy, [3, C, H, W] (rows in parallel; each
    pixel sums its channels in order, so the map does not depend on the threads)."""
    _, h, w = m.shape
    out = np.zeros((h, w), np.float32)
    dd = np.empty((3, c, h, w), np.float32)
    inv_c = np.float32(1.0 / c)
    for i in prange(h):
        for q in range(c):
            for j in range(w):
                mx, my = m[q, i, j], m[c + q, i, j]
                exx, eyy, exy = m[2 * c + q, i, j], m[3 * c + q, i, j], m[4 * c + q, i, j]
                a1 = 2.0 * mx * my + C1
                a2 = 2.0 * (exy - mx * my) + C2
                b1 = mx * mx + my * my + C1
                b2 = (exx - mx * mx) + (eyy - my * my) + C2
                inv = 1.0 / (b1 * b2)
                s = a1 * a2 * inv
                out[i, j] += s * inv_c
                dd[0, q, i, j] = 2.0 * my * (a2 - a1) * inv - s * 2.0 * mx * (1.0 / b1 - 1.0 / b2)
                dd[1, q, i, j] = -s / b2
                dd[2, q, i, j] = 2.0 * a1 * inv
    return out, dd


@njit(cache=True, parallel=True, fastmath=True)
def _grad_fields(dd, dmap, c):
    """Scale the partials by the upstream gradient of the map (dmap [H, W], shared by the C
    channels through the mean): [3C, H, W] ready to blur (rows in parallel)."""
    _, _, h, w = dd.shape
    f = np.empty((3 * c, h, w), np.float32)
    inv_c = np.float32(1.0 / c)
    for i in prange(h):
        for t in range(3):
            for q in range(c):
                for j in range(w):
                    f[t * c + q, i, j] = dd[t, q, i, j] * dmap[i, j] * inv_c
    return f


@njit(cache=True, parallel=True, fastmath=True)
def _grad_x(b, x, y, c):
    """dL/dx [C, H, W] from the blurred fields b [3C, H, W] (mx, Exx, Exy parts; rows in parallel)."""
    _, h, w = x.shape
    g = np.empty_like(x)
    for i in prange(h):
        for q in range(c):
            for j in range(w):
                g[q, i, j] = (b[q, i, j] + np.float32(2.0) * x[q, i, j] * b[c + q, i, j]
                              + y[q, i, j] * b[2 * c + q, i, j])
    return g


class _FusedSSIM(torch.autograd.Function):
    @staticmethod
    def forward(ctx, pred, gt):
        x = np.ascontiguousarray(pred.detach().permute(2, 0, 1).numpy())  # [C, H, W]
        y = np.ascontiguousarray(gt.detach().permute(2, 0, 1).numpy())
        taps = _taps()
        m = _blur(_moments(x, y), taps)
        smap, dd = _ssim_terms(m, x.shape[0])
        ctx.saved = (x, y, dd, taps)
        return torch.from_numpy(smap)

    @staticmethod
    def backward(ctx, dmap):
        x, y, dd, taps = ctx.saved
        c = x.shape[0]
        fields = _blur(_grad_fields(dd, np.ascontiguousarray(dmap.numpy(), np.float32), c), taps)
        g = torch.from_numpy(_grad_x(fields, x, y, c)).permute(1, 2, 0)  # [H, W, C]
        return g, None


def fused_applies(pred: torch.Tensor, gt: torch.Tensor) -> bool:
    """The fused map serves float32 CPU images [H, W, C] whose target needs no gradient."""
    return (pred.dtype == torch.float32 and gt.dtype == torch.float32 and pred.device.type == "cpu"
            and gt.device.type == "cpu" and pred.dim() == 3 and pred.shape == gt.shape
            and not gt.requires_grad)


def ssim_map_fused(pred: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """`losses.ssim_map(pred, gt)` ([H, W, C] in [0, 1] -> [H, W], zero padding), differentiable
    in pred only; float32 CPU tensors (see `fused_applies`)."""
    if not fused_applies(pred, gt):
        raise ValueError("ssim_map_fused: float32 CPU images [H, W, C] of one shape, target without grad")
    return _FusedSSIM.apply(pred, gt)
