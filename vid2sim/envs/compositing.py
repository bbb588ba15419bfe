"""Z-buffer compositing of two layers (the paper: obstacles and people over the splat render).

Each layer is (rgb [H, W, 3] u8, depth [H, W] camera z). Per pixel the nearer layer wins;
a depth that is not a positive finite number (+inf, 0 from an uncovered splat pixel, NaN)
counts as empty. Ties go to layer a.
"""

from __future__ import annotations

import numpy as np


def _depth_or_inf(depth: np.ndarray) -> np.ndarray:
    """Depth [H, W] as float32 with every empty pixel (<= 0, NaN) set to +inf."""
    d = np.asarray(depth, dtype=np.float32)
    return np.where(d > 0, d, np.float32(np.inf))  # NaN > 0 is False


def composite(rgb_a: np.ndarray, depth_a: np.ndarray, rgb_b: np.ndarray, depth_b: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """Nearest of two layers per pixel: (rgb [H, W, 3] u8, depth [H, W] f32, +inf where empty)."""
    if rgb_a.shape != rgb_b.shape or depth_a.shape != depth_b.shape:
        raise ValueError(f"layers differ in shape: {rgb_a.shape}/{depth_a.shape} vs "
                         f"{rgb_b.shape}/{depth_b.shape}")
    if rgb_a.shape[:2] != depth_a.shape:
        raise ValueError(f"rgb {rgb_a.shape} and depth {depth_a.shape} differ in size")
    da, db = _depth_or_inf(depth_a), _depth_or_inf(depth_b)
    b_wins = db < da  # [H, W]
    rgb = np.where(b_wins[..., None], rgb_b, rgb_a).astype(np.uint8)  # [H, W, 3]
    return rgb, np.where(b_wins, db, da)
