"""The robot's front camera: intrinsics, mounting pose and per-episode sinusoidal jitter."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from vid2sim.envs.config import CameraConfig
from vid2sim.splats import Camera


@dataclass(frozen=True)
class Jitter:
    """Per-episode sinusoidal perturbation (official Vid2Sim Unity agent; ranges in CameraConfig)."""

    amp: np.ndarray  # [6] x, y, z (m, camera frame) then pitch, yaw, roll (rad)
    freq: np.ndarray  # [6] Hz
    phase: np.ndarray  # [6] rad

    @classmethod
    def sample(cls, conf: CameraConfig, rng: np.random.Generator) -> "Jitter":
        rot = math.radians(conf.jitter_rot_deg)
        hi = np.array([conf.jitter_pos] * 3 + [rot, rot, 5.0 * rot])
        return cls(rng.uniform(0.0, 1.0, 6) * hi, rng.uniform(*conf.jitter_freq, 6),
                   rng.uniform(0.0, 2 * math.pi, 6))

    @classmethod
    def none(cls) -> "Jitter":
        return cls(np.zeros(6), np.zeros(6), np.zeros(6))

    def at(self, t: float) -> np.ndarray:
        """Offsets [6] at time t (s)."""
        return self.amp * np.sin(2 * math.pi * self.freq * t + self.phase)


def intrinsics(conf: CameraConfig) -> np.ndarray:
    """K [3, 3]: the paper's 1280x720 sensor (Unity default 60 deg vertical FOV) scaled to W x H."""
    f = conf.focal
    return np.array([[f, 0.0, conf.width / 2], [0.0, f, conf.height / 2], [0.0, 0.0, 1.0]])


def _rot(axis: int, a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    i, j = [(1, 2), (0, 2), (0, 1)][axis]
    R = np.eye(3)
    R[i, i], R[i, j], R[j, i], R[j, j] = c, -s, s, c
    return R


def world_to_camera(x: float, y: float, yaw: float, conf: CameraConfig,
                    offset: np.ndarray | None = None) -> np.ndarray:
    """world_to_cam [4, 4] (OpenCV axes) of the front camera of a robot at (x, y, yaw)."""
    fwd = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
    down = np.array([0.0, 0.0, -1.0])
    R_cw = np.stack([right, down, fwd], axis=1)  # [3, 3] columns = camera axes in world
    centre = np.array([x, y, conf.mount_height]) + conf.mount_forward * fwd
    if offset is not None:
        R_cw = R_cw @ _rot(0, offset[3]) @ _rot(1, offset[4]) @ _rot(2, offset[5])
        centre = centre + R_cw @ offset[:3]
    w2c = np.eye(4)
    w2c[:3, :3] = R_cw.T
    w2c[:3, 3] = -R_cw.T @ centre
    return w2c


def splat_camera(conf: CameraConfig, world_to_cam: np.ndarray) -> Camera:
    """The splat engine's Camera for the env camera at world_to_cam [4, 4]."""
    K = intrinsics(conf)
    return Camera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], conf.width, conf.height,
                  torch.from_numpy(world_to_cam))
