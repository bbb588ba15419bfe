"""Stage `recon`: geometry-consistent Gaussian-splat training of one PosedClip.

work(conf, posed_clip_dir) -> StageWork, run by `runtime/runner.run_stage(work, out_dir)`.
Reads:  a PosedClip folder (cameras.parquet, points.npz, frame.json, images, masks).
Writes: out_dir/splats.ply (3DGS PLY), metrics.json (held-out PSNR/SSIM[/LPIPS], depth and
        normal error when GT depth is known, counts, time), config.json (the ReconConfig),
        prior.npz (cached depth prior), checkpoint.pt (resume); the runner adds stage.json.
A re-run with the same config and inputs is skipped; a killed run resumes from checkpoint.pt.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import cv2
import numpy as np
import torch

from vid2sim.factory.sfm.posed import PosedClip
from vid2sim.factory.recon import losses as L
from vid2sim.factory.recon.config import ReconConfig
from vid2sim.factory.recon.data import OUTPUTS, STAGE, STAGE_VERSION, View, downscale_view, load_views, scene_extent
from vid2sim.factory.recon.densify import DensifyStats, densify_and_prune, prune_only, reset_opacity
from vid2sim.factory.recon.depth_prior import DepthPrior, estimate_priors
from vid2sim.factory.recon.evaluate import evaluate_views, load_gt_depths
from vid2sim.factory.recon.params import SplatParams
from vid2sim.factory.runtime.stage_cache import StageError, StageWork, Timer, input_key, stage_key
from vid2sim.splats.camera import Camera
from vid2sim.splats.model import GaussianModel
from vid2sim.splats.ply import write_ply
from vid2sim.splats.render import render
from vid2sim.splats.types import RasterSettings
from vid2sim.threads import torch_threads
from vid2sim.versioning import config_hash

CHECKPOINT = "checkpoint.pt"


# ----------------------------------------------------------------------------- inputs

def check_posed_dir(posed_clip_dir: Path) -> Path:
    """The folder, or StageError `bad_posed_clip` naming the PosedClip file it lacks."""
    d = Path(posed_clip_dir)
    for name in ("cameras.parquet", "points.npz", "frame.json"):
        if not (d / name).is_file():
            raise StageError(STAGE, "bad_posed_clip", f"{d} lacks {name}")
    return d


@dataclass
class PriorTensors:
    """Per training view: prior depth [H, W], confidence [H, W], normals [H, W, 3], ok [H, W]."""

    depth: torch.Tensor
    conf: torch.Tensor
    normal: torch.Tensor
    normal_ok: torch.Tensor


def load_or_estimate_priors(conf: ReconConfig, views: list[View], points: np.ndarray,
                            out_dir: Path) -> dict[int, DepthPrior]:
    """Depth priors, cached in out_dir/prior.npz (keyed by the prior config)."""
    path = Path(out_dir) / "prior.npz"
    key = config_hash(conf.prior, conf.max_width)
    if path.is_file():
        data = np.load(path)
        if str(data["key"]) == key:
            idx = data["index"]
            return {int(i): DepthPrior(data["depth"][k], data["conf"][k]) for k, i in enumerate(idx)}
    priors = estimate_priors(conf.prior, views, points, threads=torch.get_num_threads())  # the stage's CPUs
    if priors:
        idx = sorted(priors)
        tmp = path.with_name("prior.tmp.npz")
        np.savez_compressed(tmp, key=key, index=np.array(idx),
                            depth=np.stack([priors[i].depth for i in idx]),
                            conf=np.stack([priors[i].confidence for i in idx]))
        os.replace(tmp, path)
    return priors


def prior_tensors(prior: DepthPrior, view: View, window: int) -> PriorTensors:
    """The prior at the view's resolution (nearest-neighbour when the view is smaller)."""
    depth_np, conf_np = prior.depth, prior.confidence
    if depth_np.shape != (view.height, view.width):
        size = (view.width, view.height)
        depth_np = cv2.resize(depth_np, size, interpolation=cv2.INTER_NEAREST)  # [h, w]
        conf_np = cv2.resize(conf_np.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    depth = torch.from_numpy(np.ascontiguousarray(depth_np)).float()
    ok = torch.from_numpy(np.ascontiguousarray(conf_np)) & (depth > 0)
    normal, normal_ok = L.normals_from_depth_pca(depth, torch.from_numpy(view.K), window, valid=ok)
    return PriorTensors(depth, ok, normal, normal_ok)


def init_model(clip: PosedClip, conf: ReconConfig, rng: np.random.Generator) -> GaussianModel:
    xyz, rgb = np.asarray(clip.points_xyz), np.asarray(clip.points_rgb)
    if xyz.shape[0] < 4:
        raise StageError(STAGE, "no_sparse_points", f"the PosedClip has {xyz.shape[0]} sparse points; need >= 4")
    if xyz.shape[0] > conf.max_init_points:
        keep = rng.choice(xyz.shape[0], conf.max_init_points, replace=False)
        xyz, rgb = xyz[keep], rgb[keep]
    return GaussianModel.from_points(xyz, rgb, conf.sh_degree)


def learning_rates(conf: ReconConfig, extent: float) -> dict[str, float]:
    lr = conf.lr
    return {"means": lr.means * extent, "quats": lr.quats, "log_scales": lr.scales,
            "opacity_logits": lr.opacity, "sh0": lr.sh0, "shN": lr.shN}


def means_lr(conf: ReconConfig, extent: float, it: int) -> float:
    """3DGS exponential decay from lr.means to lr.means_final over the run (x extent)."""
    t = min(max(it / max(conf.iterations, 1), 0.0), 1.0)
    return extent * float(np.exp((1 - t) * np.log(conf.lr.means) + t * np.log(conf.lr.means_final)))


# ----------------------------------------------------------------------------- one step

def step_loss(conf: ReconConfig, out, gt: torch.Tensor, mask: torch.Tensor,
              prior: Optional[PriorTensors], log_scales: torch.Tensor, it: int) -> tuple[torch.Tensor, dict]:
    """Total loss (paper eq. 5 with weights) for one rendered view; returns (loss, parts)."""
    lc = conf.loss
    loss = L.rgb_loss(out.rgb, gt, mask, lc.lambda_dssim)
    parts = {"rgb": float(loss.detach())}
    if not (lc.geometry and it >= lc.geometry_from_iter):
        return loss, parts
    covered = (out.alpha.detach() > 0.5) & mask  # [H, W]
    if lc.w_scale > 0:
        l_scale = L.scale_loss(log_scales)
        loss = loss + lc.w_scale * l_scale
        parts["scale"] = float(l_scale.detach())
    if prior is not None:
        l_depth = L.ncc_depth_loss(out.depth, prior.depth, prior.conf & covered, lc.ncc_patch, lc.ncc_stride)
        l_normal = L.normal_loss(out.normal, prior.normal, prior.normal_ok & covered)
        loss = loss + lc.w_depth * l_depth + lc.w_normal * l_normal
        parts.update(depth=float(l_depth.detach()), normal=float(l_normal.detach()))
    if lc.w_geo > 0:
        # weights from the prior depth where confident, the rendered depth elsewhere; log depth
        # makes |grad D| the relative depth change (scale-free)
        d = out.depth.detach()
        if prior is not None:
            d = torch.where(prior.conf, prior.depth, d)
        l_geo = L.geo_consistency_loss(out.normal, torch.log(d.clamp_min(1e-6)), covered)
        loss = loss + lc.w_geo * l_geo
        parts["geo"] = float(l_geo.detach())
    return loss, parts


# ----------------------------------------------------------------------------- checkpoints

def save_checkpoint(path: Path, key: str, it: int, params: SplatParams, stats: DensifyStats,
                    log: list, holdout: Optional[dict] = None) -> None:
    tmp = path.with_name(path.name + ".tmp")
    torch.save({"key": key, "iter": it, "params": params.state_dict(), "stats": stats.__dict__,
                "torch_rng": torch.get_rng_state(), "log": log, "holdout": holdout or {}}, tmp)
    os.replace(tmp, path)


def load_checkpoint(path: Path, key: str) -> Optional[dict]:
    if not path.is_file():
        return None
    try:
        ck = torch.load(path, weights_only=False)
    except Exception:  # a torn file from a killed run: start over
        return None
    return ck if ck.get("key") == key else None


# ----------------------------------------------------------------------------- training

@dataclass
class Level:
    """Cameras, target images and prior tensors of the training views at one resolution."""

    cams: dict[int, Camera]
    gts: dict[int, tuple[torch.Tensor, torch.Tensor]]  # index -> (image [H, W, 3], mask [H, W])
    priors: dict[int, PriorTensors]


def make_level(conf: ReconConfig, train_views: list[View], priors: dict[int, DepthPrior],
               scale: float = 1.0) -> Level:
    views = [downscale_view(v, scale) for v in train_views]
    return Level(
        cams={v.index: Camera.from_cam_to_world(v.K, v.cam_to_world, v.width, v.height) for v in views},
        gts={v.index: (torch.from_numpy(v.image), torch.from_numpy(v.mask)) for v in views},
        priors={v.index: prior_tensors(priors[v.index], v, conf.loss.normal_pca_window)
                for v in views if v.index in priors and priors[v.index].confidence.any()})


@torch.no_grad()
def holdout_l1(conf: ReconConfig, params: SplatParams, views: list[View], deg: int) -> float:
    """Mean masked L1 of the current splats on the held-out views (full training resolution)."""
    model = params.model()
    total = 0.0
    for v in views:
        cam = Camera.from_cam_to_world(v.K, v.cam_to_world, v.width, v.height)
        settings = RasterSettings(width=v.width, height=v.height, active_sh_degree=deg)
        out = render(model, cam, settings, conf.background, conf.backend)
        mask = torch.from_numpy(v.mask)[..., None].float()  # [H, W, 1]
        err = ((out.rgb - torch.from_numpy(v.image)).abs() * mask).sum()
        total += float(err / (3 * mask.sum()).clamp_min(1.0))
    return total / max(len(views), 1)


def train(conf: ReconConfig, clip: PosedClip, views: list[View], priors: dict[int, DepthPrior],
          out_dir: Path, key: str, log_every: int = 100) -> tuple[GaussianModel, dict]:
    """Optimise the splats; returns (model, training summary). The splat kernels run on numba's
    threads; the losses' torch ops, on images of a few ten thousand pixels, on one thread
    (GoPro clip, 2 CPUs: training 116.7 -> 110.0 s wall, 178 -> 165 CPU-s)."""
    with torch_threads(1):
        return _train(conf, clip, views, priors, out_dir, key, log_every)


def _train(conf: ReconConfig, clip: PosedClip, views: list[View], priors: dict[int, DepthPrior],
           out_dir: Path, key: str, log_every: int) -> tuple[GaussianModel, dict]:
    torch.manual_seed(conf.seed)
    rng = np.random.default_rng(conf.seed)
    train_views = [v for v in views if v.split == "train"]
    test_views = [v for v in views if v.split == "test"]
    if not train_views:
        raise StageError(STAGE, "no_training_frames", "every frame of the clip is held out")
    extent = scene_extent(views)
    lrs = learning_rates(conf, extent)
    ck_path = Path(out_dir) / CHECKPOINT
    ck = load_checkpoint(ck_path, key)
    holdout = {"best": float("inf"), "bad": 0}
    if ck is None:
        params = SplatParams.from_model(init_model(clip, conf, rng), lrs)
        stats, start, log = DensifyStats.zeros(params.n), 0, []
    else:
        params = SplatParams.from_state_dict(ck["params"], lrs)
        stats, start, log = DensifyStats(**ck["stats"]), int(ck["iter"]), list(ck["log"])
        holdout.update(ck.get("holdout", {}))
        torch.set_rng_state(ck["torch_rng"])
    coarse = conf.coarse_scale < 1.0 and start < conf.coarse_iterations
    level = make_level(conf, train_views, priors, conf.coarse_scale if coarse else 1.0)
    dc = conf.densify
    order: list[int] = []
    t0 = time.perf_counter()
    done = start
    for it in range(start, conf.iterations):
        if coarse and it >= conf.coarse_iterations:
            coarse, level = False, make_level(conf, train_views, priors)
        if not order:
            order = list(rng.permutation([v.index for v in train_views]))
        vi = order.pop()
        params.set_lr("means", means_lr(conf, extent, it))
        cam = level.cams[vi]
        deg = min(conf.sh_degree, it // max(conf.sh_increase_every, 1))
        settings = RasterSettings(width=cam.width, height=cam.height, active_sh_degree=deg,
                                  median_depth=False)  # no loss reads it
        out = render(params.model(), cam, settings, conf.background, conf.backend, absgrad=True)
        gt, mask = level.gts[vi]
        loss, parts = step_loss(conf, out, gt, mask, level.priors.get(vi), params.p["log_scales"], it)
        loss.backward()
        if it < dc.stop_iter and out.raw.grad2d is not None:
            absgrad = out.raw.absgrad if out.raw.absgrad is not None else out.raw.grad2d.abs()
            stats.accumulate(out.raw.grad2d, absgrad, out.raw.radii, cam.width, cam.height)
        params.opt.step()
        params.opt.zero_grad(set_to_none=True)
        done = it + 1
        if dc.start_iter <= done < dc.stop_iter and done % dc.every == 0:
            counts = densify_and_prune(params, stats, dc, extent, prune_large=done > dc.opacity_reset_every)
            stats = DensifyStats.zeros(params.n)
            log.append({"iter": done, **counts})
            if done % dc.opacity_reset_every == 0:
                reset_opacity(params)
        elif done == dc.stop_iter:
            prune_only(params, dc)
            stats = DensifyStats.zeros(params.n)
        if done % log_every == 0 or done == conf.iterations:
            log.append({"iter": done, "n": params.n, "sec": round(time.perf_counter() - t0, 2), **parts})
        if conf.holdout_every and test_views and done % conf.holdout_every == 0 and done < conf.iterations:
            l1 = holdout_l1(conf, params, test_views, deg)
            log.append({"iter": done, "holdout_l1": l1})
            if l1 < holdout["best"] * (1.0 - conf.holdout_min_delta):
                holdout["best"], holdout["bad"] = l1, 0
            elif done >= dc.stop_iter:
                holdout["bad"] += 1
            if done >= dc.stop_iter and holdout["bad"] >= conf.holdout_patience:
                log.append({"iter": done, "stopped": "held-out L1 converged"})
                break
        if conf.checkpoint_every and done % conf.checkpoint_every == 0 and done < conf.iterations:
            save_checkpoint(ck_path, key, done, params, stats, log, holdout)
    model = params.detached_model()
    return model, {"iterations": done, "resumed_from": start, "n_gaussians": model.num,
                   "scene_extent": extent, "log": log}


# ----------------------------------------------------------------------------- stage

def _write_json(path: Path, data: dict) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2))
    os.replace(tmp, path)


def work(conf: ReconConfig, posed_clip_dir: Path, gt_depth_dir: Optional[Path] = None) -> StageWork:
    """Training splats for the PosedClip at `posed_clip_dir`: keyed by the config and the clip's
    key; a checkpoint of the same key in the folder is resumed.

    gt_depth_dir: optional folder of ground-truth depth maps (`<image stem>.png` uint16 mm or
    `.npy` metres); defaults to the clip's frame_info["gt_depth_dir"] when present.
    """
    posed_clip_dir = check_posed_dir(posed_clip_dir)
    clip_key = input_key(posed_clip_dir)
    key = stage_key(STAGE, STAGE_VERSION, conf, clip_key)  # a checkpoint belongs to this key
    return StageWork(STAGE, STAGE_VERSION, conf, (clip_key,),
                     build=lambda out_dir: build(conf, posed_clip_dir, out_dir, key, gt_depth_dir),
                     resume=lambda out_dir: load_checkpoint(out_dir / CHECKPOINT, key) is not None)


def build(conf: ReconConfig, posed_clip_dir: Path, out_dir: Path, key: str,
          gt_depth_dir: Optional[Path] = None) -> dict:
    """Train splats into `out_dir` (empty, or holding a checkpoint of `key`; see module doc);
    returns the summary (metrics.json's scalars)."""
    conf.save(out_dir / "config.json")
    clip = PosedClip.load(posed_clip_dir)
    cpu = {"start": time.process_time()}  # process CPU seconds (every thread): wall time on a shared machine misleads
    with Timer() as timer:
        views = load_views(clip, conf.max_width)
        with Timer() as t_prior:
            cpu["prior"] = time.process_time()
            priors = load_or_estimate_priors(conf, views, np.asarray(clip.points_xyz), out_dir)
        with Timer() as t_train:
            cpu["train"] = time.process_time()
            model, summary = train(conf, clip, views, priors, out_dir, key)
            cpu["train_end"] = time.process_time()
        write_ply(model, out_dir / OUTPUTS.splats)
        gt_dir = gt_depth_dir or clip.frame_info.get("gt_depth_dir")
        gt = load_gt_depths(Path(gt_dir), views) if gt_dir else {}
        metrics = evaluate_views(model, [v for v in views if v.split == "test"], conf, gt)
    metrics.update(preset=conf.preset, prior=conf.prior.kind, geometry=conf.loss.geometry,
                   n_gaussians=summary["n_gaussians"], iterations=summary["iterations"],
                   resumed_from=summary["resumed_from"], prior_seconds=t_prior.seconds,
                   train_seconds=t_train.seconds, seconds=timer.seconds,
                   prior_cpu_seconds=cpu["train"] - cpu["prior"], train_cpu_seconds=cpu["train_end"] - cpu["train"],
                   cpu_seconds=time.process_time() - cpu["start"],
                   prior_coverage=_coverage(priors), resolution=[views[0].width, views[0].height])
    _write_json(out_dir / OUTPUTS.metrics, metrics)
    _write_json(out_dir / "train_log.json", {"log": summary["log"]})
    (out_dir / CHECKPOINT).unlink(missing_ok=True)
    return {k: v for k, v in metrics.items() if not isinstance(v, (list, dict))}


def _coverage(priors: dict[int, DepthPrior]) -> Optional[float]:
    if not priors:
        return None
    return float(np.mean([p.confidence.mean() for p in priors.values()]))
