"""cameras.parquet: one row per frame, shared by the factory's PosedClip and the scene bundle.

Columns: index int32, image string (file name), timestamp float64 (s), width/height int32,
fx fy cx cy float64 (pixels, pinhole), cam_to_world list<float64>[16] (row-major 4x4, OpenCV
axes: x right, y down, z forward), split string ("train" | "test").
The reader checks the footer before reading: more than MAX_CAMERA_ROWS rows, or more than
MAX_CAMERA_BYTES of uncompressed data, is `BundleTooLarge`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from vid2sim.formats.errors import BundleError, BundleTooLarge

CAMERAS_PARQUET = "cameras.parquet"
MAX_CAMERA_ROWS = 1_000_000  # frames per scene (a 15 s clip at 10 fps has 150)
MAX_CAMERA_BYTES = 1 << 30  # uncompressed bytes the footer declares (a row takes about 250)
CAMERA_COLUMNS = ("index", "image", "timestamp", "width", "height", "fx", "fy", "cx", "cy",
                  "cam_to_world", "split")


def cameras_schema() -> pa.Schema:
    """The cameras table schema shared by PosedClip and the scene bundle's cameras.parquet."""
    return pa.schema([
        ("index", pa.int32()), ("image", pa.string()), ("timestamp", pa.float64()),
        ("width", pa.int32()), ("height", pa.int32()),
        ("fx", pa.float64()), ("fy", pa.float64()), ("cx", pa.float64()), ("cy", pa.float64()),
        ("cam_to_world", pa.list_(pa.float64(), 16)), ("split", pa.string()),
    ])


def check_declared_size(path: Path) -> None:
    """BundleTooLarge when the parquet footer declares more rows or uncompressed bytes than the caps."""
    try:
        meta = pq.ParquetFile(path).metadata
    except Exception as e:
        raise BundleError(path, f"unreadable parquet ({type(e).__name__}: {e})") from None
    size = sum(meta.row_group(i).total_byte_size for i in range(meta.num_row_groups))
    if meta.num_rows > MAX_CAMERA_ROWS:
        raise BundleTooLarge(path, f"declares {meta.num_rows:,} rows, over the cap of {MAX_CAMERA_ROWS:,}")
    if size > MAX_CAMERA_BYTES:
        raise BundleTooLarge(path, f"declares {size:,} uncompressed bytes, over the cap of {MAX_CAMERA_BYTES:,}")


def load_cameras(path: Path) -> pa.Table:
    """cameras.parquet -> pyarrow.Table with exactly `cameras_schema()` columns and types."""
    if not Path(path).is_file():
        raise BundleError(path, "missing cameras table")
    check_declared_size(path)
    try:
        table = pq.read_table(path)
    except Exception as e:
        raise BundleError(path, f"unreadable parquet ({type(e).__name__}: {e})") from None
    want = cameras_schema()
    got = {f.name: f.type for f in table.schema}
    missing = [f.name for f in want if f.name not in got]
    wrong = [f"{f.name} is {got[f.name]}, expected {f.type}" for f in want if f.name in got and got[f.name] != f.type]
    extra = sorted(set(got) - set(want.names))
    if missing or wrong or extra:
        parts = (([f"missing columns {missing}"] if missing else []) + wrong
                 + ([f"unknown columns {extra}"] if extra else []))
        raise BundleError(path, "wrong cameras schema: " + "; ".join(parts))
    table = table.select(want.names)
    splits = set(table.column("split").to_pylist())
    if not splits <= {"train", "test"}:
        raise BundleError(path, f"split values must be 'train' or 'test', got {sorted(map(str, splits))}")
    if table.num_rows == 0:
        raise BundleError(path, "cameras table has no rows")
    _check_camera_values(path, table)
    return table


def _check_camera_values(path: Path, table: pa.Table) -> None:
    """Finite intrinsics, poses and timestamps; positive sizes and focal lengths."""
    for c in ("timestamp", "fx", "fy", "cx", "cy"):
        v = table.column(c).to_numpy(zero_copy_only=False).astype(np.float64)
        if not np.isfinite(v).all():
            raise BundleError(path, f"non-finite '{c}' in {int(np.count_nonzero(~np.isfinite(v)))} row(s)")
    poses = np.asarray(table.column("cam_to_world").combine_chunks().flatten().to_numpy(zero_copy_only=False),
                       np.float64)
    if not np.isfinite(poses).all():
        raise BundleError(path, "non-finite values in cam_to_world poses")
    for c in ("width", "height", "fx", "fy"):
        v = table.column(c).to_numpy(zero_copy_only=False)
        if (v <= 0).any():
            raise BundleError(path, f"'{c}' must be > 0, got {v[v <= 0][0]!r}")
