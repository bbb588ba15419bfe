"""Pinhole camera with an OpenCV-axes world-to-camera pose (x right, y down, z forward).

Pixel (row i, col j) has its centre at (j + 0.5, i + 0.5) in the coordinates of
cx, cy (COLMAP convention); see docs/splat_renderer.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch


def _as_tensor(x, dtype=torch.float64) -> torch.Tensor:
    return torch.as_tensor(np.asarray(x) if not torch.is_tensor(x) else x, dtype=dtype)


@dataclass
class Camera:
    """Intrinsics (pixels) + world_to_cam [4, 4]."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    world_to_cam: torch.Tensor  # [4, 4]

    def __post_init__(self) -> None:
        self.world_to_cam = _as_tensor(self.world_to_cam, torch.float64)
        if self.world_to_cam.shape != (4, 4):
            raise ValueError(f"Camera.world_to_cam must be [4, 4], got {tuple(self.world_to_cam.shape)}")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"Camera size must be positive, got {self.width}x{self.height}")
        self.fx, self.fy, self.cx, self.cy = map(float, (self.fx, self.fy, self.cx, self.cy))
        self.width, self.height = int(self.width), int(self.height)

    @classmethod
    def from_cam_to_world(cls, K, c2w, width: int, height: int) -> "Camera":
        """From a 3x3 intrinsic matrix and a cam-to-world [4, 4] (or [3, 4]) pose."""
        K = _as_tensor(K)
        c2w = _as_tensor(c2w)
        if c2w.shape == (3, 4):
            c2w = torch.cat([c2w, torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=c2w.dtype)])
        return cls(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]),
                   width, height, torch.linalg.inv(c2w))

    @property
    def K(self) -> torch.Tensor:
        """Intrinsic matrix [3, 3] (float64)."""
        return torch.tensor([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]],
                            dtype=torch.float64)

    @property
    def cam_to_world(self) -> torch.Tensor:
        """Inverse pose [4, 4]."""
        return torch.linalg.inv(self.world_to_cam)

    @property
    def center(self) -> torch.Tensor:
        """Camera centre in world coordinates [3]."""
        R, t = self.world_to_cam[:3, :3], self.world_to_cam[:3, 3]
        return -R.T @ t

    def scaled(self, factor: float) -> "Camera":
        """Same pose, image resized by `factor` (intrinsics scaled, size rounded)."""
        w, h = max(1, round(self.width * factor)), max(1, round(self.height * factor))
        sx, sy = w / self.width, h / self.height
        return Camera(self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, w, h,
                      self.world_to_cam.clone())


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> torch.Tensor:
    """World-to-camera [4, 4] (OpenCV axes) for a camera at `eye` looking at `target`.

    `up` is the world up direction; the image y axis points opposite to it.
    """
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)  # right = forward x up (with y down)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: view direction is parallel to up")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: camera axes in world
    w2c = np.eye(4)
    w2c[:3, :3] = R
    w2c[:3, 3] = -R @ eye
    return torch.from_numpy(w2c)


def pinhole(width: int, height: int, fov_x_deg: float, world_to_cam) -> Camera:
    """Camera with square pixels, principal point at the image centre."""
    fx = 0.5 * width / np.tan(np.deg2rad(fov_x_deg) / 2)
    return Camera(fx, fx, width / 2, height / 2, width, height, world_to_cam)
