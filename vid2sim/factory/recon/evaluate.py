"""Held-out evaluation of a splat model (paper protocol: every 8th frame).

Image metrics: PSNR, SSIM (own Gaussian-window SSIM, 'valid' region as skimage), LPIPS only
when the `lpips` package and its AlexNet weights are present locally (else skipped, with the
reason). Geometry metrics (when GT depth is given): depth abs-rel and RMSE of the median and
expected rendered depth, coverage, and the normal angular error against normals from the GT
depth (PCA, same as the prior normals).
Reads: a GaussianModel, Views, optional GT depth maps. Writes nothing.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Optional

import cv2
import numpy as np
import torch

from vid2sim.factory.recon import losses as L
from vid2sim.factory.recon.data import View
from vid2sim.splats.camera import Camera
from vid2sim.splats.model import GaussianModel
from vid2sim.splats.render import render
from vid2sim.splats.types import RasterSettings


def load_gt_depths(folder: Path, views: list[View]) -> dict[int, np.ndarray]:
    """GT depth per view at the view's resolution: `<stem>.png` (uint16 mm, 0 = unknown) or
    `<stem>.npy` (metres), nearest-neighbour downsampled. Views without a file are left out."""
    out = {}
    for v in views:
        stem = Path(v.name).stem
        png, npy = Path(folder) / f"{stem}.png", Path(folder) / f"{stem}.npy"
        if npy.is_file():
            d = np.load(npy).astype(np.float32)
        elif png.is_file():
            d = cv2.imread(str(png), cv2.IMREAD_UNCHANGED).astype(np.float32) / 1000.0
        else:
            continue
        if d.shape != (v.height, v.width):
            d = cv2.resize(d, (v.width, v.height), interpolation=cv2.INTER_NEAREST)
        out[v.index] = d
    return out


def _lpips_fn():
    """(fn, None) when LPIPS can run offline, else (None, reason)."""
    try:
        import lpips
    except ImportError:
        return None, "lpips package not installed"
    hub = Path(torch.hub.get_dir()) / "checkpoints"
    if not any(hub.glob("alexnet-*.pth")):
        return None, f"AlexNet weights absent from {hub} (never downloaded at run time)"

    net = lpips.LPIPS(net="alex", verbose=False).eval()
    return (lambda a, b: float(net(a.permute(2, 0, 1)[None] * 2 - 1, b.permute(2, 0, 1)[None] * 2 - 1))), None


def depth_errors(pred: np.ndarray, gt: np.ndarray) -> dict:
    """pred, gt [H, W] metres (0 = none) -> abs_rel, rmse over pixels where both are > 0."""
    ok = (gt > 0) & (pred > 0)
    if not ok.any():
        return {"abs_rel": float("nan"), "rmse": float("nan"), "coverage": 0.0}
    e = pred[ok] - gt[ok]
    return {"abs_rel": float(np.mean(np.abs(e) / gt[ok])), "rmse": float(np.sqrt(np.mean(e ** 2))),
            "coverage": float(ok.sum() / max((gt > 0).sum(), 1))}


def normal_error_deg(pred: torch.Tensor, gt_depth: np.ndarray, K: np.ndarray, alpha: torch.Tensor) -> float:
    """Mean angle (deg) between rendered normals [H, W, 3] and PCA normals of the GT depth."""
    gt_n, ok = L.normals_from_depth_pca(torch.from_numpy(gt_depth), torch.from_numpy(K))
    ok = ok & (alpha > 0.5) & (pred.norm(dim=-1) > 0)
    if not bool(ok.any()):
        return float("nan")
    cos = (pred[ok] * gt_n[ok]).sum(-1).clamp(-1, 1)
    return float(torch.rad2deg(torch.arccos(cos)).mean())


def _mean(rows: list[dict], key: str) -> Optional[float]:
    vals = [r[key] for r in rows if key in r and r[key] is not None and not math.isnan(r[key])]
    return float(np.mean(vals)) if vals else None


@torch.no_grad()
def evaluate_views(model: GaussianModel, views: list[View], conf, gt_depths: Optional[dict] = None) -> dict:
    """Metrics averaged over `views` (the held-out frames), plus per-frame rows."""
    gt_depths = gt_depths or {}
    if conf.eval_max_frames:
        views = views[: conf.eval_max_frames]
    lpips_fn, lpips_reason = _lpips_fn()
    rows = []
    for v in views:
        cam = Camera.from_cam_to_world(v.K, v.cam_to_world, v.width, v.height)
        settings = RasterSettings(width=v.width, height=v.height, active_sh_degree=model.sh_degree)
        out = render(model, cam, settings, conf.background, conf.backend)
        gt = torch.from_numpy(v.image)
        pred = out.rgb.clamp(0, 1)
        row = {"index": v.index, "psnr": L.psnr(pred, gt),
               "ssim": float(L.ssim_map(pred, gt, same=False).mean())}
        if not v.mask.all():
            row["psnr_static"] = L.psnr(pred, gt, torch.from_numpy(v.mask))
        if lpips_fn is not None:
            row["lpips"] = lpips_fn(pred, gt)
        if v.index in gt_depths:
            gd = gt_depths[v.index]
            for name, d in (("median", out.median_depth), ("expected", out.depth)):
                for k, val in depth_errors(d.numpy(), gd).items():
                    row[f"depth_{name}_{k}"] = val
            row["normal_err_deg"] = normal_error_deg(out.normal, gd, v.K, out.alpha)
        rows.append(row)
    keys = sorted({k for r in rows for k in r if k != "index"})
    metrics = {k: _mean(rows, k) for k in keys}
    metrics["n_test_frames"] = len(rows)
    if lpips_fn is None:
        metrics["lpips"] = None
        metrics["lpips_skipped"] = lpips_reason
    metrics["per_frame"] = rows
    return metrics
