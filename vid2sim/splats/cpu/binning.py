"""Binning: depth-sort the splats that reach a pixel and build per-tile lists.

Reads per-row depths fo[:, F_Z] and pixel boxes box [R, 4] (j0, i0, j1, i1 inclusive;
empty when j1 < j0); writes tile_offsets [T+1] and the instance list inst [M] (row index),
each tile's slice sorted by depth, ties by row index. The radix sort carries each row's
packed tile rectangle so binning reads sequentially (no random access into `box`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .preprocess import F_Z

U16 = np.uint64(0xFFFF)


@njit(cache=True)
def _float_key(b):
    """Order-preserving uint32 key of float32 bits b."""
    return b ^ np.uint32(0xFFFFFFFF) if b >> np.uint32(31) else b ^ np.uint32(0x80000000)


@njit(cache=True)
def radix_sort(keys, rows, rects):
    """Stable ascending sort of uint32 keys [n], carrying int32 rows [n] and uint64 rects [n]:
    LSD radix, three 11-bit passes. Returns (rows, rects) sorted."""
    n = keys.shape[0]
    k2 = np.empty(n, np.uint32)
    r2 = np.empty(n, np.int32)
    q2 = np.empty(n, np.uint64)
    count = np.empty(2049, np.int64)
    for shift in (0, 11, 22):
        sh = np.uint32(shift)
        count[:] = 0
        for i in range(n):
            count[((keys[i] >> sh) & np.uint32(2047)) + 1] += 1
        for d in range(2048):
            count[d + 1] += count[d]
        for i in range(n):
            d = (keys[i] >> sh) & np.uint32(2047)
            j = count[d]
            k2[j] = keys[i]
            r2[j] = rows[i]
            q2[j] = rects[i]
            count[d] = j + 1
        keys, k2 = k2, keys
        rows, r2 = r2, rows
        rects, q2 = q2, rects
    return rows, rects


@njit(cache=True)
def sort_and_bin(fo, box, n_rows, tile, tiles_x, n_tiles, want_pos=False):
    """Rows r < n_rows with a non-empty pixel box, depth-sorted and binned to tiles.

    Returns (tile_offsets [n_tiles+1] int64, inst [M] int32 row indices, row_start
    [n_rows+1] int64, pos [M] int64): with want_pos, row r's instances sit at
    inst[pos[row_start[r]:row_start[r+1]]] (what the backward sums per splat); else the
    last two are 0-size."""
    n = 0
    for r in range(n_rows):
        if box[r, 2] >= box[r, 0]:
            n += 1
    keys = np.empty(n, np.uint32)
    rows = np.empty(n, np.int32)
    rects = np.empty(n, np.uint64)
    z = np.empty(1, np.float32)
    bits = z.view(np.uint32)
    row_start = np.zeros(n_rows + 1 if want_pos else 0, np.int64)
    j = 0
    for r in range(n_rows):
        if box[r, 2] >= box[r, 0]:
            z[0] = fo[r, F_Z]
            keys[j] = _float_key(bits[0])
            rows[j] = r
            tx0, ty0 = box[r, 0] // tile, box[r, 1] // tile
            tx1, ty1 = box[r, 2] // tile, box[r, 3] // tile
            rects[j] = (np.uint64(tx0) | (np.uint64(ty0) << 16) | (np.uint64(tx1) << 32)
                        | (np.uint64(ty1) << 48))
            if want_pos:
                row_start[r + 1] = (tx1 - tx0 + 1) * (ty1 - ty0 + 1)
            j += 1
    if want_pos:
        for r in range(n_rows):
            row_start[r + 1] += row_start[r]
    rows, rects = radix_sort(keys, rows, rects)
    counts = np.zeros(n_tiles + 1, np.int64)
    for k in range(n):
        q = rects[k]
        tx0, ty0 = np.int64(q & U16), np.int64((q >> 16) & U16)
        tx1, ty1 = np.int64((q >> 32) & U16), np.int64(q >> 48)
        for ty in range(ty0, ty1 + 1):
            for tx in range(tx0, tx1 + 1):
                counts[ty * tiles_x + tx + 1] += 1
    for t in range(n_tiles):
        counts[t + 1] += counts[t]
    inst = np.empty(counts[n_tiles], np.int32)
    pos = np.empty(counts[n_tiles] if want_pos else 0, np.int64)
    fill = counts[:n_tiles].copy()
    for k in range(n):
        q = rects[k]
        tx0, ty0 = np.int64(q & U16), np.int64((q >> 16) & U16)
        tx1, ty1 = np.int64((q >> 32) & U16), np.int64(q >> 48)
        r = rows[k]
        j = row_start[r] if want_pos else 0
        for ty in range(ty0, ty1 + 1):
            for tx in range(tx0, tx1 + 1):
                t = ty * tiles_x + tx
                inst[fill[t]] = r
                if want_pos:
                    pos[j] = fill[t]
                    j += 1
                fill[t] += 1
    return counts, inst, row_start, pos
