"""Hand-held walking trajectory: forward at walk_speed with step bob, sway and smooth jitter."""

from __future__ import annotations

import numpy as np

from vid2sim.factory.synthetic.config import StreetConfig

# OpenCV camera (x right, y down, z forward) looking along world +x with z up:
# camera x = world -y, camera y = world -z, camera z = world +x.
CAM_TO_WORLD_BASE = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _rot_z(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def _rot_y(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def _rot_x(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def smooth_noise(rng: np.random.Generator, t: np.ndarray, freqs=(0.23, 0.41, 0.77, 1.3)) -> np.ndarray:
    """Zero-mean smooth signal in about [-1, 1]: a sum of sinusoids with random phases."""
    out = np.zeros_like(t)
    for f in freqs:
        out += np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)) / len(freqs) ** 0.5
    return out / 1.2


def walking_poses(conf: StreetConfig) -> tuple[np.ndarray, np.ndarray]:
    """Timestamps [N] and camera-to-world poses [N, 4, 4] (OpenCV axes, world z up, ground z = 0)."""
    rng = np.random.default_rng(conf.seed + 7919)
    t = np.arange(conf.n_frames) / conf.fps  # [N]
    x_start = (conf.length_m - conf.path_length) / 2.0
    phase = rng.uniform(0, 2 * np.pi)
    w = 2 * np.pi * conf.step_hz
    x = x_start + conf.walk_speed * t + 0.02 * np.sin(w * t + phase)  # surge with each step
    y = conf.walk_lateral * conf.sidewalk_width + conf.sway_amplitude * np.sin(w / 2 * t + phase)
    y = y + 0.05 * smooth_noise(rng, t, (0.11, 0.17))
    z = conf.capture_height + conf.bob_amplitude * np.sin(w * t + phase)
    d = np.deg2rad
    yaw = d(conf.yaw_deg) + d(conf.yaw_jitter_deg) * smooth_noise(rng, t)
    pitch = d(conf.pitch_deg) + d(conf.pitch_jitter_deg) * (0.6 * smooth_noise(rng, t)
                                                           + 0.4 * np.sin(w * t + phase + 0.5))
    roll = d(conf.roll_jitter_deg) * (0.5 * smooth_noise(rng, t) + 0.5 * np.sin(w / 2 * t + phase))
    # world-frame yaw about +z, pitch about the body's left axis (+y), roll about forward (+x)
    R_body = _rot_z(yaw) @ _rot_y(-pitch) @ _rot_x(roll)  # [N, 3, 3] body (x fwd, y left, z up) -> world
    T = np.tile(np.eye(4), (len(t), 1, 1))
    T[:, :3, :3] = R_body @ CAM_TO_WORLD_BASE
    T[:, :3, 3] = np.stack([x, y, z], 1)
    return t, T
