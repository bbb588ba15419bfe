"""Per-tile compositing (forward) and its back-to-front gradient pass (backward).

Each tile walks its depth-sorted splat list once and, per splat, only the pixels of the
splat's pixel box inside the tile (splat-major order with per-pixel state: the same
per-pixel arithmetic and order as the 3DGS pixel loop, but tiny splats cost a few pixels
instead of the whole tile). Forward writes the raw images plus, per pixel, the final
transmittance, n_contrib (list position after the last blended splat) and the median
splat's list position; backward walks back to front from those, recovering T by division.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ._sched import CHUNK, fetch_add, n_chunks, new_counter

from .project import (F_A, F_B, F_BL, F_C, F_CUT, F_G, F_NX, F_NY, F_NZ, F_O, F_R, F_X,
                      F_Y, F_Z, G_A, G_AX, G_AY, G_B, G_C, G_MX, G_MY, G_O, G_R, G_Z, NG)

F32 = np.float32
S_MAX = F32(4.5)
A_MIN = F32(1.0 / 255.0)
A_MAX = F32(0.99)
T_MIN = F32(1e-4)
T_MED = F32(0.5)
ONE = F32(1.0)
HALF = F32(0.5)
ZERO = F32(0.0)
NL = 14  # packed per-splat columns F_X .. F_NZ
MAX_TILE = 64  # tile rows carry a 64-bit mask of terminated pixels
ALL_BITS = np.uint64(0xFFFFFFFFFFFFFFFF)


def kernel_tile(tile_size: int) -> int:
    """Tile edge the kernels use: settings.tile_size capped at MAX_TILE (results do not
    depend on the tile size)."""
    return max(1, min(int(tile_size), MAX_TILE))


@njit(cache=True)
def gather(fo, box, inst, s, n, g, gb):
    """Copy the n splats of a tile (inst[s:s+n]) into packed g [n, NL] and boxes gb [n, 4]."""
    for k in range(n):
        v = inst[s + k]
        for q in range(NL):
            g[k, q] = fo[v, q]
        for q in range(4):
            gb[k, q] = box[v, q]


@njit(cache=True)
def _tile_forward(g, gb, n, x0, y0, x1, y1, color, alpha, depth, normal, median, T_out,
                  n_contrib, med_idx):
    tw = x1 - x0
    npx = tw * (y1 - y0)
    T = np.ones(npx, np.float32)
    acc = np.zeros((npx, 7), np.float32)  # r g b depth nx ny nz
    med = np.full(npx, -1, np.int32)
    last = np.zeros(npx, np.int32)
    done = np.zeros(npx, np.bool_)
    rmask = np.zeros(y1 - y0, np.uint64)  # per tile row: bit (px - x0) set once px is done
    n_done = 0
    for k in range(n):
        bx0 = max(gb[k, 0], x0)
        bx1 = min(gb[k, 2] + 1, x1)
        by0 = max(gb[k, 1], y0)
        by1 = min(gb[k, 3] + 1, y1)
        mx, my = g[k, F_X], g[k, F_Y]
        ca, cb, cc = g[k, F_A], g[k, F_B], g[k, F_C]
        o, cut = g[k, F_O], g[k, F_CUT]
        # hoisted: stores into acc could alias g as far as the compiler knows
        c0, c1, c2, c3 = g[k, F_R], g[k, F_G], g[k, F_BL], g[k, F_Z]
        c4, c5, c6 = g[k, F_NX], g[k, F_NY], g[k, F_NZ]
        if bx1 <= bx0:
            continue
        span = (ALL_BITS >> np.uint64(64 - (bx1 - bx0))) << np.uint64(bx0 - x0)
        for py in range(by0, by1):
            if rmask[py - y0] & span == span:
                continue  # every pixel of this row's span has terminated
            dy = (F32(py) + HALF) - my
            row = (py - y0) * tw - x0
            for px in range(bx0, bx1):
                p = row + px
                if done[p]:
                    continue
                dx = (F32(px) + HALF) - mx
                s = HALF * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                if s < ZERO or s > cut or s > S_MAX:
                    continue
                al = min(A_MAX, o * np.exp(-s))
                if al < A_MIN:
                    continue
                Tp = T[p]
                Tn = Tp * (ONE - al)
                if Tn < T_MIN:
                    done[p] = True
                    n_done += 1
                    rmask[py - y0] |= np.uint64(1) << np.uint64(px - x0)
                    continue
                w = al * Tp
                a = acc[p]
                a[0] += w * c0
                a[1] += w * c1
                a[2] += w * c2
                a[3] += w * c3
                a[4] += w * c4
                a[5] += w * c5
                a[6] += w * c6
                if med[p] < 0 and Tn <= T_MED:
                    med[p] = k
                T[p] = Tn
                last[p] = k + 1
        if n_done == npx:
            break
    for py in range(y0, y1):
        for px in range(x0, x1):
            p = (py - y0) * tw + px - x0
            a = acc[p]
            color[py, px, 0] = a[0]
            color[py, px, 1] = a[1]
            color[py, px, 2] = a[2]
            alpha[py, px] = ONE - T[p]
            depth[py, px] = a[3]
            normal[py, px, 0] = a[4]
            normal[py, px, 1] = a[5]
            normal[py, px, 2] = a[6]
            median[py, px] = g[med[p], F_Z] if med[p] >= 0 else ZERO
            T_out[py, px] = T[p]
            n_contrib[py, px] = last[p]
            med_idx[py, px] = med[p]


@njit(cache=True)
def tile_order(tile_offsets):
    """Tile ids [T] by instance count, largest first: drawn in this order from a shared
    counter, the big tiles start early and the small ones fill in at the end."""
    return np.argsort(tile_offsets[:-1] - tile_offsets[1:], kind="mergesort")


@njit(cache=True)
def tile_rect(t, tiles_x, tile, width, height):
    """Pixel rectangle (x0, y0, x1, y1) of tile t (x1, y1 exclusive)."""
    x0 = (t % tiles_x) * tile
    y0 = (t // tiles_x) * tile
    return x0, y0, min(x0 + tile, width), min(y0 + tile, height)


@njit(parallel=True, cache=True)
def raster_forward(fo, box, tile_offsets, inst, width, height, tile, color, alpha, depth,
                   normal, median, T_out, n_contrib, med_idx, n_workers=1):
    """Composite every tile; outputs are [H, W(, 3)] arrays. n_workers parallel workers
    draw tiles, largest first, from a shared counter (dynamic balance: near-camera tiles
    and a core slowed by other processes do not hold the others up)."""
    tiles_x = (width + tile - 1) // tile
    n_tiles = tiles_x * ((height + tile - 1) // tile)
    if tile > MAX_TILE:
        raise ValueError("cpu raster: tile larger than MAX_TILE (use kernel_tile())")
    order = tile_order(tile_offsets)
    cap = max(np.max(tile_offsets[1:] - tile_offsets[:-1]) if n_tiles > 0 else 0, 1)
    nxt = new_counter()
    for _h in prange(n_workers):
        g = np.empty((cap, NL), np.float32)
        gb = np.empty((cap, 4), np.int32)
        while True:
            k = fetch_add(nxt, 1)
            if k >= n_tiles:
                break
            t = order[k]
            s = tile_offsets[t]
            n = tile_offsets[t + 1] - s
            x0, y0, x1, y1 = tile_rect(t, tiles_x, tile, width, height)
            gather(fo, box, inst, s, n, g, gb)
            _tile_forward(g, gb, n, x0, y0, x1, y1, color, alpha, depth, normal, median,
                          T_out, n_contrib, med_idx)


# fastmath (reassociation, contraction) on the backward only: ~13 % less CPU in the 100k-splat
# 320x180 fwd+bwd (benchmarks/splats.py), gradients within the reference tolerances
# (tests/test_splats_cpu.py) and still the same for any thread count. The forward stays strict:
# the env's exact frames are compared bit for bit with it.
@njit(cache=True, fastmath=True)
def _tile_backward(g, gb, n, x0, y0, x1, y1, T_out, n_contrib, med_idx, d_color,
                   d_alpha, d_depth, d_normal, d_median, acc):
    """Back-to-front pass of one tile; adds splat k's 2D gradients into acc[k] ([n, NG])."""
    tw = x1 - x0
    npx = tw * (y1 - y0)
    T = np.empty(npx, np.float32)
    last = np.empty(npx, np.int32)
    gpix = np.empty((npx, 8), np.float32)  # dL/d(r g b depth nx ny nz), dL/dalpha * T_final
    S = np.zeros((npx, 7), np.float32)  # colour/depth/normal accumulated behind the splat
    for py in range(y0, y1):
        for px in range(x0, x1):
            p = (py - y0) * tw + px - x0
            T[p] = T_out[py, px]
            last[p] = n_contrib[py, px]
            m = med_idx[py, px]
            if m >= 0:
                acc[m, G_Z] += d_median[py, px]
            q = gpix[p]
            q[0] = d_color[py, px, 0]
            q[1] = d_color[py, px, 1]
            q[2] = d_color[py, px, 2]
            q[3] = d_depth[py, px]
            q[4] = d_normal[py, px, 0]
            q[5] = d_normal[py, px, 1]
            q[6] = d_normal[py, px, 2]
            q[7] = d_alpha[py, px] * T[p]
    for k in range(n - 1, -1, -1):
        bx0 = max(gb[k, 0], x0)
        bx1 = min(gb[k, 2] + 1, x1)
        by0 = max(gb[k, 1], y0)
        by1 = min(gb[k, 3] + 1, y1)
        mx, my = g[k, F_X], g[k, F_Y]
        ca, cb, cc = g[k, F_A], g[k, F_B], g[k, F_C]
        o, cut = g[k, F_O], g[k, F_CUT]
        ck = (g[k, F_R], g[k, F_G], g[k, F_BL], g[k, F_Z], g[k, F_NX], g[k, F_NY], g[k, F_NZ])
        a = acc[k]
        for py in range(by0, by1):
            dy = (F32(py) + HALF) - my
            row = (py - y0) * tw - x0
            for px in range(bx0, bx1):
                p = row + px
                if k >= last[p]:
                    continue
                dx = (F32(px) + HALF) - mx
                s = HALF * (ca * dx * dx + cc * dy * dy) + cb * dx * dy
                if s < ZERO or s > cut or s > S_MAX:
                    continue
                G = np.exp(-s)
                raw = o * G
                al = min(A_MAX, raw)
                if al < A_MIN:
                    continue
                om = ONE - al
                Tp = T[p] / om
                T[p] = Tp
                w = al * Tp
                q = gpix[p]
                Sp = S[p]
                dal = ZERO
                for c in range(7):  # G_R .. G_NZ follow the F_R .. F_NZ order
                    a[G_R + c] += w * q[c]
                    dal += (ck[c] - Sp[c]) * q[c]
                    Sp[c] = al * ck[c] + om * Sp[c]
                dal = Tp * dal + q[7] / om
                if raw <= A_MAX:
                    a[G_O] += G * dal
                    ds = -al * dal
                    gmx = -ds * (ca * dx + cb * dy)
                    gmy = -ds * (cc * dy + cb * dx)
                    a[G_MX] += gmx
                    a[G_MY] += gmy
                    a[G_AX] += abs(gmx)
                    a[G_AY] += abs(gmy)
                    a[G_A] += HALF * ds * dx * dx
                    a[G_B] += ds * dx * dy
                    a[G_C] += HALF * ds * dy * dy


@njit(parallel=True, cache=True)
def raster_backward(fo, box, tile_offsets, inst, row_start, pos, n_vis, width, height, tile,
                    T_out, n_contrib, med_idx, d_color, d_alpha, d_depth, d_normal, d_median,
                    n_workers):
    """Per-visible-splat 2D gradients g2 [V, NG] float32.

    Race-free and deterministic for any thread count: each (tile, splat) instance owns
    one row of gi [M, NG] (tiles drawn dynamically, largest first); then every splat sums
    its instance rows pos[row_start[v]:row_start[v+1]] in a fixed order.
    """
    tiles_x = (width + tile - 1) // tile
    n_tiles = tiles_x * ((height + tile - 1) // tile)
    order = tile_order(tile_offsets)
    cap = max(np.max(tile_offsets[1:] - tile_offsets[:-1]) if n_tiles > 0 else 0, 1)
    gi = np.empty((inst.shape[0], NG), np.float32)
    nxt = new_counter()
    for _h in prange(n_workers):
        g = np.empty((cap, NL), np.float32)
        gb = np.empty((cap, 4), np.int32)
        while True:
            k = fetch_add(nxt, 1)
            if k >= n_tiles:
                break
            t = order[k]
            s = tile_offsets[t]
            n = tile_offsets[t + 1] - s
            if n == 0:
                continue
            x0, y0, x1, y1 = tile_rect(t, tiles_x, tile, width, height)
            gather(fo, box, inst, s, n, g, gb)
            acc = gi[s:s + n]
            acc[:] = 0.0
            _tile_backward(g, gb, n, x0, y0, x1, y1, T_out, n_contrib, med_idx, d_color,
                           d_alpha, d_depth, d_normal, d_median, acc)
    out = np.empty((n_vis, NG), np.float32)
    nxt[0] = 0
    n_items = n_chunks(n_vis, CHUNK)
    for _h in prange(n_workers):
        while True:
            c = fetch_add(nxt, 1)
            if c >= n_items:
                break
            for v in range(c * CHUNK, min(n_vis, (c + 1) * CHUNK)):
                o = out[v]
                o[:] = 0.0
                for j in range(row_start[v], row_start[v + 1]):
                    a = gi[pos[j]]
                    for q in range(NG):
                        o[q] += a[q]
    return out
