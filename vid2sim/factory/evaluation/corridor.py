"""Ground-truth-free corridor check: does the physical layer let a body pass where the video's
camera walked?

The walked corridor is the camera path dropped to the ground and swept by a body: a vertical
cylinder of radius `body_radius_m` from `body_bottom_m` above the ground to `head_gap_m` below
the camera. Three figures, none needing ground truth:
  walkable_fraction   fraction of the walked path (sampled every `step_m`) on walkable cells
  path_components     number of 4-connected walkable components the walked path touches
  corridor_area_m2    collision-mesh surface area inside the corridor (phantom obstacles)
`gate_reasons` turns them into named quality-gate failures. Why each walked sample off the map is
off it (from the map's evidence, also ground-truth free) is `geometry.map_evidence.path_miss_causes`,
which the walkable stage stores in its report.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Optional

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from vid2sim.factory.evaluation.geometry_metrics import sample_surface
from vid2sim.factory.geometry.raycast import MeshLike, mesh_arrays
from vid2sim.factory.geometry.walked_path import (  # noqa: F401  (CorridorError re-exported)
    BODY_RADIUS_M, CorridorError, walked_path)
from vid2sim.formats.walkable import WalkableGrid
from vid2sim.ranges import checked


@checked
@dataclass(frozen=True)
class CorridorConfig:
    body_radius_m: float = BODY_RADIUS_M  # m, radius of the walker's body swept along the camera path
    body_bottom_m: float = 0.2  # above the local ground: kerbs and ground noise stay below
    head_gap_m: float = 0.1  # the body stops this far below the camera
    ground_z_m: float = 0.0  # metric frame: ground plane at z = 0
    step_m: float = 0.05  # walked-path sampling
    area_spacing_m: float = 0.02  # surface sampling for the area inside the corridor
    # quality gate (a scene failing these is not registered as fine); looser than the
    # quality targets (>= 99 % walkable, 1 component, < 0.05 m^2) so that a usable but
    # imperfect scene is still kept, with its figures in the metrics. Measured
    # (docs/studies/physical_layer.md):
    # GoPro 47.8 % / 3 / 2.11 m^2 before, 94.8 % / 1 / 0.02 after; demo street 78.8 % before,
    # 89.2 % / 1 / 0.0 after; with the physical layer (trimmed mesh, exact inflation) GoPro
    # 83.3 % / 1 / 0.044, demo 93.5 % / 1 / 0.0
    gate_min_walkable_fraction: float = 0.8  # less of the walked path on walkable cells fails (corridor_not_walkable)
    gate_max_components: int = 1  # more walkable components along the walked path fail (corridor_split)
    gate_max_area_m2: float = 0.5  # m^2, more collision surface inside the corridor fails (corridor_obstructed)


@dataclass
class CorridorReport:
    walkable_fraction: float
    path_components: int
    corridor_area_m2: float
    path_length_m: float
    n_samples: int

    def to_dict(self) -> dict:
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in asdict(self).items()}


def corridor_points_mask(points: np.ndarray, walked: np.ndarray, conf: CorridorConfig,
                         ground_z: float | np.ndarray | None = None) -> np.ndarray:
    """Points [P, 3] inside the swept body [P] bool. walked [S, 3] is the resampled camera
    path (spacing << body radius); ground_z: scalar or [S] local ground under each sample."""
    if len(points) == 0:
        return np.zeros(0, bool)
    gz = np.broadcast_to(conf.ground_z_m if ground_z is None else ground_z, (len(walked),))
    tree = cKDTree(walked[:, :2])
    inside = np.zeros(len(points), bool)
    for i, near in enumerate(tree.query_ball_point(points[:, :2], conf.body_radius_m)):
        if near:
            z = points[i, 2]
            lo = gz[near] + conf.body_bottom_m
            hi = walked[near, 2] - conf.head_gap_m
            inside[i] = bool(np.any((z >= lo) & (z <= hi)))
    return inside


def corridor_area(mesh: Optional[MeshLike], walked: np.ndarray, conf: CorridorConfig,
                  ground_z: float | np.ndarray | None = None) -> float:
    """Collision-surface area (m^2) inside the swept body, by uniform surface sampling of
    the faces near the path (about one sample per area_spacing_m^2)."""
    if mesh is None:
        return 0.0
    v, f = mesh_arrays(mesh)
    if len(f) == 0:
        return 0.0
    tri = v[f]  # [F, 3, 3]
    reach = np.linalg.norm(tri - tri.mean(axis=1, keepdims=True), axis=2).max(axis=1)  # [F]
    d = cKDTree(walked[:, :2]).query(tri.mean(axis=1)[:, :2])[0]  # [F]
    near = d <= conf.body_radius_m + reach
    if not near.any():
        return 0.0
    tri = tri[near]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    total = float(area.sum())
    if total <= 0:
        return 0.0
    n = max(1000, int(np.ceil(total / conf.area_spacing_m ** 2)))
    sub_v = tri.reshape(-1, 3)
    sub_f = np.arange(len(sub_v)).reshape(-1, 3)
    pts = sample_surface(sub_v, sub_f, n)  # [n, 3]
    return total * float(corridor_points_mask(pts, walked, conf, ground_z).mean())


def path_on_walkable(wm: WalkableGrid, walked: np.ndarray) -> tuple[float, int]:
    """(fraction of walked samples [S, 3] on walkable cells, walkable components touched)."""
    on = wm.lookup(walked[:, 0], walked[:, 1])  # [S]
    labels, _ = ndimage.label(wm.grid > 0)
    r, c = wm.world_to_cell(walked[on, 0], walked[on, 1])
    comps = np.unique(labels[r, c]) if on.any() else np.zeros(0, int)
    return float(on.mean()), int(np.count_nonzero(comps))


def corridor_check(wm: WalkableGrid, collision: Optional[MeshLike], camera_path: np.ndarray,
                   conf: CorridorConfig = CorridorConfig()) -> CorridorReport:
    """The three corridor figures for one scene (see module docstring)."""
    walked = walked_path(camera_path, conf.step_m)
    frac, comps = path_on_walkable(wm, walked)
    seg = np.linalg.norm(np.diff(walked[:, :2], axis=0), axis=1)
    return CorridorReport(frac, comps, corridor_area(collision, walked, conf),
                          float(seg.sum()), len(walked))


def gate_reasons(report: CorridorReport, conf: CorridorConfig) -> list[str]:
    """Named quality-gate failures (empty list = pass)."""
    reasons = []
    if report.walkable_fraction < conf.gate_min_walkable_fraction:
        reasons.append("corridor_not_walkable")
    if report.path_components > conf.gate_max_components:
        reasons.append("corridor_split")
    if report.corridor_area_m2 > conf.gate_max_area_m2:
        reasons.append("corridor_obstructed")
    return reasons
