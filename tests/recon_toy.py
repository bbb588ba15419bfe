"""A tiny ray-cast PosedClip with exact depth, for tests and as a benchmark fallback.

Scene (metric, z up): textured ground z = 0, walls at y = +-2, an end wall at x = 14 and a
box obstacle; the camera walks along +x at 1.5 m height looking forward (OpenCV axes).
Writes: images/*.png, gt_depth/*.npy (metres), a PosedClip (cameras.parquet, points.npz,
frame.json with gt_depth_dir).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from vid2sim.factory.sfm.posed import PosedClip, PosedFrame, holdout_split

# planes: (normal axis, offset, sign facing the corridor)
_PLANES = [(2, 0.0), (1, 2.0), (1, -2.0), (0, 14.0)]
_BOX = (np.array([5.0, -1.6, 0.0]), np.array([6.0, -0.6, 1.0]))


def _texture(p: np.ndarray) -> np.ndarray:
    """Deterministic colour [M, 3] in [0, 1] for world points p [M, 3] (multi-scale pattern)."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    a = np.sin(3.1 * x + 1.7 * y) * np.cos(2.3 * z + 0.9 * y)
    b = np.sin(7.3 * x - 5.1 * z + 2.2 * y) * 0.5
    c = (np.floor(x * 2) + np.floor(y * 2) + np.floor(z * 2)) % 2
    base = 0.5 + 0.25 * a + 0.15 * b
    return np.clip(np.stack([base + 0.1 * c, 0.8 * base + 0.15 * (1 - c), 0.6 * base + 0.2 * c], 1), 0, 1)


def _box_hit(o: np.ndarray, d: np.ndarray) -> np.ndarray:
    lo, hi = _BOX
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - o) / d, (hi - o) / d
    tmin = np.nanmax(np.minimum(t1, t2), axis=1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=1)
    return np.where((tmax >= tmin) & (tmin > 1e-6), tmin, np.inf)


def raycast(c2w: np.ndarray, K: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Image [H, W, 3] float and z-depth [H, W] (metres) of the toy scene."""
    j, i = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    dirs_c = np.stack([(j - K[0, 2]) / K[0, 0], (i - K[1, 2]) / K[1, 1], np.ones_like(j)], -1).reshape(-1, 3)
    d = dirs_c @ c2w[:3, :3].T  # [P, 3], camera z component 1
    o = np.broadcast_to(c2w[:3, 3], d.shape)
    t = np.full(d.shape[0], np.inf)
    for axis, off in _PLANES:
        with np.errstate(divide="ignore", invalid="ignore"):
            ti = (off - o[:, axis]) / d[:, axis]
        t = np.where((ti > 1e-6) & (ti < t), ti, t)
    t = np.minimum(t, _box_hit(o, d))
    t = np.where(np.isfinite(t), t, 0.0)
    pts = o + d * t[:, None]
    rgb = _texture(pts) * (t[:, None] > 0)
    return rgb.reshape(height, width, 3).astype(np.float32), t.reshape(height, width).astype(np.float32)


def toy_poses(n: int, step: float = 0.12) -> list[np.ndarray]:
    """Camera-to-world poses walking +x at 1.5 m, slight yaw wobble, looking forward."""
    poses = []
    for k in range(n):
        yaw = 0.05 * np.sin(0.7 * k)
        fwd = np.array([np.cos(yaw), np.sin(yaw), -0.08])
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, [0, 0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(fwd, right)
        c2w = np.eye(4)
        c2w[:3, :3] = np.stack([right, down, fwd], 1)
        c2w[:3, 3] = [0.5 + step * k, 0.2 * np.sin(0.3 * k), 1.5]
        poses.append(c2w)
    return poses


def make_toy_clip(out_dir: Path, n_frames: int = 17, width: int = 64, height: int = 48,
                  n_points: int = 3000, seed: int = 0) -> Path:
    """Write the toy PosedClip into out_dir/clip and return that folder."""
    out_dir = Path(out_dir)
    img_dir, depth_dir = out_dir / "images", out_dir / "gt_depth"
    img_dir.mkdir(parents=True, exist_ok=True)
    depth_dir.mkdir(exist_ok=True)
    f = 0.6 * width
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]])
    frames, split = [], holdout_split(n_frames)
    all_pts = []
    rng = np.random.default_rng(seed)
    for k, c2w in enumerate(toy_poses(n_frames)):
        rgb, depth = raycast(c2w, K, width, height)
        name = f"frame_{k:05d}.png"
        cv2.imwrite(str(img_dir / name), cv2.cvtColor((rgb * 255).round().astype(np.uint8), cv2.COLOR_RGB2BGR))
        np.save(depth_dir / f"frame_{k:05d}.npy", depth)
        frames.append(PosedFrame(k, name, k / 10.0, width, height, K, c2w, split[k]))
        if split[k] == "train":  # sparse "SfM" points: back-projected GT depth, jittered
            i, j = rng.integers(0, height, 400), rng.integers(0, width, 400)
            z = depth[i, j]
            cam = np.stack([(j + 0.5 - K[0, 2]) / f * z, (i + 0.5 - K[1, 2]) / f * z, z], 1)[z > 0]
            all_pts.append(cam @ c2w[:3, :3].T + c2w[:3, 3])
    xyz = np.concatenate(all_pts)
    xyz = xyz[rng.permutation(len(xyz))[:n_points]] + rng.normal(0, 0.01, (min(n_points, len(xyz)), 3))
    rgb = (_texture(xyz) * 255).astype(np.uint8)
    clip = PosedClip(frames=frames, images_dir=img_dir, points_xyz=xyz, points_rgb=rgb,
                     frame_info={"units": "m", "up": "z", "gt_depth_dir": str(depth_dir.resolve()),
                                 "scale_source": "toy"})
    return clip.save(out_dir / "clip")
