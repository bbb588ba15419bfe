"""Binning: depth-sort visible splats and build per-tile lists (counting sort by tile).

Reads per-visible-splat depths [V] and pixel boxes [V, 4]; writes tile_offsets [T+1] and
the instance list inst [M] (visible-splat index), each tile's slice sorted by depth,
ties by index.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def depth_order(z):
    """Stable ascending order of float32 depths z [V] (ties by index): LSD radix sort,
    three 11-bit passes over order-preserving uint32 keys of the float bits."""
    n = z.shape[0]
    bits = z.view(np.uint32)
    keys = np.empty(n, np.uint32)
    for i in range(n):
        b = bits[i]
        keys[i] = b ^ np.uint32(0xFFFFFFFF) if b >> np.uint32(31) else b ^ np.uint32(0x80000000)
    order = np.arange(n).astype(np.int64)
    tmp = np.empty(n, np.int64)
    for shift in (0, 11, 22):
        count = np.zeros(2049, np.int64)
        sh = np.uint32(shift)
        for i in range(n):
            count[((keys[order[i]] >> sh) & np.uint32(2047)) + 1] += 1
        for d in range(2048):
            count[d + 1] += count[d]
        for i in range(n):
            d = (keys[order[i]] >> sh) & np.uint32(2047)
            tmp[count[d]] = order[i]
            count[d] += 1
        order, tmp = tmp, order
    return order


@njit(cache=True)
def bin_tiles(order, box, tile, tiles_x, n_tiles):
    """Per-tile instance lists from pixel boxes box [V, 4] (j0, i0, j1, i1 inclusive);
    returns (tile_offsets [n_tiles+1] int64, inst [M] int32)."""
    V = order.shape[0]
    rect = np.empty((V, 4), np.int32)
    for v in range(V):
        if box[v, 2] < box[v, 0]:
            rect[v, 0] = rect[v, 1] = rect[v, 2] = rect[v, 3] = 0
        else:
            rect[v, 0] = box[v, 0] // tile
            rect[v, 1] = box[v, 1] // tile
            rect[v, 2] = box[v, 2] // tile + 1
            rect[v, 3] = box[v, 3] // tile + 1
    counts = np.zeros(n_tiles + 1, np.int64)
    for k in range(V):
        v = order[k]
        for ty in range(rect[v, 1], rect[v, 3]):
            for tx in range(rect[v, 0], rect[v, 2]):
                counts[ty * tiles_x + tx + 1] += 1
    for t in range(n_tiles):
        counts[t + 1] += counts[t]
    inst = np.empty(counts[n_tiles], np.int32)
    fill = counts[:n_tiles].copy()
    for k in range(order.shape[0]):
        v = order[k]
        for ty in range(rect[v, 1], rect[v, 3]):
            for tx in range(rect[v, 0], rect[v, 2]):
                t = ty * tiles_x + tx
                inst[fill[t]] = v
                fill[t] += 1
    return counts, inst
