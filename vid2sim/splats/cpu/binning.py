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
    """Stable ascending order of float32 depths z [V] (ties by index)."""
    return np.argsort(z, kind="mergesort")


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
