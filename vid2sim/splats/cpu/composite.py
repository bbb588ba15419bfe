"""Per-tile compositing (forward) and its back-to-front gradient pass (backward).

Each tile walks its depth-sorted splat list once and, per splat, only the pixels of the
splat's pixel box inside the tile (splat-major order with per-pixel state: the same
per-pixel arithmetic and order as the 3DGS pixel loop, but tiny splats cost a few pixels
instead of the whole tile). Forward writes the raw images plus, per pixel, the final
transmittance, n_contrib (list position after the last blended splat) and the median
splat's list position; backward walks back to front from those, recovering T by division.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
from numba import njit, prange

from ._bits import popc64
from ._expf import expf_glibc, expf_lanes
from ._sched import CHUNK, fetch_add, n_chunks, new_counter
from .project import (F_A, F_B, F_BL, F_C, F_CUT, F_G, F_NX, F_NY, F_NZ, F_O, F_R, F_X,
                      F_Y, F_Z, G_A, G_AX, G_AY, G_B, G_BL, G_C, G_G, G_MX, G_MY, G_NX, G_NY,
                      G_NZ, G_O, G_R, G_Z, NG)

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
# Tile edge cap: the pixel planes below hold MAX_TILE x MAX_TILE pixels (rows carry a 64-bit
# mask of stopped pixels). Compact planes keep a tile's state in L1; the GoPro clip's training
# views (320x150, 88k splats, 2 threads) composite ~9 % (forward) and ~10 % (backward) faster
# in 32 px tiles than in 16 px ones, and as fast as in 64 px tiles with 64 px planes.
MAX_TILE = 32
CPU_TILE = 32  # px, the cpu kernels' tile edge when RasterSettings.tile_size is None
ALL_BITS = np.uint64(0xFFFFFFFFFFFFFFFF)


def kernel_tile(tile_size: Optional[int]) -> int:
    """Tile edge the kernels use: settings.tile_size (CPU_TILE when None) capped at MAX_TILE
    (images do not depend on the tile size; the backward's gradients by float rounding)."""
    return CPU_TILE if tile_size is None else max(1, min(int(tile_size), MAX_TILE))


@njit(cache=True)
def gather(fo, box, inst, s, n, g, gb):
    """Copy the n splats of a tile (inst[s:s+n]) into packed g [n, NL] and boxes gb [n, 4]."""
    for k in range(n):
        v = inst[s + k]
        for q in range(NL):
            g[k, q] = fo[v, q]
        for q in range(4):
            gb[k, q] = box[v, q]


LANES = 8  # pixels per SIMD window of a splat row
PROW = MAX_TILE + LANES  # row stride of the tile's pixel planes (windows may run past the tile)
PLANE = MAX_TILE * PROW  # floats per plane
U64 = np.uint64
# Forward planes of `pix` after T (plane 0): r g b depth nx ny nz, n_contrib, median position
# (both float32: exact below 2^24). Fixed compile-time offsets into one buffer with unsigned
# indices let LLVM vectorise the windows without runtime alias checks.
P_ACC = tuple(U64(i * PLANE) for i in range(1, 8))
P_LAST, P_MED = U64(8 * PLANE), U64(9 * PLANE)
N_FWD_PLANES = 10


@njit(cache=True, inline="always")
def _fwd_window(pix, pb, px0, livebits, hi, kf, mx, dy, ccdy2, ca, cb, o, ct, c0, c1, c2, c3,
                c4, c5, c6, med):
    """Blend splat kf into LANES pixels of a row (lane j = pixel px0 + j, plane index pb + j)
    with the arithmetic and order of the per-pixel 3DGS loop but no branch, so the window
    vectorises (expf_glibc equals np.exp bit for bit). Lanes that have stopped (bit j of
    livebits clear), lie past the box (j > hi), fall outside the cut-off or below A_MIN take
    no weight; lanes reaching T < T_MIN stop. med (a constant at each call: the branch folds
    away once inlined): track the median splat. Returns the stop bits."""
    stops = U64(0)
    for j in range(LANES):
        p = pb + U64(j)
        dx = (F32(px0 + j) + HALF) - mx
        s = HALF * (ca * dx * dx + ccdy2) + cb * dx * dy
        cand = ((livebits >> U64(j)) & U64(1) == U64(1)) & (U64(j) <= hi) & (s >= ZERO) & (
            s <= ct)
        oe = o * expf_glibc(-s)  # garbage outside [0, ct]: masked below
        al = A_MAX if A_MAX < oe else oe  # min(A_MAX, o e)
        ok = cand & (al >= A_MIN)
        Tp = pix[p]
        Tn = Tp * (ONE - al)
        blend = ok & (Tn >= T_MIN)
        w = al * Tp if blend else ZERO
        pix[p + P_ACC[0]] += w * c0
        pix[p + P_ACC[1]] += w * c1
        pix[p + P_ACC[2]] += w * c2
        pix[p + P_ACC[3]] += w * c3
        pix[p + P_ACC[4]] += w * c4
        pix[p + P_ACC[5]] += w * c5
        pix[p + P_ACC[6]] += w * c6
        pix[p] = Tn if blend else Tp
        pix[p + P_LAST] = kf + ONE if blend else pix[p + P_LAST]
        if med:
            m = pix[p + P_MED]
            pix[p + P_MED] = kf if blend & (m < ZERO) & (Tn <= T_MED) else m
        stops |= U64(ok & (Tn < T_MIN)) << U64(j)
    return stops


@njit(cache=True, error_model="numpy")
def _tile_forward(g, gb, n, x0, y0, x1, y1, pix, rdone, color, alpha, depth, normal, median,
                  T_out, n_contrib, med_idx, want_median):
    """Composite one tile's depth-sorted splats g [n, NL] / gb [n, 4] (splat-major, each
    splat row in SIMD windows, per-pixel early stop); pix [N_FWD_PLANES PLANE] and
    rdone [MAX_TILE] (per row: bit px - x0 set once px has stopped) are scratch. Without
    want_median, median and med_idx read 0 and -1."""
    tw, th = x1 - x0, y1 - y0
    for i in range(th * PROW):
        p = U64(i)
        pix[p] = ONE
        for q in range(7):
            pix[p + P_ACC[q]] = ZERO
        pix[p + P_LAST] = ZERO
        pix[p + P_MED] = -ONE
    rdone[:th] = 0
    n_live = tw * th
    for k in range(n):
        bx0 = max(gb[k, 0], x0)
        bx1 = min(gb[k, 2] + 1, x1)
        by0 = max(gb[k, 1], y0)
        by1 = min(gb[k, 3] + 1, y1)
        if bx1 <= bx0:
            continue
        mx, my = g[k, F_X], g[k, F_Y]
        ca, cb, cc = g[k, F_A], g[k, F_B], g[k, F_C]
        o, ct = g[k, F_O], min(g[k, F_CUT], S_MAX)
        c0, c1, c2, c3 = g[k, F_R], g[k, F_G], g[k, F_BL], g[k, F_Z]
        c4, c5, c6 = g[k, F_NX], g[k, F_NY], g[k, F_NZ]
        kf = F32(k)
        lo, hi = bx0 - x0, bx1 - 1 - x0
        span = (ALL_BITS >> U64(63 - (hi - lo))) << U64(lo)
        for py in range(by0, by1):
            ry = py - y0
            if rdone[ry] & span == span:
                continue  # every pixel of this row's span has stopped
            dy = (F32(py) + HALF) - my
            ccdy2 = cc * dy * dy
            for c in range(lo, hi + 1, LANES):
                pb, live = U64(ry * PROW + c), ~rdone[ry] >> U64(c)
                if want_median:
                    stop = _fwd_window(pix, pb, x0 + c, live, U64(hi - c), kf, mx, dy, ccdy2, ca,
                                       cb, o, ct, c0, c1, c2, c3, c4, c5, c6, True)
                else:
                    stop = _fwd_window(pix, pb, x0 + c, live, U64(hi - c), kf, mx, dy, ccdy2, ca,
                                       cb, o, ct, c0, c1, c2, c3, c4, c5, c6, False)
                stop <<= U64(c)
                rdone[ry] |= stop
                n_live -= np.int64(popc64(stop))
        if n_live == 0:
            break
    for py in range(y0, y1):
        for px in range(x0, x1):
            p = U64((py - y0) * PROW + px - x0)
            color[py, px, 0] = pix[p + P_ACC[0]]
            color[py, px, 1] = pix[p + P_ACC[1]]
            color[py, px, 2] = pix[p + P_ACC[2]]
            alpha[py, px] = ONE - pix[p]
            depth[py, px] = pix[p + P_ACC[3]]
            normal[py, px, 0] = pix[p + P_ACC[4]]
            normal[py, px, 1] = pix[p + P_ACC[5]]
            normal[py, px, 2] = pix[p + P_ACC[6]]
            m = np.int32(pix[p + P_MED])
            median[py, px] = g[m, F_Z] if m >= 0 else ZERO
            T_out[py, px] = pix[p]
            n_contrib[py, px] = np.int32(pix[p + P_LAST])
            med_idx[py, px] = m


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
                   normal, median, T_out, n_contrib, med_idx, n_workers=1, want_median=True):
    """Composite every tile; outputs are [H, W(, 3)] arrays (without want_median, median
    and med_idx read 0 and -1). n_workers parallel workers draw tiles, largest first, from a
    shared counter (dynamic balance: near-camera tiles and a core slowed by other processes
    do not hold the others up)."""
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
        pix = np.empty(N_FWD_PLANES * PLANE, np.float32)
        rdone = np.empty(MAX_TILE, np.uint64)
        while True:
            k = fetch_add(nxt, 1)
            if k >= n_tiles:
                break
            t = order[k]
            s = tile_offsets[t]
            n = tile_offsets[t + 1] - s
            x0, y0, x1, y1 = tile_rect(t, tiles_x, tile, width, height)
            gather(fo, box, inst, s, n, g, gb)
            _tile_forward(g, gb, n, x0, y0, x1, y1, pix, rdone, color, alpha, depth, normal,
                          median, T_out, n_contrib, med_idx, want_median)


# Backward planes of `pix` after T (plane 0): n_contrib (float32), the 8 per-pixel loss
# gradients Q (dL/d r g b depth nx ny nz, dL/dalpha * T_final) and R = sum_c Q_c S_c, the
# 7 channels S accumulated behind the current splat weighted by their loss gradients. The
# pixel's Q do not change from splat to splat, so one plane R stands for the seven S planes
# of the 3DGS backward: dL/dalpha needs sum_c (c_c - S_c) Q_c = sum_c c_c Q_c - R, and
# S_c <- alpha c_c + (1 - alpha) S_c becomes R <- alpha sum_c c_c Q_c + (1 - alpha) R.
P_LAST_B = U64(PLANE)
P_Q = tuple(U64((2 + i) * PLANE) for i in range(8))
P_R = U64(10 * PLANE)
N_BWD_PLANES = 11


# fastmath (reassociation, contraction) on the backward only: it lets LLVM sum each window's
# lanes; gradients stay within the reference tolerances (tests/test_splats_cpu.py) and the
# same for any thread count. The forward stays strict: the env's exact frames are compared
# bit for bit with it. The backward's exp is `expf_lanes` (float32 lanes, within 3 ulp of the
# forward's `expf_glibc`; glibc's replay works in double precision with a table, which costs
# an AVX2 machine a third of the backward).
@njit(cache=True, fastmath=True, inline="always")
def _bwd_window(pix, pb, px0, hi, kf, mx, dy, ccdy2, ca, cb, cc, o, ct, c0, c1, c2, c3, c4, c5,
                c6):
    """Take splat kf off LANES pixels of a row (lane j = pixel px0 + j, plane index pb + j),
    back to front, without a branch so the window vectorises. Lanes past the box (j > hi),
    at or behind the pixel's last blended splat, outside the cut-off or below A_MIN add
    zeros. Returns (bits of the lanes that took part, the window's sums: of ds, ds dx and
    ds dx^2 (ds = dL/dsigma; `_add_sums` turns them into the mean, conic and opacity
    gradients, dy being the row's), of the r g b, depth and normal x y z gradients, and of
    |dL/dmean x| and |dL/dmean y|)."""
    hits = U64(0)
    s0 = s1 = s2 = ZERO
    s_r = s_g = s_bl = s_z = s_nx = s_ny = s_nz = s_ax = s_ay = ZERO
    for j in range(LANES):
        p = pb + U64(j)
        dx = (F32(px0 + j) + HALF) - mx
        s = HALF * (ca * dx * dx + ccdy2) + cb * dx * dy
        cand = (U64(j) <= hi) & (kf < pix[p + P_LAST_B]) & (s >= ZERO) & (s <= ct)
        e = expf_lanes(-s)  # garbage outside [0, ct]: masked below
        raw = o * e
        al = A_MAX if A_MAX < raw else raw  # min(A_MAX, o e)
        ok = cand & (al >= A_MIN)
        al = al if ok else ZERO  # a lane that does not take part: T, R unchanged, zero sums
        om = ONE - al
        Tp = pix[p] / om  # T in front of the splat
        pix[p] = Tp
        w = al * Tp
        q0, q1, q2, q3 = pix[p + P_Q[0]], pix[p + P_Q[1]], pix[p + P_Q[2]], pix[p + P_Q[3]]
        q4, q5, q6 = pix[p + P_Q[4]], pix[p + P_Q[5]], pix[p + P_Q[6]]
        cq = c0 * q0 + c1 * q1 + c2 * q2 + c3 * q3 + c4 * q4 + c5 * q5 + c6 * q6
        rb = pix[p + P_R]  # sum_c Q_c S_c behind the splat
        pix[p + P_R] = al * cq + om * rb if ok else rb
        s_r += w * q0
        s_g += w * q1
        s_bl += w * q2
        s_z += w * q3
        s_nx += w * q4
        s_ny += w * q5
        s_nz += w * q6
        dal = Tp * (cq - rb) + pix[p + P_Q[7]] / om  # dL/dalpha
        dal = dal if ok & (raw <= A_MAX) else ZERO  # clamped at A_MAX: no gradient through it
        ds = -al * dal  # dL/dsigma
        gmx = -ds * (ca * dx + cb * dy)
        gmy = -ds * (cc * dy + cb * dx)
        s0 += ds
        s1 += ds * dx
        s2 += ds * dx * dx
        s_ax += abs(gmx)
        s_ay += abs(gmy)
        hits |= U64(ok) << U64(j)
    return hits, (s0, s1, s2, s_r, s_g, s_bl, s_z, s_nx, s_ny, s_nz, s_ax, s_ay)


@njit(cache=True, fastmath=True, inline="always")
def _add_sums(a, sums, dy, ca, cb, cc, o):
    """Adds a window's gradients into a splat's row a [NG] (G_* order) from its sums
    (`_bwd_window` order). dy is the same in every lane of a window, so the mean, conic and
    opacity gradients follow from three sums (S0, S1, S2 of ds, ds dx, ds dx^2):
    dL/dmean x = -(ca S1 + cb dy S0), dL/dmean y = -(cc dy S0 + cb S1), dL/da = S2 / 2,
    dL/db = dy S1, dL/dc = dy^2 S0 / 2 and dL/do = -S0 / o (ds = -o e dL/dalpha wherever a
    lane has a gradient); written out: a loop over the tuple compiles to a jump table."""
    s0, s1 = sums[0], sums[1]
    a[G_MX] -= ca * s1 + cb * dy * s0
    a[G_MY] -= cc * dy * s0 + cb * s1
    a[G_A] += HALF * sums[2]
    a[G_B] += dy * s1
    a[G_C] += HALF * dy * dy * s0
    a[G_O] -= s0 / o if o > ZERO else ZERO
    a[G_R] += sums[3]
    a[G_G] += sums[4]
    a[G_BL] += sums[5]
    a[G_Z] += sums[6]
    a[G_NX] += sums[7]
    a[G_NY] += sums[8]
    a[G_NZ] += sums[9]
    a[G_AX] += sums[10]
    a[G_AY] += sums[11]


@njit(cache=True)
def _bwd_init(x0, y0, x1, y1, pix, rlast, T_out, n_contrib, med_idx, d_color, d_alpha,
              d_depth, d_normal, d_median, acc):
    """Fill the backward planes of one tile (windows past the tile's right edge read T = 1
    and zeros); rlast [MAX_TILE] gets each row's largest n_contrib, acc [n, NG] the median
    depth gradients. Returns the tile's largest n_contrib."""
    tw = x1 - x0
    k_end = 0
    for ry in range(y1 - y0):
        py = y0 + ry
        rl = 0
        for cx in range(tw + LANES):
            p = U64(ry * PROW + cx)
            px = x0 + cx
            if cx >= tw:
                pix[p] = ONE
                pix[p + P_LAST_B] = ZERO
                for c in range(8):
                    pix[p + P_Q[c]] = ZERO
                pix[p + P_R] = ZERO
                continue
            T = T_out[py, px]
            last = n_contrib[py, px]
            rl = max(rl, last)
            pix[p] = T
            pix[p + P_LAST_B] = F32(last)
            m = med_idx[py, px]
            if m >= 0:
                acc[m, G_Z] += d_median[py, px]
            for c in range(3):
                pix[p + P_Q[c]] = d_color[py, px, c]
                pix[p + P_Q[4 + c]] = d_normal[py, px, c]
            pix[p + P_Q[3]] = d_depth[py, px]
            pix[p + P_Q[7]] = d_alpha[py, px] * T
            pix[p + P_R] = ZERO
        rlast[ry] = rl
        k_end = max(k_end, rl)
    return k_end


@njit(cache=True, fastmath=True, error_model="numpy")
def _tile_backward(g, gb, n, x0, y0, x1, y1, pix, rlast, T_out, n_contrib, med_idx, d_color,
                   d_alpha, d_depth, d_normal, d_median, acc):
    """Back-to-front pass of one tile (from each pixel's last blended splat, recovering T by
    division); adds splat k's 2D gradients into acc[k] ([n, NG]). pix [N_BWD_PLANES PLANE]
    and rlast [MAX_TILE] are scratch. Returns the number of leading rows of acc it touched
    (rows from there on stay as they were)."""
    k_end = _bwd_init(x0, y0, x1, y1, pix, rlast, T_out, n_contrib, med_idx, d_color, d_alpha,
                      d_depth, d_normal, d_median, acc)
    for k in range(min(n, k_end) - 1, -1, -1):
        bx0 = max(gb[k, 0], x0)
        bx1 = min(gb[k, 2] + 1, x1)
        by0 = max(gb[k, 1], y0)
        by1 = min(gb[k, 3] + 1, y1)
        if bx1 <= bx0:
            continue
        mx, my = g[k, F_X], g[k, F_Y]
        ca, cb, cc = g[k, F_A], g[k, F_B], g[k, F_C]
        o, ct = g[k, F_O], min(g[k, F_CUT], S_MAX)
        c0, c1, c2, c3 = g[k, F_R], g[k, F_G], g[k, F_BL], g[k, F_Z]
        c4, c5, c6 = g[k, F_NX], g[k, F_NY], g[k, F_NZ]
        kf = F32(k)
        lo, hi = bx0 - x0, bx1 - 1 - x0
        a = acc[k]
        for py in range(by0, by1):
            ry = py - y0
            if k >= rlast[ry]:
                continue  # no pixel of this row blended splat k
            dy = (F32(py) + HALF) - my
            ccdy2 = cc * dy * dy
            for c in range(lo, hi + 1, LANES):
                hits, sums = _bwd_window(pix, U64(ry * PROW + c), x0 + c, U64(hi - c), kf, mx,
                                         dy, ccdy2, ca, cb, cc, o, ct, c0, c1, c2, c3, c4, c5,
                                         c6)
                if hits:
                    _add_sums(a, sums, dy, ca, cb, cc, o)
    return min(n, k_end)


@njit(parallel=True, cache=True)
def _raster_backward_tiles(fo, box, tile_offsets, inst, row_start, pos, n_vis, width, height, tile,
                    T_out, n_contrib, med_idx, d_color, d_alpha, d_depth, d_normal, d_median,
                    n_workers):
    """raster_backward on n_workers threads: each (tile, splat) instance owns one row of
    gi [M, NG] (tiles drawn dynamically, largest first, race-free); then every splat sums
    its instance rows pos[row_start[v]:row_start[v+1]] (ascending tile order)."""
    tiles_x = (width + tile - 1) // tile
    n_tiles = tiles_x * ((height + tile - 1) // tile)
    order = tile_order(tile_offsets)
    cap = max(np.max(tile_offsets[1:] - tile_offsets[:-1]) if n_tiles > 0 else 0, 1)
    gi = np.empty((inst.shape[0], NG), np.float32)
    nxt = new_counter()
    for _h in prange(n_workers):
        g = np.empty((cap, NL), np.float32)
        gb = np.empty((cap, 4), np.int32)
        pix = np.empty(N_BWD_PLANES * PLANE, np.float32)
        rlast = np.empty(MAX_TILE, np.int64)
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
            _tile_backward(g, gb, n, x0, y0, x1, y1, pix, rlast, T_out, n_contrib, med_idx,
                           d_color, d_alpha, d_depth, d_normal, d_median, acc)
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


@njit(cache=True)
def _raster_backward_serial(fo, box, tile_offsets, inst, n_vis, width, height, tile, T_out,
                            n_contrib, med_idx, d_color, d_alpha, d_depth, d_normal, d_median):
    """raster_backward in one thread: tiles in ascending order, each tile's gradient rows
    added straight into their splat's row of g2 (the same sums in the same order as the
    instance rows of the parallel version, without the [M, NG] buffer)."""
    tiles_x = (width + tile - 1) // tile
    n_tiles = tiles_x * ((height + tile - 1) // tile)
    cap = max(np.max(tile_offsets[1:] - tile_offsets[:-1]) if n_tiles > 0 else 0, 1)
    g = np.empty((cap, NL), np.float32)
    gb = np.empty((cap, 4), np.int32)
    pix = np.empty(N_BWD_PLANES * PLANE, np.float32)
    rlast = np.empty(MAX_TILE, np.int64)
    acc = np.zeros((cap, NG), np.float32)
    out = np.zeros((n_vis, NG), np.float32)
    for t in range(n_tiles):
        s = tile_offsets[t]
        n = tile_offsets[t + 1] - s
        if n == 0:
            continue
        x0, y0, x1, y1 = tile_rect(t, tiles_x, tile, width, height)
        gather(fo, box, inst, s, n, g, gb)
        m = _tile_backward(g, gb, n, x0, y0, x1, y1, pix, rlast, T_out, n_contrib, med_idx,
                           d_color, d_alpha, d_depth, d_normal, d_median, acc)
        for k in range(m):  # rows m.. are zero: adding them would change nothing
            o = out[inst[s + k]]
            a = acc[k]
            for q in range(NG):
                o[q] += a[q]
                a[q] = 0.0
    return out


def raster_backward(fo: np.ndarray, box: np.ndarray, tile_offsets: np.ndarray, inst: np.ndarray,
                    row_start: np.ndarray, pos: np.ndarray, n_vis: int, width: int, height: int,
                    tile: int, T_out: np.ndarray, n_contrib: np.ndarray, med_idx: np.ndarray,
                    d_color: np.ndarray, d_alpha: np.ndarray, d_depth: np.ndarray,
                    d_normal: np.ndarray, d_median: np.ndarray, n_workers: int) -> np.ndarray:
    """Per-visible-splat 2D gradients g2 [V, NG] float32 from the per-pixel loss gradients
    d_color / d_normal [H, W, 3], d_alpha / d_depth / d_median [H, W].

    Deterministic and bitwise the same for any thread count: every splat sums its per-tile
    gradients in ascending tile order. One worker runs the serial version."""
    if n_workers <= 1:
        return _raster_backward_serial(fo, box, tile_offsets, inst, n_vis, width, height, tile,
                                       T_out, n_contrib, med_idx, d_color, d_alpha, d_depth,
                                       d_normal, d_median)
    return _raster_backward_tiles(fo, box, tile_offsets, inst, row_start, pos, n_vis, width,
                                  height, tile, T_out, n_contrib, med_idx, d_color, d_alpha,
                                  d_depth, d_normal, d_median, n_workers)
