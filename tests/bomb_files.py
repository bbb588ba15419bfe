"""Small files that declare huge contents: a walkable.npz whose grid inflates to gigabytes."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np


def write_walkable_bomb(path: Path, rows: int, cols: int, chunk: int = 1 << 24) -> Path:
    """A real walkable.npz: a zero grid of rows x cols cells (deflated, so a few hundred KB per GB)."""
    header = {"descr": "|u1", "fortran_order": False, "shape": (rows, cols)}
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as zf:
        with zf.open("grid.npy", "w", force_zip64=True) as f:
            np.lib.format.write_array_header_1_0(f, header)
            zeros, left = bytes(chunk), rows * cols
            while left:
                f.write(zeros[:min(chunk, left)])
                left -= min(chunk, left)
        for key, value in (("origin", np.zeros(2)), ("resolution", np.float64(0.1))):
            with zf.open(f"{key}.npy", "w") as f:
                np.lib.format.write_array(f, np.asarray(value))
    return path
