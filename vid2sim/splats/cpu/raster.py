"""Per-tile compositing (forward) and its back-to-front gradient pass (backward).

Forward reads the binned splats and writes the raw images plus, per pixel, the final
transmittance, the number of splats walked (n_contrib) and the median splat's list
position, which backward uses to traverse back to front as the 3DGS rasteriser does.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .preprocess import (F_A, F_B, F_BL, F_C, F_CUT, F_G, F_NX, F_NY, F_NZ, F_O, F_R, F_X,
                         F_Y, F_Z, G_A, G_AX, G_AY, G_B, G_BL, G_C, G_G, G_MX, G_MY, G_NX,
                         G_NY, G_NZ, G_O, G_R, G_Z, NG)

F32 = np.float32
S_MAX = F32(4.5)
A_MIN = F32(1.0 / 255.0)
A_MAX = F32(0.99)
T_MIN = F32(1e-4)
T_MED = F32(0.5)
ONE = F32(1.0)
HALF = F32(0.5)
ZERO = F32(0.0)


@njit(cache=True)
def gather(fo, inst, s, n, g):
    """Copy the n splats of a tile (inst[s:s+n]) into the packed local array g [n, 14]."""
    for k in range(n):
        v = inst[s + k]
        for q in range(14):
            g[k, q] = fo[v, q]


@njit(cache=True)
def _tile_forward(g, n, x0, y0, x1, y1, color, alpha, depth, normal, median, T_out,
                  n_contrib, med_idx):
    for py in range(y0, y1):
        fy = F32(py) + HALF
        for px in range(x0, x1):
            fx = F32(px) + HALF
            T = ONE
            cr = ZERO
            cg = ZERO
            cb = ZERO
            dd = ZERO
            nx = ZERO
            ny = ZERO
            nz = ZERO
            med = -1
            last = 0
            for k in range(n):
                dx = fx - g[k, F_X]
                dy = fy - g[k, F_Y]
                s = HALF * (g[k, F_A] * dx * dx + g[k, F_C] * dy * dy) + g[k, F_B] * dx * dy
                if s < ZERO or s > g[k, F_CUT]:
                    continue
                if s > S_MAX:
                    continue
                al = min(A_MAX, g[k, F_O] * np.exp(-s))
                if al < A_MIN:
                    continue
                Tn = T * (ONE - al)
                if Tn < T_MIN:
                    break
                w = al * T
                cr += w * g[k, F_R]
                cg += w * g[k, F_G]
                cb += w * g[k, F_BL]
                dd += w * g[k, F_Z]
                nx += w * g[k, F_NX]
                ny += w * g[k, F_NY]
                nz += w * g[k, F_NZ]
                if med < 0 and Tn <= T_MED:
                    med = k
                T = Tn
                last = k + 1
            color[py, px, 0] = cr
            color[py, px, 1] = cg
            color[py, px, 2] = cb
            alpha[py, px] = ONE - T
            depth[py, px] = dd
            normal[py, px, 0] = nx
            normal[py, px, 1] = ny
            normal[py, px, 2] = nz
            median[py, px] = g[med, F_Z] if med >= 0 else ZERO
            T_out[py, px] = T
            n_contrib[py, px] = last
            med_idx[py, px] = med


@njit(parallel=True, cache=True)
def raster_forward(fo, tile_offsets, inst, width, height, tile, color, alpha, depth, normal,
                   median, T_out, n_contrib, med_idx):
    """Composite every tile (parallel over tiles); outputs are [H, W(, 3)] arrays."""
    tiles_x = (width + tile - 1) // tile
    n_tiles = tiles_x * ((height + tile - 1) // tile)
    for t in prange(n_tiles):
        s = tile_offsets[t]
        n = tile_offsets[t + 1] - s
        x0 = (t % tiles_x) * tile
        y0 = (t // tiles_x) * tile
        x1 = min(x0 + tile, width)
        y1 = min(y0 + tile, height)
        g = np.empty((max(n, 1), 14), np.float32)
        gather(fo, inst, s, n, g)
        _tile_forward(g, n, x0, y0, x1, y1, color, alpha, depth, normal, median, T_out,
                      n_contrib, med_idx)


@njit(cache=True)
def _tile_backward(g, vids, n, x0, y0, x1, y1, T_out, n_contrib, med_idx, d_color, d_alpha,
                   d_depth, d_normal, d_median, acc):
    for py in range(y0, y1):
        fy = F32(py) + HALF
        for px in range(x0, x1):
            fx = F32(px) + HALF
            last = n_contrib[py, px]
            med = med_idx[py, px]
            if med >= 0:
                acc[vids[med], G_Z] += d_median[py, px]
            if last == 0:
                continue
            T_fin = T_out[py, px]
            T = T_fin
            gr, gg, gb = d_color[py, px, 0], d_color[py, px, 1], d_color[py, px, 2]
            gd = d_depth[py, px]
            gnx, gny, gnz = d_normal[py, px, 0], d_normal[py, px, 1], d_normal[py, px, 2]
            gAT = d_alpha[py, px] * T_fin
            sr = ZERO
            sg = ZERO
            sb = ZERO
            sd = ZERO
            snx = ZERO
            sny = ZERO
            snz = ZERO
            for k in range(last - 1, -1, -1):
                dx = fx - g[k, F_X]
                dy = fy - g[k, F_Y]
                ca, cb_, cc = g[k, F_A], g[k, F_B], g[k, F_C]
                s = HALF * (ca * dx * dx + cc * dy * dy) + cb_ * dx * dy
                if s < ZERO or s > g[k, F_CUT]:
                    continue
                if s > S_MAX:
                    continue
                o = g[k, F_O]
                G = np.exp(-s)
                raw = o * G
                al = min(A_MAX, raw)
                if al < A_MIN:
                    continue
                om = ONE - al
                T = T / om
                w = al * T
                a = acc[vids[k]]
                r, gc_, bc = g[k, F_R], g[k, F_G], g[k, F_BL]
                zk = g[k, F_Z]
                nxk, nyk, nzk = g[k, F_NX], g[k, F_NY], g[k, F_NZ]
                a[G_R] += w * gr
                a[G_G] += w * gg
                a[G_BL] += w * gb
                a[G_Z] += w * gd
                a[G_NX] += w * gnx
                a[G_NY] += w * gny
                a[G_NZ] += w * gnz
                dal = T * ((r - sr) * gr + (gc_ - sg) * gg + (bc - sb) * gb + (zk - sd) * gd
                           + (nxk - snx) * gnx + (nyk - sny) * gny + (nzk - snz) * gnz)
                dal += gAT / om
                sr = al * r + om * sr
                sg = al * gc_ + om * sg
                sb = al * bc + om * sb
                sd = al * zk + om * sd
                snx = al * nxk + om * snx
                sny = al * nyk + om * sny
                snz = al * nzk + om * snz
                if raw <= A_MAX:
                    a[G_O] += G * dal
                    ds = -al * dal
                    gmx = -ds * (ca * dx + cb_ * dy)
                    gmy = -ds * (cc * dy + cb_ * dx)
                    a[G_MX] += gmx
                    a[G_MY] += gmy
                    a[G_AX] += abs(gmx)
                    a[G_AY] += abs(gmy)
                    a[G_A] += HALF * ds * dx * dx
                    a[G_B] += ds * dx * dy
                    a[G_C] += HALF * ds * dy * dy


@njit(parallel=True, cache=True)
def raster_backward(fo, tile_offsets, inst, n_vis, width, height, tile, T_out, n_contrib,
                    med_idx, d_color, d_alpha, d_depth, d_normal, d_median, n_chunks):
    """Per-visible-splat 2D gradients g2 [V, NG] float32.

    Race-free: tiles are dealt round-robin to n_chunks workers (one per thread), each
    accumulating into its own [V, NG] buffer; buffers are summed at the end.
    """
    tiles_x = (width + tile - 1) // tile
    n_tiles = tiles_x * ((height + tile - 1) // tile)
    bufs = np.zeros((n_chunks, n_vis, NG), np.float32)
    for h in prange(n_chunks):
        for t in range(h, n_tiles, n_chunks):
            s = tile_offsets[t]
            n = tile_offsets[t + 1] - s
            if n == 0:
                continue
            x0 = (t % tiles_x) * tile
            y0 = (t // tiles_x) * tile
            x1 = min(x0 + tile, width)
            y1 = min(y0 + tile, height)
            g = np.empty((n, 14), np.float32)
            gather(fo, inst, s, n, g)
            _tile_backward(g, inst[s:s + n], n, x0, y0, x1, y1, T_out, n_contrib, med_idx,
                           d_color, d_alpha, d_depth, d_normal, d_median, bufs[h])
    out = np.empty((n_vis, NG), np.float32)
    for v in prange(n_vis):
        for q in range(NG):
            acc = F32(0.0)
            for h in range(n_chunks):
                acc += bufs[h, v, q]
            out[v, q] = acc
    return out
