"""Why a walkable map is (not) walkable where it is: the map's evidence and the walked path's misses.

`MapEvidence` is written by the walkable stage next to the map; `path_miss_causes` reads it to say,
for every walked-path sample off the map, which evidence put it off (ground-truth free). The
corridor check (`factory.evaluation.corridor`) and the GT ceiling (`evaluation.walkable_ceiling`)
report these causes; they live here, in the geometry layer, because the walkable stage itself
stores them in `walkable.json`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from vid2sim.factory.geometry.walked_path import walked_path
from vid2sim.formats.walkable import WalkableGrid


@dataclass
class MapEvidence:
    """Why each cell of a walkable map is (not) walkable, on the map's grid [H, W]."""

    seen: np.ndarray  # [H, W] bool ground (seen, walked or grown)
    blocked_obstacle: np.ndarray  # [H, W] bool centre within the robot radius of a sample
    blocked_kerb: np.ndarray  # [H, W] bool within the robot radius of a kerb / step cell
    obstacle_xy: np.ndarray  # [P, 2] the collision-surface samples that block


MISS_CAUSES = ("off_grid", "unseen", "obstacle_within_radius", "obstacle_cell", "kerb", "component")


def path_miss_causes(wm: WalkableGrid, evidence: MapEvidence, camera_path: np.ndarray,
                     robot_radius_m: float, step_m: float = 0.05) -> dict:
    """Why walked samples (every step_m of camera_path [T, 3]) are not on walkable cells, as
    fractions of all samples, the first cause that holds per sample:
      off_grid                the sample lies outside the map
      unseen                  its cell is not ground (never seen, walked or grown over)
      obstacle_within_radius  collision surface lies within the robot radius of the sample
                              itself: the reconstructed geometry blocks a robot there
      obstacle_cell           the sample clears every surface sample by more than the radius,
                              but its cell's centre does not (map discretisation)
      kerb                    its cell lies within the radius of ground beyond a kerb / step
      component               free, but not in the component the path is kept in
    plus `obstacle_clearance_min_m`, the smallest sample-to-surface distance on the path."""
    walked = walked_path(camera_path, step_m)  # [S, 3]
    on = wm.lookup(walked[:, 0], walked[:, 1])  # [S]
    H, W = wm.shape
    r, c = wm.world_to_cell(walked[:, 0], walked[:, 1])
    inside = (r >= 0) & (r < H) & (c >= 0) & (c < W)
    rr, cc = np.clip(r, 0, H - 1), np.clip(c, 0, W - 1)
    if len(evidence.obstacle_xy):
        clear = cKDTree(evidence.obstacle_xy).query(walked[:, :2])[0]  # [S]
    else:
        clear = np.full(len(walked), np.inf)
    tests = (~inside, ~evidence.seen[rr, cc], clear <= robot_radius_m,
             evidence.blocked_obstacle[rr, cc], evidence.blocked_kerb[rr, cc], np.ones(len(walked), bool))
    left = ~on
    out = {}
    for name, hit in zip(MISS_CAUSES, tests):
        out[name] = float(np.count_nonzero(left & hit)) / len(walked)
        left &= ~hit
    out["obstacle_clearance_min_m"] = float(clear.min())
    return out
