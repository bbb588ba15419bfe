"""Grid planning on a scene's walkable map: A* paths, free-point sampling, geodesic lengths.

Grid convention (`vid2sim.formats.walkable`, the bundle's `walkable.npz`): `grid[row, col]`
uint8, 1 = walkable; cell [0, 0] has its lower-left corner at world `origin` (x, y); columns run
along +x, rows along +y; `resolution` metres per cell. Points outside the grid are not walkable.

The search is 8-connected with metric step costs (resolution, resolution x sqrt 2); a diagonal
step is allowed only when both side cells are free (no corner cutting). Clearance inflation
removes cells closer than `clearance` metres to a blocked cell or to the grid border.

A planner with a `comfort` distance (> clearance) also plans comfortable routes
(`plan(..., comfortable=True)`): a step into a free cell closer than `comfort` to anything blocked
costs up to 1 + COMFORT_WEIGHT times its length (linearly from `comfort` down to `clearance`), and
the line-of-sight pruning keeps to cells at least `comfort` away or on the searched cell path, so
the route runs down the middle of a sidewalk narrower than 2 x comfort instead of grazing the
clearance boundary, and still squeezes through a gap when there is no other way.
"""

from __future__ import annotations

import heapq
import math
from typing import Optional

import numba
import numpy as np
from scipy import ndimage

from vid2sim.formats.walkable import WalkableGrid

SQRT2 = math.sqrt(2.0)
COMFORT_WEIGHT = 3.0  # extra step-cost factor of a free cell right at the clearance boundary
NO_WEIGHT = np.zeros((0, 0))  # `_search`'s weight for plain step costs (nothing allocated per search)


class GridPlanner:
    """A* over a walkable grid, in metres.

    `plan(start_xy, goal_xy)` returns metric waypoints [K, 2] (start and goal included) or None
    when no path exists. Start and goal are snapped to the nearest free cell within `snap`
    metres; farther away (or off the grid) there is no path. With `smooth` (default) the cell
    path is pruned by line of sight on the free cells (any-angle, closer to the true geodesic)
    and resampled every 0.25 m.
    """

    def __init__(self, grid: WalkableGrid, clearance: float = 0.0, snap: float = 0.5,
                 smooth: bool = True, comfort: float = 0.0) -> None:
        self.raw = np.asarray(grid.grid, np.uint8)  # [H, W]
        self.origin = np.asarray(grid.origin, np.float64).reshape(2)
        self.resolution = float(grid.resolution)
        self.clearance = float(clearance)
        self.comfort = max(float(comfort), self.clearance)
        room = _room(self.raw > 0)  # [H, W] cells to the nearest blocked cell centre
        self.free = room > self.clearance / self.resolution  # [H, W] bool (`inflate`)
        self._weight, self._roomy = self._comfort_layers(room * self.resolution)  # [H, W] float, bool
        self.snap = float(snap)
        self.smooth = smooth
        # nearest free cell for every cell (for snapping)
        if self.free.any():
            _, idx = ndimage.distance_transform_edt(~self.free, return_indices=True)
            self._nearest = idx  # [2, H, W]
        else:
            self._nearest = None

    def _comfort_layers(self, room: np.ndarray) -> tuple[Optional[np.ndarray], Optional[np.ndarray]]:
        """Step-cost factor of every cell [H, W] and the cells more than `comfort` from anything
        blocked [H, W], from each cell's room in metres [H, W]; (None, None) without a comfort distance."""
        if self.comfort <= self.clearance:
            return None, None
        tight = np.clip((self.comfort - room) / (self.comfort - self.clearance), 0.0, 1.0)
        return 1.0 + COMFORT_WEIGHT * tight, room > self.comfort

    @property
    def shape(self) -> tuple[int, int]:
        return self.free.shape  # type: ignore[return-value]

    # --- coordinates -------------------------------------------------------------------------
    def to_cell(self, x: float, y: float) -> tuple[int, int]:
        """(row, col) of a world point (may lie outside the grid)."""
        c = math.floor((x - self.origin[0]) / self.resolution)
        r = math.floor((y - self.origin[1]) / self.resolution)
        return r, c

    def to_world(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Cell centres -> world points [N, 2]."""
        x = self.origin[0] + (np.asarray(cols, np.float64) + 0.5) * self.resolution
        y = self.origin[1] + (np.asarray(rows, np.float64) + 0.5) * self.resolution
        return np.stack([x, y], axis=-1)

    def inside(self, r: int, c: int) -> bool:
        H, W = self.free.shape
        return 0 <= r < H and 0 <= c < W

    # --- queries -----------------------------------------------------------------------------
    def is_walkable(self, x: float, y: float) -> bool:
        """True when (x, y) lies on a walkable cell of the raw (uninflated) map."""
        r, c = self.to_cell(x, y)
        return self.inside(r, c) and bool(self.raw[r, c])

    def is_free(self, x: float, y: float) -> bool:
        """True when (x, y) lies on a cell free after clearance inflation."""
        r, c = self.to_cell(x, y)
        return self.inside(r, c) and bool(self.free[r, c])

    def free_cells(self) -> tuple[np.ndarray, np.ndarray]:
        """(rows [F], cols [F]) of the free cells, row-major (`np.nonzero(free)`; kept: the map
        does not change)."""
        if getattr(self, "_free_cells", None) is None:
            self._free_cells = np.nonzero(self.free)
        return self._free_cells

    def sample_free(self, rng: np.random.Generator) -> tuple[float, float]:
        """A uniformly random point inside a random free cell."""
        rows, cols = self.free_cells()
        if len(rows) == 0:
            raise ValueError("walkable grid has no free cell (after clearance inflation)")
        i = int(rng.integers(len(rows)))
        jitter = rng.uniform(-0.4, 0.4, size=2) * self.resolution
        p = self.to_world(rows[i], cols[i]) + jitter
        return float(p[0]), float(p[1])

    def snap_cell(self, x: float, y: float) -> Optional[tuple[int, int]]:
        """Nearest free cell to (x, y) within `snap` metres, or None."""
        r, c = self.to_cell(x, y)
        if self._nearest is None or not self.inside(r, c):
            return None
        rr, cc = int(self._nearest[0, r, c]), int(self._nearest[1, r, c])
        if math.hypot(rr - r, cc - c) * self.resolution > self.snap + 1e-9:
            return None
        return rr, cc

    def plan(self, start_xy: tuple[float, float], goal_xy: tuple[float, float],
             comfortable: bool = False) -> Optional[np.ndarray]:
        """A* path as world waypoints [K, 2] (exact start first, exact goal last) or None; the
        comfortable route (see the module docs) when asked and the planner has a comfort distance."""
        s = self.snap_cell(*start_xy)
        g = self.snap_cell(*goal_xy)
        if s is None or g is None:
            return None
        comfortable = comfortable and self._weight is not None
        cells = astar(self.free, s, g, self._weight if comfortable else None)
        if cells is None:
            return None
        pts = self.to_world(cells[:, 0], cells[:, 1])  # [K, 2]
        pts[0] = start_xy
        pts[-1] = goal_xy
        if not self.smooth:
            return pts
        if not comfortable:
            return self.shortcut(pts)
        lane = self._roomy.copy()  # [H, W] bool: roomy cells and the searched path itself
        lane[cells[:, 0], cells[:, 1]] = True
        return self.shortcut(pts, lane)

    def line_free(self, a: np.ndarray, b: np.ndarray) -> bool:
        """True when the segment a-b stays on free cells (sampled every resolution / 4)."""
        return _segment_free(self.free, self.origin[0], self.origin[1], self.resolution,
                             float(a[0]), float(a[1]), float(b[0]), float(b[1]))

    def shortcut(self, pts: np.ndarray, free: Optional[np.ndarray] = None) -> np.ndarray:
        """Greedy (forward) line-of-sight pruning of waypoints [K, 2] -> [K', 2] over `free` cells
        (default: the planner's), densified every 0.25 m (`_shortcut_keep`, one numba call;
        `shortcut_reference` is the plain loop)."""
        pts = np.ascontiguousarray(pts, np.float64)
        free = self.free if free is None else free
        keep = _shortcut_keep(free, self.origin[0], self.origin[1], self.resolution, pts)
        return densify(pts[keep], 0.25)

    def shortcut_reference(self, pts: np.ndarray) -> np.ndarray:
        """`shortcut` as a Python loop over `line_free` (the reference it is tested against)."""
        keep = [0]
        i, j = 0, 1
        while j < len(pts) - 1:  # extend the segment from pts[i] while it stays free
            if not self.line_free(pts[i], pts[j + 1]):
                keep.append(j)
                i = j
            j += 1
        keep.append(len(pts) - 1)
        return densify(pts[keep], 0.25)

    def distance_field(self, start_xy: tuple[float, float]) -> np.ndarray:
        """Geodesic distance in metres from start to every cell [H, W] (+inf unreachable)."""
        s = self.snap_cell(*start_xy)
        dist = np.full(self.free.shape, np.inf)
        if s is None:
            return dist
        return dijkstra(self.free, s) * self.resolution


def inflate(free: np.ndarray, radius_cells: float) -> np.ndarray:
    """Free cells at least `radius_cells` from any blocked cell or the border ([H, W] bool)."""
    if radius_cells <= 0:
        return free.copy()
    return _room(free) > radius_cells


def _room(free: np.ndarray) -> np.ndarray:
    """Distance in cells from every cell to the nearest blocked cell centre or the grid border
    [H, W] (0 on blocked cells)."""
    padded = np.pad(free, 1, constant_values=False)
    return ndimage.distance_transform_edt(padded)[1:-1, 1:-1]


def path_length(points: np.ndarray) -> float:
    """Polyline length in metres of points [K, 2]."""
    pts = np.asarray(points, np.float64)
    if len(pts) < 2:
        return 0.0
    return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())


@numba.njit(cache=True)
def _segment_free(free: np.ndarray, ox: float, oy: float, res: float, ax: float, ay: float,
                  bx: float, by: float) -> bool:
    H, W = free.shape
    n = max(2, int(math.ceil(math.hypot(bx - ax, by - ay) / (0.25 * res))) + 1)
    for k in range(n):
        t = k / (n - 1)
        c = int(math.floor((ax + t * (bx - ax) - ox) / res))
        r = int(math.floor((ay + t * (by - ay) - oy) / res))
        if r < 0 or r >= H or c < 0 or c >= W or not free[r, c]:
            return False
    return True


@numba.njit(cache=True)
def _shortcut_keep(free: np.ndarray, ox: float, oy: float, res: float, pts: np.ndarray) -> np.ndarray:
    """Indices [K'] of the waypoints pts [K, 2] the greedy line-of-sight pruning keeps."""
    K = pts.shape[0]
    keep = np.empty(K + 1, np.int64)
    keep[0] = 0
    n, i, j = 1, 0, 1
    while j < K - 1:  # extend the segment from pts[i] while it stays free
        if not _segment_free(free, ox, oy, res, pts[i, 0], pts[i, 1], pts[j + 1, 0], pts[j + 1, 1]):
            keep[n] = j
            n += 1
            i = j
        j += 1
    keep[n] = K - 1
    return keep[:n + 1]


def densify(pts: np.ndarray, step: float) -> np.ndarray:
    """Insert points so consecutive waypoints [K, 2] are at most `step` apart."""
    out = [pts[:1]]
    for a, b in zip(pts[:-1], pts[1:]):
        n = max(1, int(math.ceil(np.linalg.norm(b - a) / step)))
        out.append(a + np.linspace(0.0, 1.0, n + 1)[1:, None] * (b - a))
    return np.concatenate(out)


@numba.njit(cache=True)
def _search(free: np.ndarray, weight: np.ndarray, sr: int, sc: int, gr: int, gc: int
            ) -> tuple[np.ndarray, np.ndarray]:
    """Best-first search from (sr, sc): A* with the octile heuristic towards (gr, gc), stopping
    there, or a full Dijkstra when gr < 0. A step into a cell costs its length times the cell's
    weight [H, W] (>= 1, so the heuristic stays admissible; an empty weight: 1 everywhere).
    Returns (cost in cells [H, W], parent flat index [H, W], -1 = none)."""
    H, W = free.shape
    weighted = weight.size > 0
    dist = np.full((H, W), np.inf)
    parent = np.full((H, W), -1, np.int64)
    closed = np.zeros((H, W), np.bool_)
    dr8 = np.array([0, 0, 1, -1, 1, 1, -1, -1])
    dc8 = np.array([1, -1, 0, 0, 1, -1, 1, -1])
    cost8 = np.array([1.0, 1.0, 1.0, 1.0, SQRT2, SQRT2, SQRT2, SQRT2])
    dist[sr, sc] = 0.0
    heap = [(0.0, sr * W + sc)]
    while len(heap) > 0:
        _, cur = heapq.heappop(heap)
        r, c = cur // W, cur % W
        if closed[r, c]:
            continue
        closed[r, c] = True
        if r == gr and c == gc:
            break
        for k in range(8):
            rr, cc = r + dr8[k], c + dc8[k]
            if rr < 0 or rr >= H or cc < 0 or cc >= W or not free[rr, cc] or closed[rr, cc]:
                continue
            if k >= 4 and not (free[rr, c] and free[r, cc]):
                continue  # no corner cutting
            nd = dist[r, c] + (cost8[k] * weight[rr, cc] if weighted else cost8[k])
            if nd < dist[rr, cc]:
                dist[rr, cc] = nd
                parent[rr, cc] = cur
                f = nd
                if gr >= 0:
                    a, b = abs(rr - gr), abs(cc - gc)
                    f += (SQRT2 - 1.0) * min(a, b) + max(a, b)
                heapq.heappush(heap, (f, rr * W + cc))
    return dist, parent


def astar(free: np.ndarray, start: tuple[int, int], goal: tuple[int, int],
          weight: Optional[np.ndarray] = None) -> Optional[np.ndarray]:
    """A* on an 8-connected bool grid; cells [K, 2] (row, col) from start to goal, or None.
    weight: per-cell step-cost factor [H, W] >= 1 (None: 1 everywhere, the shortest path)."""
    if not (free[start] and free[goal]):
        return None
    w = NO_WEIGHT if weight is None else np.asarray(weight, np.float64)
    dist, parent = _search(free, w, start[0], start[1], goal[0], goal[1])
    if not np.isfinite(dist[goal]):
        return None
    W = free.shape[1]
    cells = [goal[0] * W + goal[1]]
    target = start[0] * W + start[1]
    while cells[-1] != target:
        cells.append(int(parent.flat[cells[-1]]))
    flat = np.array(cells[::-1], np.int64)
    return np.stack([flat // W, flat % W], axis=1)  # [K, 2]


def dijkstra(free: np.ndarray, start: tuple[int, int]) -> np.ndarray:
    """Geodesic distance in cells from start over an 8-connected bool grid [H, W] (+inf unreachable)."""
    if not free[start]:
        return np.full(free.shape, np.inf)
    return _search(free, NO_WEIGHT, start[0], start[1], -1, -1)[0]
