"""Pose evaluation: Sim(3) (Umeyama) alignment, ATE and RPE, and relative rotation error
against a GoPro orientation stream.

Reads an estimate (PosedClip folder, COLMAP model folder, nerfstudio transforms.json or a KITTI
poses.txt) and a ground truth (KITTI poses.txt, a synthetic clip folder, transforms.json, or the
GoPro `telemetry_orientation_per_frame.csv`); returns a JSON-able report. Writes nothing.

GoPro CORI convention (measured on ../shared/data/gopro_max_sidewalk): the CSV stores CORI as
(w, x, y, z). With R(q) the rotation matrix of that quaternion, R(q)^T @ GRAV is constant over the
clip to within ~1 % (std 0.005 / 0.002 / 0.014) while R(q) @ GRAV drifts ~4x more, so R(q) maps
world -> camera (camera-to-world is R(q)^T, relative to the first frame). GRAV is ~(0, 0.99, 0.12)
for an upright camera: +y points down and +z forward-down, i.e. the GPMF camera axes are
OpenCV-like (x right, y down, z forward) up to the fixed camera-to-IMU rotation, which
`gopro_rotation_errors` estimates by fitting (`fit_extrinsic=True`). Relative rotations between
frames i and i+k are compared, which does not depend on either world frame.
"""

from __future__ import annotations

import csv
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np
from scipy.spatial.transform import Rotation

from vid2sim.factory.sfm.posed import PosedClip

GL_TO_CV = np.diag([1.0, -1.0, -1.0])  # flips camera y and z (OpenGL <-> OpenCV axes)


class PoseEvalError(ValueError):
    """Bad evaluation input; the message names the file and the reason."""

    def __init__(self, path: object, reason: str) -> None:
        self.path, self.reason = str(path), reason
        super().__init__(f"{path}: {reason}")


@dataclass
class Trajectory:
    """Camera-to-world poses keyed by frame index (OpenCV camera axes)."""

    keys: np.ndarray  # [N] int frame indices
    T: np.ndarray  # [N, 4, 4]
    timestamps: Optional[np.ndarray] = None  # [N] seconds
    source: str = ""
    extras: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.keys)

    @property
    def positions(self) -> np.ndarray:
        return self.T[:, :3, 3]  # [N, 3]


# ----------------------------------------------------------------------------- alignment / metrics
def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity dst ~ s R src + t (Umeyama 1991); src, dst [N, 3]."""
    if len(src) < 3 or src.shape != dst.shape:
        raise ValueError(f"umeyama needs >= 3 matching points, got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    var_s = (xs ** 2).sum() / len(src)
    s = float(np.trace(np.diag(D) @ S) / var_s) if with_scale and var_s > 0 else 1.0
    t = mu_d - s * R @ mu_s
    return s, R, t


def apply_sim3(T: np.ndarray, s: float, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Map camera-to-world poses [N, 4, 4] through x -> s R x + t (rotations stay orthonormal)."""
    out = T.copy()
    out[:, :3, :3] = R @ T[:, :3, :3]
    out[:, :3, 3] = s * T[:, :3, 3] @ R.T + t
    return out


def path_length(positions: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(positions, axis=0), axis=1).sum())


def rotation_angle_deg(R: np.ndarray) -> np.ndarray:
    """Angle of rotation matrices [..., 3, 3] in degrees."""
    c = (np.trace(R, axis1=-2, axis2=-1) - 1) / 2
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def ate(est: np.ndarray, gt: np.ndarray, with_scale: bool = True) -> dict:
    """Absolute trajectory error of positions est, gt [N, 3] after Sim(3) (or SE(3)) alignment."""
    s, R, t = umeyama(est, gt, with_scale)
    err = np.linalg.norm(est @ R.T * s + t - gt, axis=1)
    L = path_length(gt)
    rmse = float(np.sqrt((err ** 2).mean()))
    return {"rmse": rmse, "mean": float(err.mean()), "median": float(np.median(err)), "max": float(err.max()),
            "path_length": L, "rmse_pct_of_path": 100.0 * rmse / L if L > 0 else float("nan"),
            "scale": s, "rotation": R.tolist(), "translation": t.tolist(), "n": int(len(err))}


def rpe(est_T: np.ndarray, gt_T: np.ndarray, delta: int = 1, scale: float = 1.0) -> dict:
    """Relative pose error over frame pairs (i, i + delta); est positions are scaled by `scale` first."""
    if len(est_T) <= delta:
        raise ValueError(f"RPE needs more than {delta} poses, got {len(est_T)}")
    E = est_T.copy()
    E[:, :3, 3] *= scale
    inv = np.linalg.inv
    rel_e = inv(E[:-delta]) @ E[delta:]  # [M, 4, 4]
    rel_g = inv(gt_T[:-delta]) @ gt_T[delta:]
    D = inv(rel_g) @ rel_e
    te = np.linalg.norm(D[:, :3, 3], axis=1)
    re = rotation_angle_deg(D[:, :3, :3])
    return {"delta": delta, "trans_rmse": float(np.sqrt((te ** 2).mean())), "trans_mean": float(te.mean()),
            "rot_mean_deg": float(re.mean()), "rot_median_deg": float(np.median(re)),
            "rot_rmse_deg": float(np.sqrt((re ** 2).mean())), "n": int(len(te))}


# ----------------------------------------------------------------------------- loaders
def _frame_number(name: str, fallback: int) -> int:
    digits = re.findall(r"\d+", Path(name).stem)
    return int(digits[-1]) if digits else fallback


def load_kitti_poses(path: Path) -> Trajectory:
    """KITTI odometry poses.txt: one 3x4 row-major camera-to-world matrix per line."""
    path = Path(path)
    try:
        rows = np.loadtxt(path, ndmin=2)
    except (OSError, ValueError) as e:
        raise PoseEvalError(path, f"not a KITTI poses file ({e})") from e
    if rows.shape[1] != 12 or len(rows) == 0:
        raise PoseEvalError(path, f"expected 12 numbers per line, got shape {rows.shape}")
    T = np.tile(np.eye(4), (len(rows), 1, 1))
    T[:, :3, :] = rows.reshape(-1, 3, 4)
    return Trajectory(np.arange(len(rows)), T, source=f"kitti:{path}")


def load_posed_clip(folder: Path) -> Trajectory:
    """A PosedClip folder (cameras.parquet) or a synthetic clip (same files + ground_truth.json)."""
    folder = Path(folder)
    if not (folder / "cameras.parquet").is_file():
        raise PoseEvalError(folder, "no cameras.parquet (not a PosedClip / synthetic clip folder)")
    clip = PosedClip.load(folder)
    keys = np.array([f.index for f in clip.frames])
    T = np.stack([f.cam_to_world for f in clip.frames])
    ts = np.array([f.timestamp for f in clip.frames], np.float64)
    return Trajectory(keys, T, ts, source=f"posed:{folder}", extras={"frame_info": clip.frame_info})


def load_transforms_json(path: Path) -> Trajectory:
    """nerfstudio/instant-ngp transforms.json (OpenGL camera axes) -> OpenCV camera-to-world."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
        frames = data["frames"]
    except (OSError, ValueError, KeyError) as e:
        raise PoseEvalError(path, f"not a transforms.json ({e})") from e
    keys, Ts = [], []
    for i, f in enumerate(frames):
        T = np.asarray(f["transform_matrix"], np.float64)
        T[:3, :3] = T[:3, :3] @ GL_TO_CV
        keys.append(_frame_number(f.get("file_path", ""), i))
        Ts.append(T)
    order = np.argsort(keys, kind="stable")
    return Trajectory(np.asarray(keys)[order], np.stack(Ts)[order], source=f"transforms:{path}")


def load_colmap_model(folder: Path) -> Trajectory:
    """A COLMAP model folder (cameras/images/points3D .bin or .txt) via pycolmap."""
    import pycolmap
    folder = Path(folder)
    try:
        rec = pycolmap.Reconstruction(str(folder))
    except Exception as e:  # pycolmap raises plain exceptions for unreadable models
        raise PoseEvalError(folder, f"unreadable COLMAP model ({e})") from e
    keys, Ts = [], []
    for image_id, im in rec.images.items():
        if not im.has_pose:
            continue
        w2c = im.cam_from_world().matrix()  # [3, 4]
        T = np.eye(4)
        T[:3, :3] = w2c[:, :3].T
        T[:3, 3] = -w2c[:, :3].T @ w2c[:, 3]
        keys.append(_frame_number(im.name, image_id))
        Ts.append(T)
    if not Ts:
        raise PoseEvalError(folder, "COLMAP model has no registered images")
    order = np.argsort(keys, kind="stable")
    return Trajectory(np.asarray(keys)[order], np.stack(Ts)[order], source=f"colmap:{folder}")


def load_trajectory(path: Path, fmt: str = "auto") -> Trajectory:
    """Dispatch on `fmt` (kitti | synthetic | posed | transforms | colmap | auto)."""
    path = Path(path)
    if not path.exists():
        raise PoseEvalError(path, "does not exist")
    if fmt == "auto":
        if path.is_dir():
            if (path / "cameras.parquet").is_file():
                fmt = "posed"
            elif (path / "sparse" / "0").is_dir():
                path, fmt = path / "sparse" / "0", "colmap"
            elif (path / "transforms.json").is_file():
                path, fmt = path / "transforms.json", "transforms"
            else:
                fmt = "colmap"
        else:
            fmt = "transforms" if path.suffix == ".json" else "kitti"
    loaders = {"kitti": load_kitti_poses, "synthetic": load_posed_clip, "posed": load_posed_clip,
               "transforms": load_transforms_json, "colmap": load_colmap_model}
    if fmt not in loaders:
        raise PoseEvalError(path, f"unknown pose format {fmt!r}; known: {sorted(loaders)} or auto")
    return loaders[fmt](path)


# ----------------------------------------------------------------------------- matching + report
def match(est: Trajectory, gt: Trajectory, by: str = "auto", gt_fps: Optional[float] = None
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pair estimate and GT frames; returns (keys [M], est_T [M, 4, 4], gt_T [M, 4, 4])."""
    if by == "auto":
        by = "timestamp" if est.timestamps is not None and gt.timestamps is not None else "index"
    if by == "timestamp":
        fps = gt_fps or 1.0 / np.median(np.diff(gt.timestamps))
        est_keys = np.round(est.timestamps * fps).astype(int)
        gt_keys = np.round(gt.timestamps * fps).astype(int)
    else:
        est_keys, gt_keys = est.keys, gt.keys
    common, ie, ig = np.intersect1d(est_keys, gt_keys, return_indices=True)
    return common, est.T[ie], gt.T[ig]


def evaluate(est: Trajectory, gt: Trajectory, deltas: tuple[int, ...] = (1, 10), by: str = "auto",
             with_scale: bool = True) -> dict:
    """ATE (Sim(3)-aligned) + RPE for each frame delta; registered fraction vs the GT frame count."""
    keys, E, G = match(est, gt, by)
    if len(keys) < 3:
        raise PoseEvalError(est.source, f"only {len(keys)} frames match the ground truth {gt.source}")
    a = ate(E[:, :3, 3], G[:, :3, 3], with_scale)
    Ea = apply_sim3(E, a["scale"], np.asarray(a["rotation"]), np.asarray(a["translation"]))
    rep = {"estimate": est.source, "ground_truth": gt.source, "n_matched": int(len(keys)),
           "n_gt": int(len(gt)), "n_estimate": int(len(est)), "matched_fraction": len(keys) / len(gt),
           "ate": a, "rpe": {}}
    for d in deltas:
        if len(keys) > d:
            rep["rpe"][str(d)] = rpe(Ea, G, d)
    return rep


# ----------------------------------------------------------------------------- GoPro orientation
def load_gopro_orientation(path: Path, stabilised: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """telemetry_orientation_per_frame.csv -> (frame indices [N], camera-to-world rotations [N, 3, 3]).

    CORI (w, x, y, z) maps world -> camera body (see the module docstring). The GoPro MAX
    video is stabilised (HyperSmooth): the orientation of the PIXELS is IORI * CORI, and CORI
    alone disagrees with the image by ~1 deg per frame. `stabilised=True` (default) returns
    the image orientation, camera-to-world = (IORI * CORI)^T; False returns the body, R(CORI)^T.
    """
    path = Path(path)
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
        idx = np.array([int(r["sample"]) for r in rows])
        rot = Rotation.from_quat([[float(r[f"cori_{a}"]) for a in "xyzw"] for r in rows])
        if stabilised and rows:
            rot = Rotation.from_quat([[float(r[f"iori_{a}"]) for a in "xyzw"] for r in rows]) * rot
    except (OSError, KeyError, ValueError) as e:
        raise PoseEvalError(path, "not a GoPro orientation CSV with sample, cori_w..cori_z "
                                  f"(and iori_w..iori_z when stabilised) columns ({e})") from e
    if len(idx) == 0:
        raise PoseEvalError(path, "no rows")
    return idx, rot.as_matrix().transpose(0, 2, 1)


def _relative(R: np.ndarray, k: int) -> np.ndarray:
    return np.einsum("nji,njk->nik", R[:-k], R[k:])  # R_i^T R_{i+k}, [M, 3, 3]


def fit_extrinsic(rel_est: np.ndarray, rel_ref: np.ndarray) -> np.ndarray:
    """X (estimate camera -> reference camera) minimising |rotvec(rel_est) - X^T rotvec(rel_ref)|."""
    a = Rotation.from_matrix(rel_est).as_rotvec()  # [M, 3]
    b = Rotation.from_matrix(rel_ref).as_rotvec()
    _, Xt, _ = umeyama(b, a, with_scale=False) if len(a) >= 3 else (1.0, np.eye(3), None)
    return Xt.T


def gopro_rotation_errors(est: Trajectory, csv_path: Path, deltas: tuple[int, ...] = (1, 5, 15),
                          fit: bool = True, fps: Optional[float] = None, stride: int = 1,
                          stabilised: bool = True) -> dict:
    """Relative rotation error (degrees) between estimate and the telemetry orientation of the
    image (IORI * CORI, see `load_gopro_orientation`) over frame pairs (i, i + k).

    `angle_gap`: | angle(rel_est) - angle(rel_cori) |, no frame assumption at all.
    `fitted`: angle(rel_est^T X^T rel_cori X) with the camera-to-IMU rotation X fitted on delta=max.
    Estimate frame j is video frame j * stride (or round(timestamp * fps) when fps is given);
    deltas count estimate frames.
    """
    gidx, Rg = load_gopro_orientation(csv_path, stabilised)
    keys = est.keys * stride  # estimate frame j is video frame j * stride (sub-sampled frames)
    if fps is not None and est.timestamps is not None:  # estimate frames sub-sampled: key by time
        keys = np.round(est.timestamps * fps).astype(int)
    common, ie, ig = np.intersect1d(keys, gidx, return_indices=True)
    if len(common) < 3:
        raise PoseEvalError(csv_path, f"only {len(common)} estimate frames have telemetry")
    Re, Rg = est.T[ie, :3, :3], Rg[ig]
    rep: dict = {"n_matched": int(len(common)), "deltas": {}, "convention":
                 "camera_to_world = R(iori * cori)^T (stabilised image)" if stabilised
                 else "camera_to_world = R(cori)^T (camera body)", "pairs": "R_i^T R_{i+k}"}
    X = np.eye(3)
    if fit:
        k = max(d for d in deltas if d < len(common))
        X = fit_extrinsic(_relative(Re, k), _relative(Rg, k))
        rep["extrinsic_cam_to_imu"] = X.tolist()
        rep["extrinsic_angle_deg"] = float(rotation_angle_deg(X))
    for k in deltas:
        if k >= len(common):
            continue
        ok = (common[k:] - common[:-k]) == k * stride  # only pairs exactly k samples apart
        rel_e, rel_g = _relative(Re, k)[ok], _relative(Rg, k)[ok]
        if len(rel_e) == 0:
            continue
        gap = np.abs(rotation_angle_deg(rel_e) - rotation_angle_deg(rel_g))
        fitted = rotation_angle_deg(np.einsum("nji,njk->nik", rel_e, X.T @ rel_g @ X))
        rep["deltas"][str(k)] = {"n": int(len(gap)), "angle_gap_mean_deg": float(gap.mean()),
                                 "angle_gap_median_deg": float(np.median(gap)),
                                 "fitted_mean_deg": float(fitted.mean()),
                                 "fitted_median_deg": float(np.median(fitted)),
                                 "ref_motion_mean_deg": float(rotation_angle_deg(rel_g).mean())}
    return rep


def evaluate_paths(estimate: Path, gt: Path, gt_format: str = "auto", est_format: str = "auto",
                   deltas: tuple[int, ...] = (1, 10), fps: Optional[float] = None, stride: int = 1) -> dict:
    """Top-level entry used by `vid2sim eval poses`."""
    est = load_trajectory(estimate, est_format)
    gt = Path(gt)
    if gt_format == "auto" and gt.suffix == ".csv":
        gt_format = "gopro-csv"
    if gt_format == "gopro-csv":
        rot = gopro_rotation_errors(est, gt, fps=fps, stride=stride)
        return {"estimate": est.source, "ground_truth": f"gopro:{gt}", "rotation": rot}
    return evaluate(est, load_trajectory(gt, gt_format), deltas)
