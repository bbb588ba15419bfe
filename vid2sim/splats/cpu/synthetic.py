"""Synthetic scenes and cameras for tests and benchmarks (no data files needed).

`street_scene` mimics a reconstructed street: flat splats on a ground plane and on two
facades (world z up); `robot_camera` is a forward-looking camera at robot height.
"""

from __future__ import annotations

import numpy as np
import torch

from ..camera import Camera, look_at
from ..model import GaussianModel
from ..sh import rgb_to_sh0


def _flat_quats(normal_axis: int, n: int, rng: np.random.Generator) -> np.ndarray:
    """Quaternions [n, 4] (w,x,y,z) whose local z axis is the world axis `normal_axis`,
    with a random in-plane rotation."""
    ang = rng.uniform(0, np.pi, n)
    spin = np.stack([np.cos(ang / 2), np.zeros(n), np.zeros(n), np.sin(ang / 2)], 1)
    if normal_axis == 2:
        return spin
    # rotate local z to world y (facades face +-y): 90 deg about x, then spin about local z
    base = np.array([np.cos(np.pi / 4), -np.sin(np.pi / 4), 0.0, 0.0])
    w1, x1, y1, z1 = base
    w2, x2, y2, z2 = spin.T
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], 1)


def street_scene(n: int = 200_000, length: float = 120.0, width: float = 12.0,
                 height: float = 10.0, sh_degree: int = 3, seed: int = 0) -> GaussianModel:
    """n flat splats: half on the ground (z = 0), a quarter on each facade (y = +-width/2).

    Spacing follows the area per splat; scales are ~0.7x the spacing with a thin third axis.
    """
    rng = np.random.default_rng(seed)
    n_g = n // 2
    n_f = (n - n_g) // 2
    n_f2 = n - n_g - n_f
    xs = rng.uniform(-length / 2, length / 2, n)
    pts = np.zeros((n, 3))
    pts[:, 0] = xs
    pts[:n_g, 1] = rng.uniform(-width / 2, width / 2, n_g)
    pts[:n_g, 2] = rng.normal(0, 0.01, n_g)
    pts[n_g:n_g + n_f, 1] = width / 2 + rng.normal(0, 0.02, n_f)
    pts[n_g + n_f:, 1] = -width / 2 + rng.normal(0, 0.02, n_f2)
    pts[n_g:, 2] = rng.uniform(0, height, n - n_g)
    spacing_g = np.sqrt(length * width / n_g)
    spacing_f = np.sqrt(length * height / n_f)
    s = np.empty((n, 3))
    s[:n_g, :2] = spacing_g * rng.uniform(0.4, 1.0, (n_g, 2))
    s[n_g:, :2] = spacing_f * rng.uniform(0.4, 1.0, (n - n_g, 2))
    s[:, 2] = s[:, :2].min(1) * 0.1
    quats = np.concatenate([_flat_quats(2, n_g, rng), _flat_quats(1, n - n_g, rng)])
    base = np.where(np.arange(n)[:, None] < n_g, [[0.35, 0.35, 0.38]], [[0.6, 0.5, 0.45]])
    stripes = 0.15 * np.sin(xs * 1.3)[:, None]
    rgb = np.clip(base + stripes + rng.normal(0, 0.05, (n, 3)), 0, 1)
    K = (sh_degree + 1) ** 2
    sh = torch.zeros(n, K, 3)
    sh[:, 0] = rgb_to_sh0(torch.as_tensor(rgb, dtype=torch.float32))
    if K > 1:
        sh[:, 1:] = torch.as_tensor(rng.normal(0, 0.03, (n, K - 1, 3)), dtype=torch.float32)
    return GaussianModel(
        means=torch.as_tensor(pts, dtype=torch.float32),
        quats=torch.as_tensor(quats, dtype=torch.float32),
        log_scales=torch.as_tensor(np.log(s), dtype=torch.float32),
        opacity_logits=torch.as_tensor(rng.normal(2.0, 1.0, n), dtype=torch.float32),
        sh=sh)


def robot_camera(width: int = 128, height: int = 72, x: float = 0.0, y: float = 0.0,
                 yaw_deg: float = 0.0, height_m: float = 0.5, fov_x_deg: float = 90.0) -> Camera:
    """Forward camera at (x, y, height_m) looking horizontally along yaw (0 = +x)."""
    eye = np.array([x, y, height_m])
    yaw = np.deg2rad(yaw_deg)
    target = eye + np.array([np.cos(yaw), np.sin(yaw), 0.0])
    f = 0.5 * width / np.tan(np.deg2rad(fov_x_deg) / 2)
    return Camera(f, f, width / 2, height / 2, width, height, look_at(eye, target, (0, 0, 1)))


def random_blob_scene(n: int, seed: int = 0, sh_degree: int = 3) -> GaussianModel:
    """n random splats in front of a camera at the origin looking down +z (box 8 x 5 x 8 m)."""
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g) - 0.5) * torch.tensor([8.0, 5.0, 8.0])
    means[:, 2] += 6.0
    scale = 0.5 * (64.0 / n) ** (1 / 3)  # keeps the covered fraction similar across n
    return GaussianModel(
        means=means, quats=torch.randn(n, 4, generator=g),
        log_scales=torch.log(scale * (0.3 + torch.rand(n, 3, generator=g))),
        opacity_logits=torch.randn(n, generator=g) + 1.0,
        sh=torch.randn(n, (sh_degree + 1) ** 2, 3, generator=g) * 0.3)


def front_camera(width: int, height: int, fov_x_deg: float = 70.0) -> Camera:
    """Camera at the origin looking down +z (OpenCV axes), principal point at the centre."""
    f = 0.5 * width / np.tan(np.deg2rad(fov_x_deg) / 2)
    return Camera(f, f, width / 2, height / 2, width, height, torch.eye(4, dtype=torch.float64))
