"""The `metric` stage: SfM model -> metric, gravity-aligned world (z up, ground at z = 0).

Reads:  an `sfm` output folder (`undistorted/sparse`, `undistorted/images`, `undistorted/masks`,
        `quality.json`; timestamps from `frames.parquet` beside the SfM input frames if present).
Writes into `out_dir`:
  cameras.parquet, points.npz, frame.json   a `PosedClip` (posed.py): pinhole K, cam_to_world in
                                            the metric world, split = every 8th frame "test"
  sparse/                                   the undistorted COLMAP model moved into that world
  transforms.json                           nerfstudio export in that world
  stage.json                                marker (written by the runner, runtime/runner.py)
World: RANSAC plane through SfM points below the cameras (seen in the lower image part, on
static mask pixels, below the camera along the cameras' mean "up" = -y axis), normal oriented
towards the cameras = +z; x = walking direction on the ground; origin below the first camera.
Scale: median camera height = `capture_height_m`, or a GPS / known path length when given.
`frame.json` records the scale source, the plane, its residual and the Sim(3) applied.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Optional

import cv2
import numpy as np
from scipy.spatial import cKDTree

from vid2sim.factory.ingest import decode
from vid2sim.factory.sfm import sfm
from vid2sim.factory.sfm.export import rec_cam_to_world, write_colmap, write_transforms
from vid2sim.factory.sfm.posed import PosedClip, PosedFrame, holdout_split
from vid2sim.factory.runtime.stage_cache import StageError, StageWork, finished_key
from vid2sim.ranges import checked

STAGE = "metric"
STAGE_VERSION = 1  # bump when this stage's outputs change for the same inputs


@dataclass(frozen=True)
class MetricOutputs:
    """Folders of a finished metric output beside the PosedClip files, relative to it."""

    colmap: str = "sparse"  # the COLMAP model in the metric frame


OUTPUTS = MetricOutputs()


@checked
@dataclass
class MetricConfig:
    capture_height_m: float = 1.5  # camera height above the ground (hand-held default)
    scale_source: str = "auto"  # auto | capture_height | gps | path_length
    gps_csv: str = ""  # GoPro GPS5 CSV (t_approx_s, lat_deg, lon_deg, speed2d_mps, gps_fix)
    known_path_length_m: float = 0.0  # walked distance from any telemetry (path_length source)
    lower_image_fraction: float = 0.5  # ground candidates: observed in the lower part of images
    max_tilt_deg: float = 15.0  # plane normal within this of the up prior (see up_prior)
    inlier_frac_of_height: float = 0.03  # RANSAC threshold = this x rough camera height
    corridor_frac_of_height: float = 3.0  # keep points within this x height of the path (sideways)
    local_radius_frac: float = 4.0  # camera height measured on ground points within this x height
    ransac_iters: int = 2000  # RANSAC iterations of the ground-plane fit
    below_penalty: float = 2.0  # RANSAC prefers the lowest supported plane (see ransac_plane)
    min_ground_points: int = 30  # fewer ground candidates or plane inliers fails the stage (no_ground_plane)
    holdout_every: int = 8  # every n-th frame (index % n == 0) is held out as a test view (paper: 8)
    fallback_fps: float = 10.0  # timestamps = index / fps when no frames.parquet exists
    seed: int = 0  # RANSAC random seed


# ----------------------------------------------------------------------------- geometry

def fit_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane n.x + d = 0 of points [N, 3] (unit n)."""
    c = points.mean(0)
    n = np.linalg.svd(points - c, full_matrices=False)[2][-1]
    return n, float(-n @ c)


def ransac_plane(points: np.ndarray, up: np.ndarray, threshold: float, max_tilt_deg: float,
                 iters: int, seed: int = 0, below_penalty: float = 0.0
                 ) -> tuple[np.ndarray, float, np.ndarray]:
    """Robust plane (n, d, inlier mask [N]) with n within `max_tilt_deg` of `up`, refined by LSQ.

    Score = inliers - below_penalty x points more than 3 thresholds below the plane: the ground
    is the lowest well-supported surface (low plants, kerbs and car bodies lie above it).
    """
    rng = np.random.default_rng(seed)
    tri = points[rng.integers(0, len(points), size=(iters, 3))]  # [I, 3, 3]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # [I, 3]
    norms = np.linalg.norm(normals, axis=1)
    normals = normals / np.maximum(norms, 1e-12)[:, None]
    normals *= np.where(normals @ up < 0, -1.0, 1.0)[:, None]
    ok = (norms > 1e-12) & (normals @ up > math.cos(math.radians(max_tilt_deg)))
    if not ok.any():
        raise StageError(STAGE, "no_ground_plane", "no plane hypothesis is close to the up prior")
    normals, anchors = normals[ok], tri[ok, 0]
    best, best_count = None, -1
    for chunk in range(0, len(normals), 256):
        n, a = normals[chunk:chunk + 256], anchors[chunk:chunk + 256]
        dist = ((points[None] - a[:, None]) @ n[:, :, None])[..., 0]  # [C, N] signed, + = up
        counts = (np.abs(dist) < threshold).sum(1) - below_penalty * (dist < -3 * threshold).sum(1)
        i = int(counts.argmax())
        if counts[i] > best_count:
            best, best_count = (n[i], float(-n[i] @ a[i])), int(counts[i])
    n, d = best
    for _ in range(2):  # refine on inliers
        inl = np.abs(points @ n + d) < threshold
        n, d = fit_plane(points[inl])
        if n @ up < 0:
            n, d = -n, -d
    return n, d, np.abs(points @ n + d) < threshold


def rotation_to_world(n: np.ndarray, forward: np.ndarray) -> np.ndarray:
    """Rotation [3, 3] whose rows are the new axes: x = forward on the plane, z = n."""
    f = forward - (forward @ n) * n
    if np.linalg.norm(f) < 1e-9:
        f = np.cross(n, [1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.cross(n, [0.0, 1.0, 0.0])
    x = f / np.linalg.norm(f)
    return np.stack([x, np.cross(n, x), n])


def up_prior(c2w: np.ndarray, max_gap_deg: float = 30.0) -> tuple[np.ndarray, str]:
    """Up direction prior from the cameras [N, 4, 4]: unit vector and how it was made.

    A walker moves along the ground and holds the camera without lasting roll, so up is
    perpendicular to the walking direction (first principal axis of the path) and to the mean
    camera right axis: up = right x forward. (On the GoPro clip this is 1.4 deg from the IMU
    gravity, while the mean camera -y axis is 7 deg off, since the camera is pitched down.)
    Falls back to the mean camera -y axis for a short path or when the two disagree.
    """
    cam_up = -c2w[:, :3, 1].mean(0)
    cam_up /= np.linalg.norm(cam_up)
    centers = c2w[:, :3, 3]
    span = np.linalg.svd(centers - centers.mean(0), full_matrices=False)
    fwd = span[2][0] * np.sign(span[2][0] @ c2w[:, :3, 2].mean(0))
    right = c2w[:, :3, 0].mean(0)
    up = np.cross(right, fwd)
    if span[1][0] < 1e-9 or np.linalg.norm(up) < 0.5 * np.linalg.norm(right):
        return cam_up, "camera_minus_y"
    up /= np.linalg.norm(up)
    up *= np.sign(up @ cam_up) or 1.0
    if angle_deg(up, cam_up) > max_gap_deg:
        return cam_up, "camera_minus_y"
    return up, "right_x_walk"


def corridor(pts: np.ndarray, centers: np.ndarray, up: np.ndarray,
             frac: float) -> tuple[np.ndarray, float]:
    """Points [M, 3] whose sideways distance to the nearest camera < frac x rough height."""
    _, near = cKDTree(centers).query(pts)
    rel = pts - centers[near]  # [M, 3]
    below = -(rel @ up)
    rough_h = float(np.median(below))
    side = np.linalg.norm(rel + np.outer(below, up), axis=1)
    keep = side < frac * rough_h
    return pts[keep], float(np.median(below[keep])) if keep.any() else rough_h


def local_heights(centers: np.ndarray, ground: np.ndarray, n: np.ndarray, d: float,
                  radius: float, min_points: int = 10) -> np.ndarray:
    """Per-camera height [N] above the ground points near its foot (the plane where too few)."""
    feet = centers - np.outer(centers @ n + d, n)
    tree = cKDTree(ground)
    heights = centers @ n + d
    for i, near in enumerate(tree.query_ball_point(feet, radius)):
        if len(near) >= min_points:
            heights[i] = float(np.median((centers[i] - ground[near]) @ n))
    return heights


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    c = float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


# ----------------------------------------------------------------------------- SfM model access

def camera_arrays(rec: Any) -> tuple[list[str], np.ndarray]:
    """Registered image names (sorted) and their cam_to_world [N, 4, 4] (OpenCV axes)."""
    poses = rec_cam_to_world(rec)
    names = sorted(poses)
    return names, np.stack([poses[n] for n in names])


def ground_candidates(rec: Any, masks_dir: Optional[Path], centers: np.ndarray, up: np.ndarray,
                      conf: MetricConfig) -> np.ndarray:
    """Ids of points mostly seen in the lower image part on static pixels, below the cameras."""
    cam = next(iter(rec.cameras.values()))
    v_min = (1.0 - conf.lower_image_fraction) * cam.height
    masks: dict[int, Optional[np.ndarray]] = {}
    for image_id, image in rec.images.items():
        p = masks_dir / f"{image.name}.png" if masks_dir else None
        masks[image_id] = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) if p and p.exists() else None
    ids, xyz = [], []
    for pid, point in rec.points3D.items():
        votes = 0
        elements = point.track.elements
        for el in elements:
            image = rec.images[el.image_id]
            u, v = image.points2D[el.point2D_idx].xy
            m = masks[el.image_id]
            static = m is None or m[min(int(v), m.shape[0] - 1), min(int(u), m.shape[1] - 1)] > 127
            votes += (v >= v_min) and static
        if votes * 2 > len(elements):
            ids.append(pid)
            xyz.append(point.xyz)
    if not ids:
        return np.zeros(0, np.int64)
    xyz = np.array(xyz)
    _, near = cKDTree(centers).query(xyz)
    below = (xyz - centers[near]) @ up < 0
    return np.array(ids)[below]


# ----------------------------------------------------------------------------- scale sources

def gps_distance_m(csv_path: Path) -> float:
    """Walked distance from a GoPro GPS5 CSV: integral of speed2d (fix >= 2 rows)."""
    t, speed = [], []
    with open(csv_path, newline="") as f:
        for row in csv.DictReader(f):
            if int(float(row.get("gps_fix", 3) or 0)) >= 2:
                t.append(float(row["t_approx_s"]))
                speed.append(float(row["speed2d_mps"]))
    if len(t) < 2:
        raise StageError(STAGE, "bad_gps", f"{csv_path} has fewer than 2 GPS rows with a fix")
    t_arr, s_arr = np.array(t), np.array(speed)
    return float(np.sum(np.diff(t_arr) * 0.5 * (s_arr[1:] + s_arr[:-1])))


def horizontal_path_length(positions: np.ndarray, n: np.ndarray, window: int = 5) -> float:
    """Path length of positions [N, 3] projected on the plane with normal n, lightly smoothed."""
    p = positions - np.outer(positions @ n, n)
    if len(p) > window:
        k = np.ones(window) / window
        p = np.stack([np.convolve(p[:, i], k, mode="valid") for i in range(3)], 1)
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def choose_scale(conf: MetricConfig, heights: np.ndarray, centers: np.ndarray,
                 n: np.ndarray) -> tuple[float, str, dict]:
    """Scale factor, its source name and facts for frame.json."""
    source = conf.scale_source
    if source == "auto":
        source = "gps" if conf.gps_csv else "path_length" if conf.known_path_length_m else "capture_height"
    sfm_len = horizontal_path_length(centers, n)
    facts = {"sfm_path_length": sfm_len, "median_camera_height_sfm": float(np.median(heights))}
    if source == "capture_height":
        return conf.capture_height_m / float(np.median(heights)), source, facts
    if source == "gps":
        metres = gps_distance_m(Path(conf.gps_csv))
        facts["gps_csv"] = conf.gps_csv
    elif source == "path_length":
        metres = conf.known_path_length_m
    else:
        raise ValueError(f"unknown scale_source {conf.scale_source!r}")
    facts["path_length_m"] = metres
    if sfm_len <= 0 or metres <= 0:
        raise StageError(STAGE, "bad_scale", f"path lengths sfm={sfm_len}, {source}={metres}")
    return metres / sfm_len, source, facts


# ----------------------------------------------------------------------------- stage

def timestamps(images_dir: str, names: list[str], fps: float) -> tuple[list[int], list[float], str]:
    """Frame index (position among the SfM input frames) and timestamp of each name."""
    folder = Path(images_dir) if images_dir else None
    table = folder.parent / decode.OUTPUTS.frames if folder else None  # beside decode's images/
    all_names = sorted(p.name for p in folder.iterdir()) if folder and folder.is_dir() else names
    pos = {n: i for i, n in enumerate(all_names)}
    index = [pos.get(n, i) for i, n in enumerate(names)]
    if table is not None and table.exists():
        import pyarrow.parquet as pq

        rows = pq.read_table(table, columns=["image", "timestamp"]).to_pylist()
        ts = {r["image"]: r["timestamp"] for r in rows if r["image"]}
        if all(n in ts for n in names):
            return index, [float(ts[n]) for n in names], decode.OUTPUTS.frames
    return index, [i / fps for i in index], "index/fps"


def load_sfm(sfm_dir: Path) -> tuple[Any, Path, Optional[Path], dict]:
    import pycolmap

    und = Path(sfm_dir) / sfm.OUTPUTS.undistorted
    if not (und / "sparse").is_dir():
        raise StageError(STAGE, "missing_input", f"{sfm_dir} has no undistorted/sparse model")
    quality = json.loads((Path(sfm_dir) / sfm.OUTPUTS.quality).read_text())
    if quality.get("images_dir"):  # relative to the SfM folder (absolute in older outputs)
        quality["images_dir"] = str(Path(sfm_dir) / quality["images_dir"])
    masks = und / "masks" if (und / "masks").is_dir() else None
    return pycolmap.Reconstruction(str(und / "sparse")), und / "images", masks, quality


def align(conf: MetricConfig, rec: Any, masks: Optional[Path]) -> tuple[float, np.ndarray, np.ndarray, dict]:
    """Sim(3) (s, R, t) taking SfM coords to the metric world: x' = s R x + t; plus facts."""
    names, c2w = camera_arrays(rec)
    centers = c2w[:, :3, 3]  # [N, 3]
    up, up_source = up_prior(c2w)
    ids = ground_candidates(rec, masks, centers, up, conf)
    if len(ids) < conf.min_ground_points:
        raise StageError(STAGE, "no_ground_plane",
                         f"only {len(ids)} SfM points below the cameras (need {conf.min_ground_points})")
    all_pts = np.array([rec.point3D(int(i)).xyz for i in ids])  # [M, 3]
    relaxed = False
    try:
        n, d, inl, pts, heights = fit_ground(all_pts, centers, up, conf)
    except StageError:  # sparse photo sequences: wider corridor, looser inlier band, once
        relaxed = True
        n, d, inl, pts, heights = fit_ground(all_pts, centers, up, relax(conf))
    s, source, scale_facts = choose_scale(conf, heights, centers, n)
    R = rotation_to_world(n, centers[-1] - centers[0])
    origin = centers[0] - heights[0] * n  # foot of the first camera on the plane
    t = -s * R @ origin
    res = np.abs(pts[inl] @ n + d) * s
    facts = {
        "scale_source": source, "scale": s, **scale_facts,
        "plane_sfm": {"normal": n.tolist(), "d": d},
        "plane_candidates": int(len(ids)), "plane_inliers": int(inl.sum()), "plane_relaxed": relaxed,
        "plane_residual_rms_m": float(np.sqrt((res ** 2).mean())),
        "plane_residual_median_m": float(np.median(res)),
        "gravity_prior_angle_deg": angle_deg(n, up), "gravity_prior": up_source,
        "camera_height_m": {"median": float(np.median(heights) * s),
                            "p10": float(np.percentile(heights, 10) * s),
                            "p90": float(np.percentile(heights, 90) * s)},
        "sim3": {"scale": s, "rotation": R.tolist(), "translation": t.tolist()},
    }
    return s, R, t, facts


def relax(conf: MetricConfig) -> MetricConfig:
    """Looser ground search for sparse models (e.g. photos metres apart)."""
    return replace(conf, corridor_frac_of_height=2 * conf.corridor_frac_of_height,
                   inlier_frac_of_height=2 * conf.inlier_frac_of_height,
                   min_ground_points=max(10, conf.min_ground_points * 2 // 3))


def fit_ground(all_pts: np.ndarray, centers: np.ndarray, up: np.ndarray, conf: MetricConfig
               ) -> tuple[np.ndarray, float, np.ndarray, np.ndarray, np.ndarray]:
    """Plane (n, d), inlier mask, corridor points [M, 3] and camera heights [N] (SfM units)."""
    pts, rough_h = corridor(all_pts, centers, up, conf.corridor_frac_of_height)
    if len(pts) < conf.min_ground_points:
        raise StageError(STAGE, "no_ground_plane", f"only {len(pts)} SfM points along the path")
    n, d, inl = ransac_plane(pts, up, conf.inlier_frac_of_height * rough_h, conf.max_tilt_deg,
                             conf.ransac_iters, conf.seed, conf.below_penalty)
    heights = local_heights(centers, pts[inl], n, d, conf.local_radius_frac * rough_h)  # [N]
    if np.median(heights) <= 0 or inl.sum() < conf.min_ground_points:
        raise StageError(STAGE, "no_ground_plane",
                         f"plane with {int(inl.sum())} inliers lies above the cameras or is too thin")
    return n, d, inl, pts, heights


def apply_sim3(rec: Any, s: float, R: np.ndarray, t: np.ndarray) -> None:
    import pycolmap

    rec.transform(pycolmap.Sim3d(s, pycolmap.Rotation3d(R), t))


def posed_clip(conf: MetricConfig, rec: Any, images: Path, masks: Optional[Path],
               frames_dir: str, facts: dict) -> PosedClip:
    names, c2w = camera_arrays(rec)
    index, ts, ts_source = timestamps(frames_dir, names, conf.fallback_fps)
    split = holdout_split(len(names), conf.holdout_every)
    cam = next(iter(rec.cameras.values()))
    K = cam.calibration_matrix()
    frames = [PosedFrame(index[i], n, ts[i], cam.width, cam.height, K.copy(), c2w[i], split[i])
              for i, n in enumerate(names)]
    pts = list(rec.points3D.values())
    xyz = np.array([p.xyz for p in pts]).reshape(-1, 3)  # [M, 3]
    rgb = np.array([p.color for p in pts], np.uint8).reshape(-1, 3)  # [M, 3]
    info = {"units": "m", "up_axis": "+z", "ground_z": 0.0, "timestamps": ts_source,
            "capture_height_m": conf.capture_height_m, **facts}
    return PosedClip(frames, images, masks, xyz, rgb, info)


def work(conf: MetricConfig, sfm_dir: Path, frames_dir: Optional[Path] = None) -> StageWork:
    """Aligning a finished SfM output to the metric gravity frame: keyed by the config and the
    sfm key.

    frames_dir: the SfM input frames (decode's `images/`, with `frames.parquet` beside it) for
    frame indices and timestamps; the pipeline passes it. Left out (a standalone SfM folder), the
    folder recorded in the sfm `quality.json` is used.
    """
    sfm_dir = Path(sfm_dir)
    sfm_key = finished_key(sfm_dir, STAGE, f"{sfm_dir} is not a finished sfm output")
    return StageWork(STAGE, STAGE_VERSION, conf, (sfm_key,),
                     lambda out_dir: build(conf, sfm_dir, out_dir, frames_dir))


def build(conf: MetricConfig, sfm_dir: Path, out_dir: Path, frames_dir: Optional[Path] = None) -> dict:
    """Save the aligned PosedClip, `sparse/` and `transforms.json` in the empty `out_dir`;
    returns the summary."""
    rec, images, masks, quality = load_sfm(sfm_dir)
    s, R, t, facts = align(conf, rec, masks)
    apply_sim3(rec, s, R, t)
    clip = posed_clip(conf, rec, images, masks, str(frames_dir or quality.get("images_dir", "")), facts)
    clip.save(out_dir)
    write_colmap(rec, out_dir / OUTPUTS.colmap)
    mask_names = {p.name[:-4] for p in masks.glob("*.png")} if masks else None
    write_transforms(rec, out_dir / "transforms.json", str(images.resolve()),
                     str(masks.resolve()) if masks else None, mask_names)
    summary = {k: facts[k] for k in ("scale_source", "scale", "plane_inliers",
                                     "plane_residual_rms_m", "gravity_prior_angle_deg")}
    return {**summary, "frames": len(clip.frames)}
