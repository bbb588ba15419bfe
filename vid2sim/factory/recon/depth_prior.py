"""Depth priors for the geometry losses, chosen by `DepthPriorConfig.kind`.

mvs            plane-sweep stereo over neighbouring posed training frames: fronto-parallel
               planes at inverse-depth steps, neighbour warped by the plane homography, NCC in a
               window, best-2-of-N neighbour aggregation, parabolic refinement. Metric depth
               (the poses' units) + a confidence mask (score >= min_ncc, textured, in range,
               and consistent with the neighbouring views' priors: `filter_consistent`).
depth_anything Depth-Anything-V2 via transformers, ONLY from a local checkpoint folder; its
               relative disparity is aligned (scale, shift) to the sparse SfM points.
none           no prior (plain 3DGS).

Reads: views (images at training resolution, K, poses), sparse points. Writes nothing
(the trainer caches the result).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import cv2
import numpy as np

from vid2sim.factory.recon.config import DepthPriorConfig
from vid2sim.factory.recon.data import STAGE, View, scale_K
from vid2sim.factory.runtime.stage_cache import StageError


@dataclass
class DepthPrior:
    depth: np.ndarray  # [H, W] float32, camera z in world units (0 = unknown)
    confidence: np.ndarray  # [H, W] bool


# ----------------------------------------------------------------------------- projection, depth range and view choice

def project(points: np.ndarray, view: View) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World points [P, 3] -> (pixel coords [P, 2] (x, y; pixel j covers [j, j + 1)), camera z [P],
    inside [P] bool: in front of the camera and within the image)."""
    w2c = view.world_to_cam
    cam = points @ w2c[:3, :3].T + w2c[:3, 3]  # [P, 3]
    z = cam[:, 2]
    front = z > 1e-6
    uv = (cam @ view.K.T)[:, :2] / np.where(front, z, 1.0)[:, None]  # [P, 2]
    inside = front & (uv[:, 0] >= 0) & (uv[:, 0] < view.width) & (uv[:, 1] >= 0) & (uv[:, 1] < view.height)
    return uv, z, inside


def project_depths(points: np.ndarray, view: View) -> tuple[np.ndarray, np.ndarray]:
    """Sparse points [M, 3] -> (pixel coords [m, 2] (x, y), z [m]) of those inside the view."""
    uv, z, inside = project(points, view)
    return uv[inside], z[inside]


def depth_range(points: np.ndarray, view: View, percentiles: tuple) -> Optional[tuple[float, float]]:
    _, z = project_depths(points, view)
    if z.size < 10:
        return None
    lo, hi = np.percentile(z, percentiles)
    return float(lo) * 0.7, float(hi) * 1.5


def choose_neighbours(ref: View, views: list[View], count: int, median_depth: float) -> list[View]:
    """Training frames near `ref` in index with a useful baseline (~10% of the scene depth)
    and a similar viewing direction (< 35 degrees)."""
    c_ref, z_ref = ref.cam_to_world[:3, 3], ref.cam_to_world[:3, 2]
    scored = []
    for v in views:
        if v.index == ref.index or v.split != "train" or abs(v.index - ref.index) > 6 * count:
            continue
        base = float(np.linalg.norm(v.cam_to_world[:3, 3] - c_ref))
        cosang = float(np.dot(z_ref, v.cam_to_world[:3, 2]))
        if base < 1e-3 * median_depth or cosang < np.cos(np.deg2rad(35)):
            continue
        scored.append((abs(np.log(base / (0.1 * median_depth))), v))
    scored.sort(key=lambda s: s[0])
    return [v for _, v in scored[:count]]


def _gray(view: View, size: tuple[int, int]) -> np.ndarray:
    g = cv2.cvtColor(view.image, cv2.COLOR_RGB2GRAY)
    return cv2.resize(g, size, interpolation=cv2.INTER_AREA) if g.shape[::-1] != size else g


def _box(img: np.ndarray, win: int) -> np.ndarray:
    return cv2.boxFilter(img, cv2.CV_32F, (win, win), normalize=True, borderType=cv2.BORDER_REFLECT)


def plane_homography(K_ref: np.ndarray, K_nb: np.ndarray, T_nb_ref: np.ndarray, depth: float) -> np.ndarray:
    """Homography taking ref pixels (OpenCV integer-centre coords) to neighbour pixels for the
    fronto-parallel plane z_ref = depth. T_nb_ref [4, 4] maps ref camera to neighbour camera."""
    R, t = T_nb_ref[:3, :3], T_nb_ref[:3, 3:4]
    n = np.array([[0.0, 0.0, 1.0]])
    H = K_nb @ (R + t @ n / depth) @ np.linalg.inv(K_ref)
    shift = np.array([[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1.0]])  # centre convention j + 0.5
    return np.linalg.inv(shift) @ H @ shift


# ----------------------------------------------------------------------------- MVS

def mean_of_top_two(scores: list[np.ndarray]) -> np.ndarray:
    """Per pixel, the mean of the two highest of the neighbours' scores [H, W] (the one score
    when there is one), bit for bit what sorting the stack and averaging its top two gives."""
    first, second = scores[0], None
    for s in scores[1:]:
        low = np.minimum(first, s)
        second = low if second is None else np.maximum(second, low)
        first = np.maximum(first, s)
    return first if second is None else (second + first) / 2


def plane_sweep(ref: View, neighbours: list[View], near: float, far: float, conf: DepthPriorConfig
                ) -> DepthPrior:
    """Plane-sweep depth for `ref` at its resolution capped to conf.max_width."""
    s = min(1.0, conf.max_width / ref.width)
    w, h = max(8, int(round(ref.width * s))), max(8, int(round(ref.height * s)))
    K_ref = scale_K(ref.K, w / ref.width, h / ref.height)
    win = conf.ncc_window
    a = _gray(ref, (w, h))
    mu_a = _box(a, win)
    var_a = np.maximum(_box(a * a, win) - mu_a ** 2, 0)
    inv = np.linspace(1.0 / near, 1.0 / far, conf.num_planes)  # [D] inverse depths
    scores = np.full((conf.num_planes, h, w), -1.0, np.float32)  # [D, H, W]
    nbs = [(scale_K(v.K, w / v.width, h / v.height), _gray(v, (w, h)),
            v.world_to_cam @ ref.cam_to_world) for v in neighbours]
    ones, window = np.ones((h, w), np.uint8), np.ones((win, win), np.uint8)
    for d_i, invd in enumerate(inv):
        per_nb = []
        for K_nb, b_img, T in nbs:
            Hm = plane_homography(K_ref, K_nb, T, 1.0 / invd)
            b = cv2.warpPerspective(b_img, Hm, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                    borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            inside = cv2.warpPerspective(ones, Hm, (w, h), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
                                         borderValue=0)  # [H, W] uint8: 1 where the neighbour sees
            mu_b = _box(b, win)
            var_b = np.maximum(_box(b * b, win) - mu_b ** 2, 0)
            cov = _box(a * b, win) - mu_a * mu_b
            ncc = cov / np.sqrt(var_a * var_b + 1e-8)
            # windows with a pixel the neighbour does not see (a 0 in the window's erosion)
            ncc[cv2.erode(inside, window, borderType=cv2.BORDER_REFLECT) == 0] = -1.0
            per_nb.append(ncc)
        scores[d_i] = mean_of_top_two(per_nb)
    best = scores.argmax(0)  # [H, W]
    best_score = np.take_along_axis(scores, best[None], 0)[0]
    # parabolic sub-plane refinement in inverse depth
    lo = np.clip(best - 1, 0, conf.num_planes - 1)
    hi = np.clip(best + 1, 0, conf.num_planes - 1)
    s_lo = np.take_along_axis(scores, lo[None], 0)[0]
    s_hi = np.take_along_axis(scores, hi[None], 0)[0]
    denom = s_lo - 2 * best_score + s_hi
    curved = (denom < -1e-6) & (lo != best) & (hi != best)
    offset = np.where(curved, 0.5 * (s_lo - s_hi) / np.where(curved, denom, -1.0), 0.0)
    step = inv[1] - inv[0] if conf.num_planes > 1 else 0.0
    invd = inv[best] + np.clip(offset, -0.5, 0.5) * step
    depth = (1.0 / np.maximum(invd, 1e-9)).astype(np.float32)
    textured = np.sqrt(var_a) > 0.01
    interior = (best > 0) & (best < conf.num_planes - 1)
    confident = (best_score >= conf.min_ncc) & textured & interior
    if (w, h) != (ref.width, ref.height):
        depth = cv2.resize(depth, (ref.width, ref.height), interpolation=cv2.INTER_NEAREST)
        confident = cv2.resize(confident.astype(np.uint8), (ref.width, ref.height),
                               interpolation=cv2.INTER_NEAREST) > 0
    confident &= ref.mask
    return DepthPrior(np.where(confident, depth, 0).astype(np.float32), confident)


def consistent_mask(ref: View, prior: DepthPrior, others: list[tuple[View, DepthPrior]],
                    rel_tol: float, min_views: int) -> np.ndarray:
    """[H, W] bool: ref's confident pixels whose depth, back-projected and projected into at
    least `min_views` of `others`, lands within rel_tol x the projected z of that view's own
    confident prior depth (nearest pixel)."""
    ys, xs = np.nonzero(prior.confidence)
    z = prior.depth[ys, xs].astype(np.float64)  # [P]
    K = ref.K
    pts_cam = np.stack([(xs + 0.5 - K[0, 2]) / K[0, 0] * z, (ys + 0.5 - K[1, 2]) / K[1, 1] * z, z], 1)
    pts = pts_cam @ ref.cam_to_world[:3, :3].T + ref.cam_to_world[:3, 3]  # [P, 3] world
    votes = np.zeros(z.shape, np.int32)
    for view, other in others:
        uv, zq, inside = project(pts, view)
        ui, vi = np.floor(uv[inside]).astype(np.int64).T
        agree = other.confidence[vi, ui] & (np.abs(other.depth[vi, ui] - zq[inside]) <= rel_tol * zq[inside])
        votes[np.flatnonzero(inside)[agree]] += 1
    keep = np.zeros_like(prior.confidence)
    keep[ys[votes >= min_views], xs[votes >= min_views]] = True
    return keep


def filter_consistent(views: list[View], priors: dict[int, DepthPrior], conf: DepthPriorConfig
                      ) -> dict[int, DepthPrior]:
    """Priors with the geometrically inconsistent pixels no longer confident (consistent_mask
    against the conf.consistency_views nearest training views on each side); unchanged when
    conf.consistency_rel is 0."""
    if conf.consistency_rel <= 0:
        return priors
    if not 1 <= conf.min_consistent <= 2 * conf.consistency_views:
        raise StageError(STAGE, "bad_prior_config",
                         f"prior.min_consistent={conf.min_consistent} must lie in 1..2 x "
                         f"prior.consistency_views ({2 * conf.consistency_views}): no pixel could pass")
    ordered = sorted((v for v in views if v.index in priors), key=lambda v: v.index)
    out = {}
    for k, ref in enumerate(ordered):
        lo, hi = max(0, k - conf.consistency_views), k + conf.consistency_views + 1
        others = [(v, priors[v.index]) for v in ordered[lo:hi] if v.index != ref.index]
        keep = consistent_mask(ref, priors[ref.index], others, conf.consistency_rel, conf.min_consistent)
        out[ref.index] = DepthPrior(np.where(keep, priors[ref.index].depth, 0).astype(np.float32), keep)
    return out


def view_prior(ref: View, views: list[View], points: np.ndarray, conf: DepthPriorConfig) -> DepthPrior:
    """The plane-sweep prior of one training view (an empty confidence mask when the sparse
    points give no depth range or no neighbour has a usable baseline)."""
    rng = depth_range(points, ref, conf.near_far_percentiles)
    nbs = [] if rng is None else choose_neighbours(
        ref, views, conf.neighbours, median_depth=0.5 * (rng[0] / 0.7 + rng[1] / 1.5))
    if not nbs:
        return DepthPrior(np.zeros((ref.height, ref.width), np.float32), np.zeros((ref.height, ref.width), bool))
    return plane_sweep(ref, nbs, *rng, conf)


def mvs_priors(views: list[View], points: np.ndarray, conf: DepthPriorConfig,
               threads: int = 1) -> dict[int, DepthPrior]:
    """Plane-sweep priors for every training view, `threads` views at a time (OpenCV and numpy
    release the GIL; each view's result is the same on any thread count), then the geometric
    consistency filter."""
    train = [v for v in views if v.split == "train"]
    with ThreadPoolExecutor(max(1, threads)) as pool:
        priors = list(pool.map(lambda ref: view_prior(ref, views, points, conf), train))
    return filter_consistent(views, {v.index: p for v, p in zip(train, priors)}, conf)


# ----------------------------------------------------------------------------- Depth Anything

def _load_depth_anything(checkpoint: Optional[str], device: str):
    if not checkpoint:
        raise StageError(STAGE, "depth_prior_checkpoint_missing",
                         "prior.kind='depth_anything' needs prior.checkpoint: a local folder with a "
                         "transformers Depth-Anything-V2 model (nothing is downloaded)")
    path = Path(checkpoint).expanduser()
    if not path.is_dir() or not (path / "config.json").is_file():
        raise StageError(STAGE, "depth_prior_checkpoint_missing",
                         f"{path} is not a local transformers model folder (config.json absent)")
    try:
        from transformers import AutoImageProcessor, AutoModelForDepthEstimation
    except ImportError as exc:
        raise StageError(STAGE, "transformers_not_installed",
                         "prior.kind='depth_anything' needs the 'transformers' package "
                         f"(pip install transformers torch==2.13.0): {exc}") from exc
    proc = AutoImageProcessor.from_pretrained(str(path), local_files_only=True)
    model = AutoModelForDepthEstimation.from_pretrained(str(path), local_files_only=True).to(device).eval()
    return proc, model


def align_disparity(disp: np.ndarray, uv: np.ndarray, z: np.ndarray) -> Optional[np.ndarray]:
    """Least-squares (a, b) with a * disp + b = 1 / z at the sparse points; returns depth."""
    if z.size < 10:
        return None
    d = disp[np.clip(uv[:, 1].astype(int), 0, disp.shape[0] - 1), np.clip(uv[:, 0].astype(int), 0, disp.shape[1] - 1)]
    A = np.stack([d, np.ones_like(d)], 1)
    (a, b), *_ = np.linalg.lstsq(A, 1.0 / z, rcond=None)
    inv = a * disp + b
    return np.where(inv > 1e-6, 1.0 / np.maximum(inv, 1e-6), 0.0).astype(np.float32)


def depth_anything_priors(views: list[View], points: np.ndarray, conf: DepthPriorConfig) -> dict[int, DepthPrior]:
    import torch

    proc, model = _load_depth_anything(conf.checkpoint, conf.device)
    out = {}
    for v in views:
        if v.split != "train":
            continue
        inputs = proc(images=(v.image * 255).astype(np.uint8), return_tensors="pt").to(conf.device)
        with torch.no_grad():
            pred = model(**inputs).predicted_depth  # [1, h, w] relative disparity
        disp = torch.nn.functional.interpolate(pred[None], size=(v.height, v.width), mode="bilinear",
                                               align_corners=False)[0, 0].cpu().numpy()
        uv, z = project_depths(points, v)
        depth = align_disparity(disp, uv, z)
        if depth is None:  # no metric anchor: relative depth is still fine for the NCC loss
            depth = (1.0 / np.maximum(disp - disp.min() + 1e-3 * np.ptp(disp) + 1e-6, 1e-6)).astype(np.float32)
        ok = (depth > 0) & v.mask
        out[v.index] = DepthPrior(np.where(ok, depth, 0).astype(np.float32), ok)
    return out


def estimate_priors(conf: DepthPriorConfig, views: list[View], points: np.ndarray,
                    threads: int = 1) -> dict[int, DepthPrior]:
    """Priors for the training views keyed by frame index ({} for kind='none'); `threads`: how
    many views the plane sweep works on at once."""
    if conf.kind == "none":
        return {}
    if conf.kind == "mvs":
        return mvs_priors(views, points, conf, threads)
    if conf.kind == "depth_anything":
        return depth_anything_priors(views, points, conf)
    raise StageError(STAGE, "unknown_depth_prior", f"prior.kind={conf.kind!r}; use mvs | depth_anything | none")
