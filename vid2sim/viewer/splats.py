"""Splat layer: reads a bundle's splats.ply (3DGS layout) into what the browser renders.

The browser sorts and draws every Gaussian it is sent, so a scene is sent with at most
`budget` Gaussians (default DEFAULT_BUDGET): when a scene holds more, the ones kept are those
with the largest opacity x projected area (opacity x the product of the two largest scales),
the ones that cover most of the picture. Colours are the degree-0 SH term (view-independent).
The file's header is checked before its body is read (`read_splat_header`: layout, the MAX_SPLATS
cap, the body size).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from plyfile import PlyData

from vid2sim.formats.splat_ply import read_splat_header

DEFAULT_BUDGET = 400_000  # Gaussians sent to the browser
SH_C0 = 0.28209479177387814


@dataclass
class SplatLayer:
    """Gaussians ready for viser: centres [N, 3], covariances [N, 3, 3], rgb [N, 3] in 0..1,
    opacity [N, 1] in 0..1; `total` is the count in the file (N <= budget)."""

    centers: np.ndarray
    covariances: np.ndarray
    rgbs: np.ndarray
    opacities: np.ndarray
    total: int

    @property
    def shown(self) -> int:
        return int(len(self.centers))


def _columns(vertex, names: tuple[str, ...]) -> np.ndarray:
    return np.stack([np.asarray(vertex[n], np.float32) for n in names], 1)


def keep_mask(opacity: np.ndarray, scales: np.ndarray, budget: int) -> np.ndarray:
    """Indices of the `budget` Gaussians with the largest opacity x area (all when fewer)."""
    n = len(opacity)
    if n <= budget:
        return np.arange(n)
    s = np.sort(scales, axis=1)
    score = opacity.reshape(-1) * s[:, 1] * s[:, 2]
    return np.sort(np.argpartition(-score, budget - 1)[:budget])


def covariances(quat_wxyz: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """R diag(s^2) R^T per Gaussian from (w, x, y, z) quaternions [N, 4] and scales [N, 3]."""
    q = quat_wxyz / np.linalg.norm(quat_wxyz, axis=1, keepdims=True)
    w, x, y, z = q.T
    R = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                  2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                  2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], 1).reshape(-1, 3, 3)
    M = R * scales[:, None, :]
    return M @ M.transpose(0, 2, 1)


def read_splat_layer(path: Path, budget: int = DEFAULT_BUDGET) -> SplatLayer:
    """splats.ply -> SplatLayer of at most `budget` Gaussians (BundleError before the body is read
    when the header is not a 3DGS PLY within the caps)."""
    read_splat_header(path)
    vertex = PlyData.read(str(path))["vertex"]
    opacity = 1.0 / (1.0 + np.exp(-np.asarray(vertex["opacity"], np.float32)))
    scales = np.exp(_columns(vertex, ("scale_0", "scale_1", "scale_2")))
    keep = keep_mask(opacity, scales, max(1, int(budget)))
    quat = _columns(vertex, ("rot_0", "rot_1", "rot_2", "rot_3"))[keep]
    rgb = np.clip(0.5 + SH_C0 * _columns(vertex, ("f_dc_0", "f_dc_1", "f_dc_2"))[keep], 0.0, 1.0)
    return SplatLayer(centers=_columns(vertex, ("x", "y", "z"))[keep],
                      covariances=covariances(quat, scales[keep]).astype(np.float32),
                      rgbs=rgb, opacities=opacity[keep, None], total=int(vertex.count))
