"""Kerb drops beside the walked path, from the ground height profile across the walk.

A kerb runs along a sidewalk walk. Per-cell ground heights of a splat reconstruction are too
noisy (+-0.05-0.1 m per 0.1 m cell) for a local step test to find a 0.12 m kerb without also
firing on noise; aggregated ALONG the walk they are not. So: every ground cell gets path
coordinates (s along the walked path, d across it, left positive); per segment of `along_m`
and per side the lateral profile is the median cell height per `bin_m` of |d|; walking
outward from the walked corridor, the first place where the median level over the next
`lower_m` lies more than a drop threshold below the highest level over the last `upper_m` is
a kerb drop, and the cells of that segment and side from there outward are below it (the
robot, which climbs at most its step, does not go down there). The threshold is
max(min_drop_m, k x the profile noise), the noise measured on the profiles themselves.
Only drops are detected (a sidewalk walk beside a road); rises are left to the local step
test and the obstacles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from vid2sim.factory.geometry.walked_path import walked_path
from vid2sim.ranges import checked


@checked
@dataclass(frozen=True)
class KerbConfig:
    along_m: float = 2.0  # profile segment length along the walk
    bin_m: float = 0.1  # lateral bin of the profile
    upper_m: float = 0.3  # the level before a drop: highest bin over this much inward
    lower_m: float = 0.4  # the level after it: median of the bins over this much outward
    max_lateral_m: float = 5.0  # profiles reach this far from the path
    # ground cells a bin needs (a 2 m x 0.1 m bin holds 20): 6 gave walkable IoU 0.755 on
    # the demo street against 0.728 with 3 (noisier sparse bins fire; without the local step
    # test and the growth up to obstacles); GoPro unchanged
    min_cells: int = 6
    upper: str = "median"  # inward level: "median" or "max" of its bins
    min_drop_m: float = 0.08  # m, smallest height drop between the levels that counts as a kerb
    k: float = 4.0  # drop threshold = max(min_drop_m, k x profile noise)
    # the inward level may come from bins up to this much further in than upper_m, across
    # bins without ground (a planter or a parked car hides the sidewalk's outer part from a
    # forward-looking camera): a drop between the last seen sidewalk and the first seen road
    # is found where the road is first seen again. 0: the inward bins must adjoin. Demo
    # street (benchmarks/meshing.py variants default / kerb_gap_1m / kerb_gap_0): walkable IoU 0.702 -> 0.797
    # (1 m) -> 0.809 (2 m), the unseen sidewalk behind a planter grows up to the kerb and the
    # road beside it is no longer walkable; an earlier build 0.766 -> 0.798; exact GT 0.895
    # unchanged; GoPro builds: path unchanged, walkable area -0.2 m^2 at most
    max_gap_m: float = 2.0


def path_coordinates(xy: np.ndarray, path_xy: np.ndarray, spacing_m: float = 0.05
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(s [N] along the walked path, d [N] signed distance across it, left of the walking
    direction positive) of points xy [N, 2]; path_xy [T, 2] is the camera path."""
    dense = walked_path(np.column_stack([path_xy, np.zeros(len(path_xy))]), spacing_m)[:, :2]
    if len(dense) < 2:
        return np.zeros(len(xy)), np.linalg.norm(xy - dense[0], axis=1)
    tan = np.gradient(dense, axis=0)  # [S, 2]
    tan /= np.maximum(np.linalg.norm(tan, axis=1, keepdims=True), 1e-12)
    i = cKDTree(dense).query(xy)[1]  # [N]
    rel = xy - dense[i]
    d = tan[i, 0] * rel[:, 1] - tan[i, 1] * rel[:, 0]
    return i * spacing_m, d


def lateral_profiles(s: np.ndarray, d: np.ndarray, z: np.ndarray, n_seg: int,
                     conf: KerbConfig) -> np.ndarray:
    """Median height [n_seg, 2, B] per segment, side (0: left, 1: right) and |d| bin of the
    cells (s, d, z) [N]; NaN where a bin has fewer than min_cells cells."""
    nb = int(np.ceil(conf.max_lateral_m / conf.bin_m))
    seg = np.clip((s / conf.along_m).astype(np.int64), 0, n_seg - 1)
    side = (d < 0).astype(np.int64)
    b = (np.abs(d) / conf.bin_m).astype(np.int64)
    ok = b < nb
    label = ((seg * 2 + side) * nb + b)[ok]
    out = np.full(n_seg * 2 * nb, np.nan)
    idx, counts = np.unique(label, return_counts=True)
    idx = idx[counts >= conf.min_cells]
    if len(idx):
        out[idx] = ndimage.median(z[ok], labels=label + 1, index=idx + 1)
    return out.reshape(n_seg, 2, nb)


def profile_noise(prof: np.ndarray) -> float:
    """Robust sigma of one bin's level: 1.4826 MAD of neighbouring-bin differences / sqrt 2."""
    diff = np.diff(prof, axis=-1)
    diff = diff[np.isfinite(diff)]
    if len(diff) == 0:
        return 0.0
    return float(1.4826 * np.median(np.abs(diff - np.median(diff))) / np.sqrt(2.0))


def first_drop(prof: np.ndarray, start: int, n_up: int, n_low: int, thr: float,
               upper: str = "median", n_gap: int = 0) -> int:
    """First bin index b >= start of a profile [B] whose outward level (median of the valid
    bins b..b+n_low, at least half of them valid) lies more than thr below the inward level
    (`upper` of the last n_up valid bins among b-n_up-n_gap..b-1), and stays below it (every
    outward bin more than thr / 2 below); -1 when none."""
    agg = np.median if upper == "median" else np.max
    valid = np.isfinite(prof)
    for b in range(max(start, 1), len(prof) - n_low + 1):
        lo = max(b - n_up - n_gap, 0)
        up = prof[lo + np.flatnonzero(valid[lo:b])[-n_up:]]
        low = prof[b:b + n_low]
        low = low[np.isfinite(low)]
        if not len(up) or 2 * len(low) < n_low:
            continue
        level = agg(up)
        if level - np.median(low) > thr and level - low.max() > thr / 2:
            return b
    return -1


def kerb_cells(z: np.ndarray, seen: np.ndarray, origin: np.ndarray, res: float,
               path_xy: np.ndarray, start_m: float, conf: KerbConfig) -> np.ndarray:
    """Cells [H, W] bool beyond a kerb drop (module docstring). z [H, W] per-cell ground
    height where seen [H, W]; path_xy [T, 2]; drops are searched from start_m out."""
    H, W = seen.shape
    rows, cols = np.mgrid[0:H, 0:W]
    centres = np.stack([origin[0] + (cols.ravel() + 0.5) * res,
                        origin[1] + (rows.ravel() + 0.5) * res], 1)  # [H * W, 2]
    s, d = path_coordinates(centres, path_xy)
    length = float(np.sum(np.linalg.norm(np.diff(path_xy, axis=0), axis=1))) if len(path_xy) > 1 else 0.0
    n_seg = max(1, int(np.ceil(length / conf.along_m)))
    flat_seen = seen.ravel()
    prof = lateral_profiles(s[flat_seen], d[flat_seen], z.ravel()[flat_seen], n_seg, conf)
    thr = max(conf.min_drop_m, conf.k * profile_noise(prof))
    n_up = max(1, int(round(conf.upper_m / conf.bin_m)))
    n_low = max(1, int(round(conf.lower_m / conf.bin_m)))
    n_gap = int(round(conf.max_gap_m / conf.bin_m))
    start = int(np.ceil(start_m / conf.bin_m))
    kerb_b = np.full((n_seg, 2), np.iinfo(np.int64).max)
    for g in range(n_seg):
        for side in range(2):
            b = first_drop(prof[g, side], start, n_up, n_low, thr, conf.upper, n_gap)
            if b >= 0:
                kerb_b[g, side] = b
    seg = np.clip((s / conf.along_m).astype(np.int64), 0, n_seg - 1)
    side = (d < 0).astype(np.int64)
    beyond = (np.abs(d) / conf.bin_m).astype(np.int64) >= kerb_b[seg, side]
    return beyond.reshape(H, W)
