"""Reconstruction losses (paper Sec. 3.1): pure functions of tensors, images as [H, W, C].

rgb:    (1 - l) L1 + l (1 - SSIM), l = 0.2, dynamic pixels (mask 0) excluded.
depth:  patch NCC between rendered and prior depth, mean and std taken per patch.
normal: 1 - cosine between rendered normals and prior normals (PCA on back-projected points).
geo:    neighbour-normal agreement (right and bottom) weighted by 1 - |grad D|.
scale:  mean over Gaussians of the smallest scale (flat, 2DGS-like splats).
"""

from __future__ import annotations

import math
from typing import Optional

import torch
import torch.nn.functional as F

from vid2sim.factory.recon.ncc_fused import ncc_applies, ncc_depth_loss_fused
from vid2sim.factory.recon.normals_fused import geo_loss_fused, normal_loss_fused, normals_apply
from vid2sim.factory.recon.scale_fused import scale_applies, scale_loss_fused
from vid2sim.factory.recon.ssim_fused import fused_applies, gaussian_window_1d, ssim_map_fused


# ----------------------------------------------------------------------------- SSIM

def gaussian_window(size: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Normalised 2D Gaussian window [size, size] (outer product of the 1D one)."""
    g = gaussian_window_1d(size, sigma)
    return g[:, None] * g[None, :]


def ssim_map(img1: torch.Tensor, img2: torch.Tensor, window: int = 11, sigma: float = 1.5,
             same: bool = True) -> torch.Tensor:
    """Per-pixel SSIM (Wang et al. 2004, C1=0.01^2, C2=0.03^2, data range 1), channel mean.

    img1, img2 [H, W, C] in [0, 1] -> [H, W] (same=True, zero padding as 3DGS)
    or [H - window + 1, W - window + 1] (same=False, the 'valid' region as skimage).
    """
    c = img1.shape[-1]
    x = img1.permute(2, 0, 1)[None]  # [1, C, H, W]
    y = img2.permute(2, 0, 1)[None]
    # The Gaussian window is separable: one horizontal and one vertical 1D pass over all
    # five moment images at once (same result as the 2D window, ~5x fewer operations).
    g = gaussian_window_1d(window, sigma).to(x)
    stack = torch.cat([x, y, x * x, y * y, x * y], dim=1)  # [1, 5C, H, W]
    n = stack.shape[1]
    pad = window // 2 if same else 0
    out = F.conv2d(stack, g.view(1, 1, 1, -1).expand(n, 1, 1, window), padding=(0, pad), groups=n)
    out = F.conv2d(out, g.view(1, 1, -1, 1).expand(n, 1, window, 1), padding=(pad, 0), groups=n)
    mu_x, mu_y, exx, eyy, exy = out.split(c, dim=1)
    sxx = exx - mu_x ** 2
    syy = eyy - mu_y ** 2
    sxy = exy - mu_x * mu_y
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    num = (2 * mu_x * mu_y + c1) * (2 * sxy + c2)
    den = (mu_x ** 2 + mu_y ** 2 + c1) * (sxx + syy + c2)
    return (num / den)[0].mean(0)  # [H', W']


def _masked_mean(values: torch.Tensor, mask: Optional[torch.Tensor]) -> torch.Tensor:
    """values [H, W, ...], mask [H, W] (1 keep, 0 drop) -> scalar."""
    if mask is None:
        return values.mean()
    m = mask.to(values.dtype)
    while m.dim() < values.dim():
        m = m[..., None]
    m = m.expand_as(values)
    return (values * m).sum() / m.sum().clamp_min(1.0)


def rgb_loss(pred: torch.Tensor, gt: torch.Tensor, mask: Optional[torch.Tensor] = None,
             lambda_dssim: float = 0.2) -> torch.Tensor:
    """(1 - l) * L1 + l * (1 - SSIM) over static pixels.

    pred, gt [H, W, 3]; mask [H, W] with 1 = static (used), 0 = dynamic (excluded). The SSIM
    map comes from ssim_fused.py (the same map, a hand-written backward) for float32 CPU
    images, from `ssim_map` otherwise.
    """
    l1 = _masked_mean((pred - gt).abs(), mask)
    smap = ssim_map_fused(pred, gt) if fused_applies(pred, gt) else ssim_map(pred, gt)
    dssim = 1.0 - _masked_mean(smap, mask)
    return (1.0 - lambda_dssim) * l1 + lambda_dssim * dssim


# ----------------------------------------------------------------------------- depth NCC

def ncc_depth_loss(rendered: torch.Tensor, prior: torch.Tensor, valid: Optional[torch.Tensor] = None,
                   patch: int = 8, stride: int = 4, min_valid: float = 0.8,
                   eps: float = 1e-6, fused: bool = True) -> torch.Tensor:
    """Patch NCC loss  1 - 1/|P| sum_p 1/K^2 sum_k D^'_pk D'_pk / (sigma^_p sigma_p).

    rendered, prior [H, W]; valid [H, W] (bool/0-1; None = all valid).
    Means and (population) standard deviations are taken per K x K patch over its valid
    pixels, so each patch score is its Pearson correlation in [-1, 1]. (The paper's sum over
    k must carry this 1/K^2 for the loss to stay in [0, 2].) Patches with fewer than
    `min_valid` valid pixels, or with a flat prior, are left out. Returns a scalar in [0, 2]
    (0 when no patch qualifies). CPU maps go through ncc_fused.py (the same loss in one pass, a
    hand-written backward) unless `fused` is False: this torch code is its reference.
    """
    h, w = rendered.shape
    if valid is None:
        valid = torch.ones_like(rendered, dtype=torch.bool)
    if fused and ncc_applies(rendered, prior):
        return ncc_depth_loss_fused(rendered, prior, valid, patch, stride, min_valid, eps)

    def unfold(t: torch.Tensor) -> torch.Tensor:  # [K^2, P]
        return F.unfold(t.reshape(1, 1, h, w).to(rendered.dtype), patch, stride=stride)[0]

    d_hat, d, m = unfold(rendered), unfold(prior), unfold(valid.float())
    n = m.sum(0)  # [P]
    n_safe = n.clamp_min(1.0)
    mu_hat = (m * d_hat).sum(0) / n_safe
    mu = (m * d).sum(0) / n_safe
    c_hat = (d_hat - mu_hat) * m  # mean-centred, [K^2, P]
    c = (d - mu) * m
    sigma_hat = torch.sqrt((c_hat ** 2).sum(0) / n_safe + eps)
    sigma = torch.sqrt((c ** 2).sum(0) / n_safe + eps)
    ncc = (c_hat * c).sum(0) / n_safe / (sigma_hat * sigma)  # [P]
    prior_std = torch.sqrt((c ** 2).sum(0) / n_safe)
    keep = (n >= min_valid * patch * patch) & (prior_std > 1e-4 * mu.abs().clamp_min(1e-6))
    if not bool(keep.any()):
        return rendered.sum() * 0.0
    return 1.0 - ncc[keep].mean()


# ----------------------------------------------------------------------------- normals

def backproject(depth: torch.Tensor, K: torch.Tensor) -> torch.Tensor:
    """depth [H, W] (camera z), K [3, 3] -> camera-frame points [H, W, 3] (OpenCV axes,
    pixel centres at j + 0.5, i + 0.5)."""
    h, w = depth.shape
    i, j = torch.meshgrid(torch.arange(h, dtype=depth.dtype), torch.arange(w, dtype=depth.dtype),
                          indexing="ij")
    x = (j + 0.5 - K[0, 2]) / K[0, 0]
    y = (i + 0.5 - K[1, 2]) / K[1, 1]
    return torch.stack([x * depth, y * depth, depth], -1)


def normals_from_depth_pca(depth: torch.Tensor, K: torch.Tensor, window: int = 5,
                           valid: Optional[torch.Tensor] = None, rel_tol: float = 0.15,
                           ) -> tuple[torch.Tensor, torch.Tensor]:
    """Pseudo-GT normals by PCA on back-projected points (paper), camera frame.

    For every pixel the points of its `window` x `window` neighbourhood whose depth is within
    `rel_tol` (relative) of the centre's are taken; the normal is the eigenvector of their
    covariance with the smallest eigenvalue, flipped to face the camera.
    depth [H, W], K [3, 3], valid [H, W] -> normals [H, W, 3] (unit; 0 where invalid), ok [H, W] bool.
    """
    h, w = depth.shape
    depth = depth.to(torch.float32)
    if valid is None:
        valid = depth > 0
    valid = valid & (depth > 0)
    pts = backproject(depth, K.to(torch.float32))  # [H, W, 3]
    pad = window // 2

    def unf(t: torch.Tensor) -> torch.Tensor:  # [C*k2, HW]
        return F.unfold(t.permute(2, 0, 1)[None], window, padding=pad)[0]

    k2 = window * window
    nb = unf(pts).reshape(3, k2, h * w) - pts.reshape(-1, 3).T[:, None]  # [3, k2, HW] centre-relative
    nb_d = unf(depth[..., None]).reshape(k2, h * w)
    nb_ok = unf(valid[..., None].to(torch.float32)).reshape(k2, h * w) > 0
    centre = depth.reshape(-1)
    wgt = (nb_ok & ((nb_d - centre).abs() <= rel_tol * centre)).to(torch.float32)  # [k2, HW]
    cnt = wgt.sum(0)  # [HW]
    ok = valid.reshape(-1) & (cnt >= max(3, k2 // 2))
    at = ok.nonzero()[:, 0]  # [P] the pixels that get a normal
    nb, wgt, cnt, centre = nb[:, :, at], wgt[:, at], cnt[at], centre[at]
    mean = (nb * wgt).sum(1) / cnt  # [3, P]
    diff = (nb - mean[:, None]) * wgt.sqrt()  # [3, k2, P]
    cov = torch.einsum("akp,bkp->pab", diff, diff) / cnt[:, None, None]  # [P, 3, 3]
    cov = cov + torch.eye(3, dtype=cov.dtype) * 1e-10 * centre[:, None, None] ** 2
    _, vecs = torch.linalg.eigh(cov)
    n_at = vecs[:, :, 0]  # [P, 3] smallest-eigenvalue direction
    flip = (n_at * pts.reshape(-1, 3)[at]).sum(-1) > 0
    n = torch.zeros(h * w, 3, dtype=n_at.dtype)
    n[at] = torch.where(flip[:, None], -n_at, n_at)
    return n.reshape(h, w, 3).float(), ok.reshape(h, w)


def normal_loss(rendered: torch.Tensor, prior: torch.Tensor,
                valid: Optional[torch.Tensor] = None, fused: bool = True) -> torch.Tensor:
    """1 - mean cosine(rendered, prior) over valid pixels.

    rendered, prior [H, W, 3] (camera frame, any length); valid [H, W]. CPU maps go through
    normals_fused.py unless `fused` is False: this torch code is its reference.
    """
    if fused and valid is not None and prior.shape == rendered.shape and normals_apply(rendered, prior):
        return normal_loss_fused(rendered, prior, valid)
    cos = F.cosine_similarity(rendered, prior, dim=-1, eps=1e-8)  # [H, W]
    return 1.0 - _masked_mean(cos, valid)


def depth_edge_weights(depth: torch.Tensor) -> torch.Tensor:
    """w_ij = clamp(1 - ||(grad_x D, grad_y D)||, 0, 1) with forward differences.

    depth [H, W] -> [H-1, W-1] (pixels that have both a right and a bottom neighbour).
    """
    gx = depth[:-1, 1:] - depth[:-1, :-1]
    gy = depth[1:, :-1] - depth[:-1, :-1]
    return (1.0 - torch.sqrt(gx ** 2 + gy ** 2)).clamp(0.0, 1.0)


def geo_consistency_loss(normals: torch.Tensor, depth: torch.Tensor,
                         valid: Optional[torch.Tensor] = None, fused: bool = True) -> torch.Tensor:
    """Geometry-consistency loss: sum w (1 - N_ij . N_nb) / sum w over right and bottom nb.

    normals [H, W, 3] (rendered, unit), depth [H, W] the map the weights come from (the trainer
    passes log prior depth, so |grad D| is the relative depth change and scale-free),
    valid [H, W]. Each pixel's term is the mean over its right and bottom neighbours. CPU maps
    go through normals_fused.py unless `fused` is False: this torch code is its reference.
    """
    if fused and valid is not None and depth.dim() == 2 and normals_apply(normals, depth):
        return geo_loss_fused(normals, depth, valid)
    n = normals[:-1, :-1]
    dots = 0.5 * ((n * normals[:-1, 1:]).sum(-1) + (n * normals[1:, :-1]).sum(-1))  # [H-1, W-1]
    w = depth_edge_weights(depth.detach())
    if valid is not None:
        v = valid[:-1, :-1] & valid[:-1, 1:] & valid[1:, :-1]
        w = w * v.to(w.dtype)
    den = w.sum()
    if float(den) <= 0:
        return normals.sum() * 0.0
    return (w * (1.0 - dots)).sum() / den


def scale_loss(log_scales: torch.Tensor, fused: bool = True) -> torch.Tensor:
    """Flat-Gaussian loss: 1/N sum_i min(s_i1, s_i2, s_i3). log_scales [N, 3] -> scalar.

    exp is increasing, so the smallest scale is exp of the smallest log scale: one exp per
    Gaussian instead of three (the same value and gradient). CPU log scales go through
    scale_fused.py (one pass that also writes the gradient) unless `fused` is False: this torch
    code is its reference."""
    if fused and scale_applies(log_scales):
        return scale_loss_fused(log_scales)
    if log_scales.shape[0] == 0:
        return log_scales.sum() * 0.0
    return torch.exp(log_scales.min(dim=1).values).mean()


def psnr(pred: torch.Tensor, gt: torch.Tensor, mask: Optional[torch.Tensor] = None) -> float:
    """PSNR in dB for images in [0, 1]; [H, W, C], optional mask [H, W]."""
    mse = float(_masked_mean((pred.clamp(0, 1) - gt) ** 2, mask))
    return float("inf") if mse <= 0 else -10.0 * math.log10(mse)
