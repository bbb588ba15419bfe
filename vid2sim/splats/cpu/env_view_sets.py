"""View sets: each frame draws only the splats that views near it were measured to need.

A potentially-visible-set scheme (a game engine's view cells), measured rather than derived
from geometry: `env_simready.sim_ready_views` records, for each of the sim-ready measurement
views, the splats that carry `view_keep_mass` of that view's blend weight. A frame whose camera
sits at centre c looking along f draws the union of the sets of the measured views within
`radius` m of c whose optical axis is within `heading_deg` of f; with fewer than MIN_VIEWS
such views it draws every splat. On the GoPro factory scene (48k sim-ready splats, 1024
views, the expert's poses) a frame then draws about two thirds of the ~27k splats in its
frustum: render CPU 2.72 -> 1.73 ms per step at -0.5 dB (docs/results.md, Environments).

A mask holds one uint64 per culling cell (cells of at most 64 rows; bit j keeps row
cell_start[c] + j): the layout `env_fast_frame.cull_project` reads. The sets are kept in model
order (`ViewSets.sets`, packed bits) and turned into cell masks for a given StaticScene, so a
change of the scene's cell order never invalidates a stored set.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import numpy as np
from numba import njit

from ..camera import Camera
from .env_scene import StaticScene

MIN_VIEWS = 3  # fewer measured views near a camera than this: the frame draws every splat
MAX_CELL_ROWS = 64  # rows a culling cell may hold for its mask to fit one uint64


@dataclass
class ViewSets:
    """The measured views (centres [V, 3], unit optical axes forwards [V, 3]) and the splats
    each needs (sets [V, ceil(N / 8)] uint8: np.packbits of a bool [V, N] in model order)."""

    centres: np.ndarray  # [V, 3] float64
    forwards: np.ndarray  # [V, 3] float64
    sets: np.ndarray  # [V, ceil(N / 8)] uint8
    num: int  # N, splats of the model the sets index

    @classmethod
    def from_cameras(cls, cameras: Sequence[Camera], sets: np.ndarray, num: int) -> "ViewSets":
        """From the measurement cameras and, per camera, the splats it needs (sets
        [V, ceil(num / 8)] uint8 packed bits, as `env_simready.sim_ready_views` gives them)."""
        sets = np.asarray(sets, np.uint8)
        if sets.shape != (len(cameras), (num + 7) // 8):
            raise ValueError(f"ViewSets: sets of shape {sets.shape} for {len(cameras)} cameras "
                             f"and {num} splats")
        poses = [camera_pose(np.asarray(c.world_to_cam, np.float64)) for c in cameras]
        centres = np.array([p[0] for p in poses]).reshape(-1, 3)
        forwards = np.array([p[1] for p in poses]).reshape(-1, 3)
        return cls(centres, forwards, sets, num)

    def save(self, path: Path) -> Path:
        path = Path(path)
        with open(path, "wb") as f:  # a file object: np.savez would append ".npz" to the name
            np.savez_compressed(f, centres=self.centres, forwards=self.forwards, sets=self.sets,
                                num=self.num)
        return path

    @classmethod
    def load(cls, path: Path) -> "ViewSets":
        with np.load(path) as z:
            return cls(z["centres"], z["forwards"], z["sets"], int(z["num"]))


def camera_pose(world_to_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centre [3], unit optical axis [3]) in world coordinates of a world-to-camera [4, 4]
    (OpenCV axes: the camera looks along its +z)."""
    R, t = world_to_cam[:3, :3], world_to_cam[:3, 3]
    return -R.T @ t, R[2] / np.linalg.norm(R[2])


class CellMasks:
    """A ViewSets turned into per-view cell masks [V, C] uint64 of one StaticScene; `mask`
    unites the views within `radius` m of a camera looking within `heading_deg` of it."""

    def __init__(self, views: ViewSets, scene: StaticScene, radius: float, heading_deg: float
                 ) -> None:
        if scene.num != views.num:
            raise ValueError(f"ViewSets: measured on {views.num} splats, the scene has {scene.num}")
        starts = np.asarray(scene.cell_start, np.int64)  # [C+1]
        if len(starts) > 1 and int(np.diff(starts).max()) > MAX_CELL_ROWS:
            raise ValueError(f"ViewSets: culling cells of up to {MAX_CELL_ROWS} splats needed, "
                             f"the scene has {int(np.diff(starts).max())}")
        row_of = np.full(scene.num, -1, np.int64)  # model index -> cached row (-1: not loaded)
        row_of[scene.index] = np.arange(len(scene.index))
        self.masks = np.zeros((len(views.sets), max(len(starts) - 1, 0)), np.uint64)  # [V, C]
        for v, bits in enumerate(views.sets):  # one view at a time: [V, N] bools may not fit
            rows = row_of[np.nonzero(np.unpackbits(bits, count=views.num))[0]]
            rows = rows[rows >= 0]
            cell = np.searchsorted(starts, rows, side="right") - 1
            bits = np.left_shift(np.uint64(1), (rows - starts[cell]).astype(np.uint64))
            np.bitwise_or.at(self.masks[v], cell, bits)
        self.centres, self.forwards = views.centres, views.forwards
        self.radius2 = float(radius) ** 2
        self.cos_heading = math.cos(math.radians(heading_deg))

    def near(self, world_to_cam: np.ndarray) -> np.ndarray:
        """Indices of the measured views near a camera (world-to-camera [4, 4]): centre within
        `radius` m, optical axis within `heading_deg`."""
        c, f = camera_pose(np.asarray(world_to_cam, np.float64))
        return near_views(self.centres, self.forwards, c, f, self.radius2, self.cos_heading)

    def mask(self, world_to_cam: np.ndarray) -> Optional[np.ndarray]:
        """The cell mask [C] uint64 a frame at this camera draws: the union of the `near` views'
        sets; None (draw every splat) when fewer than MIN_VIEWS are near."""
        near = self.near(world_to_cam)
        return unite(self.masks, near) if len(near) >= MIN_VIEWS else None


@njit(cache=True)
def near_views(centres, forwards, c, f, radius2, cos_heading):
    """Indices of the views whose centre [V, 3] is within sqrt(radius2) of c [3] and whose axis
    [V, 3] has a cosine >= cos_heading with f [3]."""
    out = np.empty(centres.shape[0], np.int64)
    n = 0
    for v in range(centres.shape[0]):
        dx, dy, dz = centres[v, 0] - c[0], centres[v, 1] - c[1], centres[v, 2] - c[2]
        if dx * dx + dy * dy + dz * dz > radius2:
            continue
        if forwards[v, 0] * f[0] + forwards[v, 1] * f[1] + forwards[v, 2] * f[2] < cos_heading:
            continue
        out[n] = v
        n += 1
    return out[:n]


@njit(cache=True)
def unite(masks, views):
    """The bitwise union [C] of the rows `views` of masks [V, C]."""
    out = np.zeros(masks.shape[1], np.uint64)
    for v in views:
        for k in range(out.shape[0]):
            out[k] |= masks[v, k]
    return out
