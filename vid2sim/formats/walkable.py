"""walkable.npz: the walkable grid every layer shares (factory writes it, registry checks it, envs plan on it).

File keys: grid uint8 [H, W] (1 = walkable, 0 = blocked), origin float64 [2], resolution float64
(metres per cell). Convention: grid[row, col], row along world +y, col along world +x; cell
(r, c) covers x in [ox + c res, ox + (c + 1) res), y in [oy + r res, oy + (r + 1) res), where
origin = (ox, oy) is the lower-left CORNER of cell [0, 0] (its centre is origin + res / 2).
`load_walkable(path) -> WalkableGrid` is the one reader; `WalkableGrid.save(path)` the writer.
The reader checks each array's declared shape before decompressing it: a grid of more than
MAX_WALKABLE_CELLS cells (8192 x 8192: 205 m square at the envs' 2.5 cm) is `BundleTooLarge`.
"""

from __future__ import annotations

import math
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vid2sim.formats.errors import BundleError, BundleTooLarge, PathLike

WALKABLE_NPZ = "walkable.npz"
NPZ_KEYS = ("grid", "origin", "resolution")
MAX_WALKABLE_CELLS = 8192 * 8192  # grid cells a walkable.npz may declare
MAX_SMALL_VALUES = 16  # elements `origin` / `resolution` may declare (they hold 2 and 1)


@dataclass
class WalkableGrid:
    """A metric walkable grid in the world frame (z up, ground z = 0)."""

    grid: np.ndarray  # [H, W] uint8, 1 = walkable
    origin: np.ndarray  # [2] world (x, y) of the lower-left corner of cell [0, 0]
    resolution: float  # metres per cell

    def __post_init__(self) -> None:
        self.grid = np.asarray(self.grid, np.uint8)
        self.origin = np.asarray(self.origin, np.float64).reshape(2)
        self.resolution = float(self.resolution)

    @property
    def shape(self) -> tuple[int, int]:
        return self.grid.shape  # type: ignore[return-value]

    def extent_max(self) -> np.ndarray:
        """World (x, y) of the upper-right corner of the grid."""
        return self.origin + np.array([self.grid.shape[1], self.grid.shape[0]]) * self.resolution

    def area_m2(self) -> float:
        return float(np.count_nonzero(self.grid)) * self.resolution ** 2

    def world_to_cell(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(row, col) integer indices (may lie outside the grid)."""
        c = np.floor((np.asarray(x) - self.origin[0]) / self.resolution).astype(np.int64)
        r = np.floor((np.asarray(y) - self.origin[1]) / self.resolution).astype(np.int64)
        return r, c

    def cell_center(self, row: np.ndarray, col: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (self.origin[0] + (np.asarray(col) + 0.5) * self.resolution,
                self.origin[1] + (np.asarray(row) + 0.5) * self.resolution)

    def lookup(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Walkable flag (bool, same shape as x) at world points; False outside the grid."""
        r, c = self.world_to_cell(x, y)
        H, W = self.grid.shape
        inside = (r >= 0) & (r < H) & (c >= 0) & (c < W)
        out = np.zeros(np.shape(r), bool)
        out[inside] = self.grid[r[inside], c[inside]] > 0
        return out

    def save(self, path: PathLike) -> Path:
        """Write walkable.npz (compressed) at `path`."""
        path = Path(path)
        with open(path, "wb") as f:
            np.savez_compressed(f, grid=self.grid, origin=self.origin,
                                resolution=np.float64(self.resolution))
        return path


def _declared_shape(zf: zipfile.ZipFile, member: str) -> tuple[int, ...]:
    """The shape an .npy member of an npz declares in its header (nothing decompressed beyond it)."""
    with zf.open(member) as f:
        major, _ = np.lib.format.read_magic(f)
        read = np.lib.format.read_array_header_1_0 if major == 1 else np.lib.format.read_array_header_2_0
        shape, _, _ = read(f)
    return tuple(int(n) for n in shape)


def check_declared_sizes(path: Path) -> None:
    """Raise BundleTooLarge when an array of the npz declares more elements than its cap."""
    try:
        with zipfile.ZipFile(path) as zf:
            names = set(zf.namelist())
            shapes = {k: _declared_shape(zf, f"{k}.npy") for k in NPZ_KEYS if f"{k}.npy" in names}
    except Exception as e:
        raise BundleError(path, f"unreadable npz ({type(e).__name__}: {e})") from None
    for key, shape in shapes.items():
        cap = MAX_WALKABLE_CELLS if key == "grid" else MAX_SMALL_VALUES
        count = math.prod(shape)
        if count > cap:
            raise BundleTooLarge(path, f"{key} declares {count:,} elements {list(shape)}, over the cap of {cap:,}")


def _read_npz(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    check_declared_sizes(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in NPZ_KEYS if k not in z.files]
            if missing:
                raise BundleError(path, f"walkable npz lacks key(s): {', '.join(missing)}")
            return z["grid"], z["origin"], z["resolution"]
    except BundleError:
        raise
    except Exception as e:
        raise BundleError(path, f"unreadable npz ({type(e).__name__}: {e})") from None


def load_walkable(path: PathLike) -> WalkableGrid:
    """Read and check walkable.npz -> WalkableGrid; raises BundleError naming the file and reason."""
    path = Path(path)
    if not path.is_file():
        raise BundleError(path, "missing walkable grid")
    grid, origin, res = _read_npz(path)
    if grid.ndim != 2 or grid.dtype != np.uint8 or grid.size == 0:
        raise BundleError(path, f"grid must be a non-empty uint8 [H, W] array, got {grid.dtype} {grid.shape}")
    if not np.isin(grid, (0, 1)).all():
        raise BundleError(path, "grid values must be 0 or 1")
    origin = np.asarray(origin, np.float64).reshape(-1)
    if origin.shape != (2,) or not np.isfinite(origin).all():
        raise BundleError(path, f"origin must be 2 finite numbers, got shape {origin.shape}")
    if np.asarray(res).size != 1 or not float(res) > 0 or not math.isfinite(float(res)):
        raise BundleError(path, f"resolution must be one positive number, got {res!r}")
    return WalkableGrid(grid, origin, float(res))
