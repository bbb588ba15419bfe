"""One whole env frame in one thread, and many frames (cameras, scenes) in one kernel call.

The env path renders tiny images (128x72): per frame the work is small, so thread fork/join
between the phases (cull, project, sort/bin, composite) and the Python glue cost as much as
the maths. `render_frame` runs every phase of one camera serially in one numba call;
`render_frames` runs many cameras in parallel, one frame per worker at a time, so N envs pay
the call and scheduling overhead once.

Outputs are what an env reads: rgb over the background, alpha and expected depth
(depth_acc / alpha, 0 where empty). With `blend_cap = 0` they equal `StaticScene.render`
bit for bit (same arithmetic, same order; tests/test_splats_frame.py): the composite blends
each splat row in SIMD windows of 8 pixels without branches, with `_expf.expf_glibc`, a
vectorisable replay of glibc's expf that gives the same floats as `np.exp`; `blend_cap > 0` stops each pixel
after that many blended splats (an approximation: the remaining transmittance shows the
background).

Scenes are packed (`pack_scenes`): concatenated Gaussian arrays and culling cells whose
`cell_start` holds global row numbers, so a camera of scene s culls cells
cell_lo[s]:cell_lo[s+1] and projects global rows.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ._bits import popc64
from ._expf import expf_glibc
from ._geom import jac_limits
from ._sched import fetch_add, new_counter
from .binning import _sort_and_bin_serial
from .composite import A_MAX, A_MIN, ALL_BITS, HALF, MAX_TILE, ONE, S_MAX, T_MIN, ZERO
from ._project_planes import NQ, PCH, lane_buffers, sh_layout
from .env_scene_kernels import cull_cells, static_chunk
from .project import F_A, F_B, F_BL, F_C, F_CUT, F_G, F_O, F_R, F_X, F_Y, F_Z, view_parts

F32 = np.float32
# stats columns written per frame
S_IN_VIEW, S_INSTANCES, S_BLENDS, S_COVERED = range(4)
NS = 4


@njit(cache=True)
def project_serial(sel, n, means, cov, opacity, cut, normal_w, rgb, sh, deg, view, campos, cam,
                   width, height, near, far, cov_alpha, fo, box, radii):
    """project_static in one thread, without normals (env frames do not composite them):
    rows r < n of fo [R, NF], box [R, 4], radii [R]."""
    W, tw = view_parts(view)
    lims = jac_limits(cam[0], cam[1], cam[2], cam[3], width, height)
    shf, ks, k3 = sh_layout(sh, deg)
    buf, shp = lane_buffers(NQ)
    for r0 in range(0, n, PCH):
        static_chunk(r0, min(PCH, n - r0), sel, means, cov, opacity, cut, normal_w, rgb, shf, ks,
                     k3, deg, W, tw, campos, cam, lims, width, height, near, far, cov_alpha, fo,
                     box, radii, False, buf, shp)


@njit(cache=True)
def _gather_tile(fo, box, inst, s, n, g, gb):
    """Tile's splats inst[s:s+n] -> contiguous g [11, n] (x y a b c o cut r g b z rows) and
    boxes gb [n, 4]: one cache line walk per column in the blend loop."""
    for k in range(n):
        v = inst[s + k]
        g[0, k] = fo[v, F_X]
        g[1, k] = fo[v, F_Y]
        g[2, k] = fo[v, F_A]
        g[3, k] = fo[v, F_B]
        g[4, k] = fo[v, F_C]
        g[5, k] = fo[v, F_O]
        g[6, k] = min(fo[v, F_CUT], S_MAX)
        g[7, k] = fo[v, F_R]
        g[8, k] = fo[v, F_G]
        g[9, k] = fo[v, F_BL]
        g[10, k] = fo[v, F_Z]
        for q in range(4):
            gb[k, q] = box[v, q]


XLANES = 8  # pixels per vector window of a splat row
XROW = MAX_TILE + XLANES  # row stride of the tile's pixel planes (tiles of at most MAX_TILE px)
XNPIX = MAX_TILE * XROW  # floats per plane
X1, X2, X3, X4, X5, X6 = (np.uint64(i * XNPIX) for i in range(1, 7))  # planes of pix after T:
# r g b z, blend count (float32: exact below 2^24), weight of the last window
U64 = np.uint64


@njit(cache=True, inline="always")
def _xwindow(pix, pb, px0, livebits, last, mx, dy, ccdy2, ca, cb, o, ct, c0, c1, c2,
             c3, cap, t_stop):
    """Blend one splat into XLANES pixels of a row, lane j = pixel px0 + j at plane index
    pb + j, with the arithmetic and order of `StaticScene.render` per pixel but no branch
    (so it vectorises; expf_glibc equals np.exp bit for bit): lanes that are stopped (bit j
    of livebits clear), beyond the box (j > last), outside the cut-off, below A_MIN or
    reaching T_MIN take no weight. pix[p + X6] gets lane j's weight (one buffer for all
    the state at fixed offsets: the vectoriser needs no alias checks). Returns bits:
    bit j where lane j blended, bit 32 + j where it stopped."""
    bits = U64(0)
    for j in range(XLANES):
        p = pb + U64(j)
        dx = (F32(px0 + j) + HALF) - mx
        sv = HALF * (ca * dx * dx + ccdy2) + cb * dx * dy
        cand = ((livebits >> U64(j)) & U64(1) == U64(1)) & (U64(j) <= last) & (sv >= ZERO) & (
            sv <= ct)
        e = expf_glibc(-sv)  # garbage (even inf / nan) outside [0, ct]: masked below
        oe = o * e
        al = A_MAX if A_MAX < oe else oe  # min(A_MAX, o e) as composite.py
        ok = cand & (al >= A_MIN)
        Tp = pix[p]
        Tn = Tp * (ONE - al)
        dead = Tn < T_MIN
        blend = ok & (Tn >= T_MIN)
        w = al * Tp if blend else ZERO
        pix[p + X1] += w * c0
        pix[p + X2] += w * c1
        pix[p + X3] += w * c2
        pix[p + X4] += w * c3
        pix[p] = Tn if blend else Tp
        cn = pix[p + X5] + (ONE if blend else ZERO)
        pix[p + X5] = cn
        stop = (ok & dead) | (blend & ((cn >= cap) | (Tn < t_stop)))
        pix[p + X6] = w
        bits |= (U64(blend) << U64(j)) | (U64(stop) << U64(32 + j))
    return bits


@njit(cache=True, error_model="numpy")
def composite_tile(g, gb, inst, s, n, x0, y0, x1, y1, blend_cap, t_stop, pix, rdone, color,
                   alpha, depth, blends_px, contrib):
    """Blend one tile's depth-sorted splats (splat-major, per-pixel early termination).

    pix [7 XNPIX] (planes T r g b z count weight, rows of XROW) and
    rdone [64] (bit px - x0: stopped) are scratch; writes color [H, W, 3] (premultiplied),
    alpha [H, W], depth [H, W] (accumulated z) and blends_px [H, W] (blended splats per
    pixel). contrib [R] (size 0: skipped) gains each splat's blend weights alpha * T at its
    row inst[s+k]. t_stop > 0 (approximate) also stops a pixel once its transmittance falls
    below t_stop (colour error <= t_stop). Each splat row is blended in SIMD windows of
    XLANES pixels (`_xwindow`: the same floats as the per-pixel loop of `composite.py`).
    Returns the number of blends."""
    tw = x1 - x0
    th = y1 - y0
    for i in range(th * XROW):
        p = U64(i)
        pix[p] = ONE
        pix[p + X1] = ZERO
        pix[p + X2] = ZERO
        pix[p + X3] = ZERO
        pix[p + X4] = ZERO
        pix[p + X5] = ZERO
    for r in range(th):
        rdone[r] = 0
    cap = F32(blend_cap if blend_cap > 0 else 1 << 30)
    want_contrib = contrib.shape[0] > 0
    n_live = tw * th
    blends = 0
    for k in range(n):
        bx0 = max(gb[k, 0], x0)
        bx1 = min(gb[k, 2] + 1, x1)
        by0 = max(gb[k, 1], y0)
        by1 = min(gb[k, 3] + 1, y1)
        if bx1 <= bx0:
            continue
        mx, my, ca, cb, cc = g[0, k], g[1, k], g[2, k], g[3, k], g[4, k]
        o, ct = g[5, k], g[6, k]
        c0, c1, c2, c3 = g[7, k], g[8, k], g[9, k], g[10, k]
        wsum = ZERO
        lo = bx0 - x0
        hi = bx1 - 1 - x0
        span = (ALL_BITS >> U64(63 - (hi - lo))) << U64(lo)
        for py in range(by0, by1):
            ry = py - y0
            if rdone[ry] & span == span:
                continue  # every pixel of this row's span has stopped
            dy = (F32(py) + HALF) - my
            ccdy2 = cc * dy * dy
            rb = ry * XROW
            for c in range(lo, hi + 1, XLANES):
                bits = _xwindow(pix, U64(rb + c), x0 + c, ~rdone[ry] >> U64(c),
                                U64(hi - c), mx, dy, ccdy2, ca, cb, o, ct, c0, c1, c2, c3, cap,
                                t_stop)
                blends += np.int64(popc64(bits & U64(0xFFFFFFFF)))
                stop = (bits >> U64(32)) << U64(c)
                rdone[ry] |= stop
                n_live -= np.int64(popc64(stop))
                if want_contrib:
                    for j in range(XLANES):
                        wsum += pix[U64(rb + c + j) + X6]
        if want_contrib and wsum > ZERO:
            contrib[inst[s + k]] += wsum
        if n_live == 0:
            break
    for py in range(y0, y1):
        rb = (py - y0) * XROW - x0
        for px in range(x0, x1):
            p = U64(rb + px)
            color[py, px, 0] = pix[p + X1]
            color[py, px, 1] = pix[p + X2]
            color[py, px, 2] = pix[p + X3]
            alpha[py, px] = ONE - pix[p]
            depth[py, px] = pix[p + X4]
            blends_px[py, px] = np.int32(pix[p + X5])
    return blends


@njit(cache=True)
def composite_frame(fo, box, offsets, inst, width, height, tile, blend_cap, t_stop, color, alpha,
                    depth, blends_px, contrib):
    """Composite every tile of one frame in this thread; returns the number of blends."""
    tiles_x = (width + tile - 1) // tile
    n_tiles = tiles_x * ((height + tile - 1) // tile)
    cap = 1
    for t in range(n_tiles):
        cap = max(cap, offsets[t + 1] - offsets[t])
    g = np.empty((11, cap), np.float32)
    gb = np.empty((cap, 4), np.int32)
    pix = np.empty(7 * XNPIX, np.float32)
    rdone = np.empty(64, np.uint64)
    blends = 0
    for t in range(n_tiles):
        s = offsets[t]
        n = offsets[t + 1] - s
        x0 = (t % tiles_x) * tile
        y0 = (t // tiles_x) * tile
        x1, y1 = min(x0 + tile, width), min(y0 + tile, height)
        _gather_tile(fo, box, inst, s, n, g, gb)
        blends += composite_tile(g, gb, inst, s, n, x0, y0, x1, y1, blend_cap, t_stop, pix, rdone,
                                 color, alpha, depth, blends_px, contrib)
    return blends


@njit(cache=True)
def finish_env(color, alpha, depth_acc, bg, rgb, depth):
    """rgb = color + (1 - alpha) bg; depth = depth_acc / alpha (0 where alpha == 0)."""
    H, W = alpha.shape
    for i in range(H):
        for j in range(W):
            a = alpha[i, j]
            for c in range(3):
                rgb[i, j, c] = color[i, j, c] + (ONE - a) * bg[c]
            depth[i, j] = depth_acc[i, j] / max(a, F32(1e-6)) if a > ZERO else ZERO


@njit(cache=True)
def render_frame(c0, c1, centers, r_means, rho, cell_start, means, cov, opacity, cut, normal_w,
                 rgb_dc, sh, deg, view, campos, cam, width, height, tile, near, far, cov_alpha,
                 blend_cap, t_stop, bg, sel, fo, box, radii, color, out_rgb, out_alpha, out_depth,
                 blends_px, contrib, stats):
    """Every phase of one camera in this thread: cull cells c0:c1, project, sort/bin,
    composite, finish. Scratch: sel [G], fo [G, NF], box [G, 4], radii [G], color [H, W, 3];
    outputs out_rgb [H, W, 3], out_alpha / out_depth / blends_px [H, W]; stats [NS]."""
    n = cull_cells(centers[c0:c1], r_means[c0:c1], rho[c0:c1], cell_start[c0:c1 + 1], view,
                   cam, width, height, near, far, sel)
    project_serial(sel, n, means, cov, opacity, cut, normal_w, rgb_dc, sh, deg, view, campos,
                   cam, width, height, near, far, cov_alpha, fo, box, radii)
    tiles_x = (width + tile - 1) // tile
    n_tiles = tiles_x * ((height + tile - 1) // tile)
    offsets, inst, _, _ = _sort_and_bin_serial(fo, box, n, tile, tiles_x, n_tiles, False)
    blends = composite_frame(fo, box, offsets, inst, width, height, tile, blend_cap, t_stop, color,
                             out_alpha, out_depth, blends_px, contrib)
    finish_env(color, out_alpha, out_depth, bg, out_rgb, out_depth)
    in_view = 0
    for r in range(n):
        if box[r, 2] >= box[r, 0]:
            in_view += 1
    covered = 0
    for i in range(height):
        for j in range(width):
            if blends_px[i, j] > 0:
                covered += 1
    stats[S_IN_VIEW] = in_view
    stats[S_INSTANCES] = offsets[n_tiles]
    stats[S_BLENDS] = blends
    stats[S_COVERED] = covered
    return n


@njit(parallel=True, cache=True)
def render_frames(scene_of, cell_lo, centers, r_means, rho, cell_start, means, cov, opacity, cut,
                  normal_w, rgb_dc, sh, deg, views, campos, cams, width, height, tile, near, far,
                  cov_alpha, blend_cap, t_stop, bg, sel, fo, box, radii, color, out_rgb, out_alpha,
                  out_depth, blends_px, stats, n_workers):
    """Render cameras i < len(scene_of) (camera i sees packed scene scene_of[i]: cells
    cell_lo[s]:cell_lo[s+1]); n_workers draw whole frames from a shared counter. Scratch
    is per worker: sel / radii [n_workers, G], fo [n_workers, G, NF], box [n_workers, G, 4],
    color [n_workers, H, W, 3]; outputs are [N, H, W(, 3)], stats [N, NS]."""
    n_cams = scene_of.shape[0]
    nxt = new_counter()
    no_contrib = np.zeros(0, np.float64)
    for h in prange(n_workers):
        while True:
            i = fetch_add(nxt, 1)
            if i >= n_cams:
                break
            s = scene_of[i]
            render_frame(cell_lo[s], cell_lo[s + 1], centers, r_means, rho, cell_start, means,
                         cov, opacity, cut, normal_w, rgb_dc, sh, deg, views[i], campos[i],
                         cams[i], width, height, tile, near, far, cov_alpha, blend_cap, t_stop, bg,
                         sel[h], fo[h], box[h], radii[h], color[h], out_rgb[i], out_alpha[i],
                         out_depth[i], blends_px[i], no_contrib, stats[i])
