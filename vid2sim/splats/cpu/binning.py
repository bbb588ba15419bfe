"""Binning: depth-sort the splats that reach a pixel and build per-tile lists.

Reads per-row depths fo[:, F_Z] and pixel boxes box [R, 4] (j0, i0, j1, i1 inclusive;
empty when j1 < j0); writes tile_offsets [T+1] and the instance list inst [M] (row index),
each tile's slice sorted by depth, ties by row index. The radix sort carries each row's
packed tile rectangle so binning reads sequentially (no random access into `box`).

Every step runs on fixed blocks of rows (per-block counts, a serial prefix over blocks,
then a parallel scatter), so the result is the same for any thread count; workers draw
blocks from a shared counter.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ._sched import fetch_add, new_counter
from .project import F_Z

U16 = np.uint64(0xFFFF)
BLOCK = 8192  # rows per block
RADIX = 2048  # 11-bit digits, three passes


@njit(cache=True)
def _float_key(b):
    """Order-preserving uint32 key of float32 bits b."""
    return b ^ np.uint32(0xFFFFFFFF) if b >> np.uint32(31) else b ^ np.uint32(0x80000000)


@njit(cache=True)
def _unpack(q):
    """Tile rectangle (tx0, ty0, tx1, ty1) of a packed uint64."""
    return (np.int64(q & U16), np.int64((q >> 16) & U16), np.int64((q >> 32) & U16),
            np.int64(q >> 48))


@njit(cache=True)
def _n_blocks(n):
    return max(1, (n + BLOCK - 1) // BLOCK)


@njit(cache=True)
def _pow2_shift(tile):
    """log2(tile) when tile is a power of two, else -1."""
    for s in range(31):
        if (1 << s) == tile:
            return s
    return -1


@njit(cache=True, inline="always")
def _tdiv(x, tile, shift):
    """x // tile for x >= 0 (a shift when tile is a power of two: integer division is slow)."""
    return x >> shift if shift >= 0 else x // tile


@njit(cache=True, inline="always")
def _rect(box, r, tile, shift):
    """(packed tile rectangle of row r's pixel box, number of tiles it covers)."""
    tx0, ty0 = _tdiv(box[r, 0], tile, shift), _tdiv(box[r, 1], tile, shift)
    tx1, ty1 = _tdiv(box[r, 2], tile, shift), _tdiv(box[r, 3], tile, shift)
    q = (np.uint64(tx0) | (np.uint64(ty0) << 16) | (np.uint64(tx1) << 32)
         | (np.uint64(ty1) << 48))
    return q, (tx1 - tx0 + 1) * (ty1 - ty0 + 1)


@njit(parallel=True, cache=True)
def radix_sort(keys, rows, rects, n_workers=1):
    """Stable ascending sort of uint32 keys [n], carrying int32 rows [n] and uint64 rects [n]:
    LSD radix, three 11-bit passes, per-block histograms. Returns (rows, rects) sorted."""
    n = keys.shape[0]
    nb = _n_blocks(n)
    k2 = np.empty(n, np.uint32)
    r2 = np.empty(n, np.int32)
    q2 = np.empty(n, np.uint64)
    hist = np.empty((nb, RADIX), np.int64)
    for shift in (0, 11, 22):
        sh = np.uint32(shift)
        nxt = new_counter()
        for _h in prange(n_workers):
            while True:
                b = fetch_add(nxt, 1)
                if b >= nb:
                    break
                hist[b, :] = 0
                for i in range(b * BLOCK, min(n, (b + 1) * BLOCK)):
                    hist[b, (keys[i] >> sh) & np.uint32(RADIX - 1)] += 1
        s = 0
        for d in range(RADIX):  # exclusive prefix, digit-major then block
            for b in range(nb):
                c = hist[b, d]
                hist[b, d] = s
                s += c
        nxt[0] = 0
        for _h in prange(n_workers):
            while True:
                b = fetch_add(nxt, 1)
                if b >= nb:
                    break
                at = hist[b]
                for i in range(b * BLOCK, min(n, (b + 1) * BLOCK)):
                    d = (keys[i] >> sh) & np.uint32(RADIX - 1)
                    j = at[d]
                    k2[j] = keys[i]
                    r2[j] = rows[i]
                    q2[j] = rects[i]
                    at[d] = j + 1
        keys, k2 = k2, keys
        rows, r2 = r2, rows
        rects, q2 = q2, rects
    return rows, rects


@njit(parallel=True, cache=True)
def _keys(fo, box, n_rows, tile, want_pos, n_workers):
    """Compact the rows with a non-empty box into (keys, rows, rects) in row order; with
    want_pos also row_start [n_rows+1] (exclusive prefix of each row's tile count)."""
    nb = _n_blocks(n_rows)
    cnt = np.zeros(nb + 1, np.int64)
    for b in prange(nb):
        c = 0
        for r in range(b * BLOCK, min(n_rows, (b + 1) * BLOCK)):
            if box[r, 2] >= box[r, 0]:
                c += 1
        cnt[b + 1] = c
    for b in range(nb):
        cnt[b + 1] += cnt[b]
    n = cnt[nb]
    keys = np.empty(n, np.uint32)
    rows = np.empty(n, np.int32)
    rects = np.empty(n, np.uint64)
    row_start = np.zeros(n_rows + 1 if want_pos else 0, np.int64)
    shift = _pow2_shift(tile)
    nxt = new_counter()
    for _h in prange(n_workers):
        z = np.empty(1, np.float32)
        bits = z.view(np.uint32)
        while True:
            b = fetch_add(nxt, 1)
            if b >= nb:
                break
            j = cnt[b]
            for r in range(b * BLOCK, min(n_rows, (b + 1) * BLOCK)):
                if box[r, 2] < box[r, 0]:
                    continue
                z[0] = fo[r, F_Z]
                keys[j] = _float_key(bits[0])
                rows[j] = r
                rects[j], nt = _rect(box, r, tile, shift)
                if want_pos:
                    row_start[r + 1] = nt
                j += 1
    if want_pos:
        for r in range(n_rows):
            row_start[r + 1] += row_start[r]
    return keys, rows, rects, row_start


@njit(parallel=True, cache=True)
def _bin(rows, rects, row_start, tiles_x, n_tiles, want_pos, n_workers):
    """Depth-sorted (rows, rects) -> tile_offsets [T+1], inst [M], pos [M] (see sort_and_bin)."""
    n = rows.shape[0]
    nb = _n_blocks(n)
    start = np.zeros((nb, n_tiles), np.int64)  # per-block counts, then write positions
    nxt = new_counter()
    for _h in prange(n_workers):
        while True:
            b = fetch_add(nxt, 1)
            if b >= nb:
                break
            cb = start[b]
            for k in range(b * BLOCK, min(n, (b + 1) * BLOCK)):
                tx0, ty0, tx1, ty1 = _unpack(rects[k])
                for ty in range(ty0, ty1 + 1):
                    for tx in range(tx0, tx1 + 1):
                        cb[ty * tiles_x + tx] += 1
    offsets = np.zeros(n_tiles + 1, np.int64)
    s = 0
    for t in range(n_tiles):  # tile-major, then block: each tile's slice stays depth-sorted
        offsets[t] = s
        for b in range(nb):
            c = start[b, t]
            start[b, t] = s
            s += c
    offsets[n_tiles] = s
    inst = np.empty(s, np.int32)
    pos = np.empty(s if want_pos else 0, np.int64)
    nxt[0] = 0
    for _h in prange(n_workers):
        while True:
            b = fetch_add(nxt, 1)
            if b >= nb:
                break
            fill = start[b]
            for k in range(b * BLOCK, min(n, (b + 1) * BLOCK)):
                tx0, ty0, tx1, ty1 = _unpack(rects[k])
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
    return offsets, inst, pos


@njit(cache=True)
def _radix_sort_serial(keys, rows, rects):
    """radix_sort in one thread."""
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
def _sort_and_bin_serial(fo, box, n_rows, tile, tiles_x, n_tiles, want_pos):
    """sort_and_bin in one thread (no parallel-region overhead)."""
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
    shift = _pow2_shift(tile)
    j = 0
    for r in range(n_rows):
        if box[r, 2] >= box[r, 0]:
            z[0] = fo[r, F_Z]
            keys[j] = _float_key(bits[0])
            rows[j] = r
            rects[j], nt = _rect(box, r, tile, shift)
            if want_pos:
                row_start[r + 1] = nt
            j += 1
    if want_pos:
        for r in range(n_rows):
            row_start[r + 1] += row_start[r]
    rows, rects = _radix_sort_serial(keys, rows, rects)
    counts = np.zeros(n_tiles + 1, np.int64)
    for k in range(n):
        q = rects[k]  # as _unpack, written out: an inlined call compiles this loop differently
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
        q = rects[k]  # as _unpack, written out: an inlined call compiles this loop differently
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


def sort_and_bin(fo: np.ndarray, box: np.ndarray, n_rows: int, tile: int, tiles_x: int,
                 n_tiles: int, want_pos: bool = False, n_workers: int = 1) -> tuple:
    """Rows r < n_rows with a non-empty pixel box, depth-sorted and binned to tiles.

    Returns (tile_offsets [n_tiles+1] int64, inst [M] int32 row indices, row_start
    [n_rows+1] int64, pos [M] int64): with want_pos, row r's instances sit at
    inst[pos[row_start[r]:row_start[r+1]]] (what the backward sums per splat); else the
    last two are 0-size. One worker runs the serial version."""
    if n_workers <= 1:
        return _sort_and_bin_serial(fo, box, n_rows, tile, tiles_x, n_tiles, want_pos)
    keys, rows, rects, row_start = _keys(fo, box, n_rows, tile, want_pos, n_workers)
    rows, rects = radix_sort(keys, rows, rects, n_workers)
    offsets, inst, pos = _bin(rows, rects, row_start, tiles_x, n_tiles, want_pos, n_workers)
    return offsets, inst, row_start, pos
