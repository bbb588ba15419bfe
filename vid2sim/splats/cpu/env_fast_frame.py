"""Approximate env frames at RL rates: one 128x72 frame in ~2 ms of one core.

NOT exact (the exact env path is `env_frame.py`); what is traded, each measured as PSNR/SSIM
against the exact render by benchmarks/env_render.py:

- colour: one RGB per splat, no view-dependent SH (`env_simready.sim_ready` bakes each splat's
  blend-weighted mean colour over robot views into the DC term);
- opaque early stop: a pixel stops once its transmittance T falls below t_stop, and its
  colour is renormalised acc / (1 - T) with alpha 1 (the remaining splats are assumed to look
  like the ones blended), which keeps the error far below T x colour; optionally every pixel
  with T < t_fill (alpha above 1 - t_fill) is renormalised too (fills the pinholes pruning
  leaves in surfaces);
- float32 projection from one packed 64-byte record per splat; depth sort on the top 22
  bits of the float depth (ties below 2^-13 relative depth keep cell order);
- alpha = o exp(-s) inside the ellipse s <= ct (not clamped below 1/255), exp(-s) from a
  polynomial (`exp_neg`, relative error < 1.4e-5).

The composite is SIMD: per tile the pixel state is 5 contiguous float32 planes (T r g b z)
and each splat row is blended in windows of LANES pixels from its clipped box start, with no
branch per pixel (pixels outside the ellipse or already stopped get weight 0), which LLVM
vectorises (8 float32 lanes: one AVX2 register).

Per frame in one thread: cull culling cells (bounding spheres, `env_scene_kernels.sphere_outside`)
and project only the splats of the cells that survive (and that the frame's cell mask keeps:
`env_view_sets.py`), straight into a compact list; radix
sort by depth; bin into small tiles; composite tile by tile front to back (per-pixel and
per-tile early stop); finish over the background. `render_fast_frames` runs N cameras
(possibly different packed scenes) over a shared counter, one frame per worker at a time.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ._bits import popc64, prefetch_row
from ._geom import LOWPASS, jac_limits
from ._sched import fetch_add, new_counter
from .env_frame import finish_env
from .env_scene_kernels import frustum_planes, sphere_outside

F32 = np.float32
U64 = np.uint64
# packed splat fields, planes [NP, G] float32 (model data, view independent)
P_X, P_Y, P_Z, P_S00, P_S01, P_S02, P_S11, P_S12, P_S22, P_O, P_R, P_G, P_B, P_CUT = range(14)
NP = 16
# projected splat record [R, NQ] float32 (one camera)
Q_X, Q_Y, Q_A, Q_B, Q_C, Q_O, Q_CUT, Q_R, Q_G, Q_BL, Q_Z, Q_DET = range(12)
NQ = 12
A_MAX = F32(0.99)
ALL_BITS = np.uint64(0xFFFFFFFFFFFFFFFF)
S_MAX = 4.5  # the exact renderer's cut-off on s (3 sigma)
PF_AHEAD = 16  # the depth-order gather prefetches the record this many rows ahead
KEY_SHIFT = np.uint32(10)  # depth key: float bits >> 10 (22 bits, two 11-bit radix passes)
# stats columns per frame: splats in view, tile instances, blends, covered pixels
NS = 4


@njit(cache=True)
def pack_splats(means, cov, opacity, rgb):
    """Packed fields as planes [NP, G] float32 (plane P_X holds every splat's x: the
    projection loads them as vectors) from means [G, 3], world covariances [G, 6] (xx xy xz
    yy yz zz), opacities [G] and colours [G, 3]; P_CUT = min(ln(255 o), S_MAX): the largest
    Gaussian power s = d^T Sigma^-1 d / 2 at which o exp(-s) still reaches 1/255, within the
    exact renderer's 3-sigma cut-off."""
    G = means.shape[0]
    pk = np.zeros((NP, G), np.float32)
    for i in range(G):
        for q in range(3):
            pk[P_X + q, i] = means[i, q]
            pk[P_R + q, i] = rgb[i, q]
        for q in range(6):
            pk[P_S00 + q, i] = cov[i, q]
        o = opacity[i]
        pk[P_O, i] = o
        pk[P_CUT, i] = min(math.log(max(o * 255.0, 1.0)), S_MAX)
    return pk


@njit(cache=True, inline="always")
def _ceil_pos(a, n):
    """max(ceil(a), 0) for a clamped to [0, n], without a libm call."""
    a = min(max(a, F32(0.0)), F32(n))
    t = np.int64(a)
    return t + np.int64(F32(t) < a)


@njit(cache=True, inline="always")
def _floor_gt(b, n):
    """floor(b) for b clamped to [-1, n] (any negative value when b < 0), without a libm
    call."""
    b = min(max(b, F32(-1.0)), F32(n))
    return np.int64(b + F32(1.0)) - 1


PCH = 64  # splats per projection chunk
# planes of the chunk buffer: inputs (packed record fields) then outputs
B_X, B_Y, B_Z, B_S00, B_S01, B_S02, B_S11, B_S12, B_S22, B_CUT = range(10)
B_PX, B_PY, B_A, B_B, B_C, B_TZ, B_IDET, B_J0, B_J1, B_I0, B_I1, B_OK = range(10, 22)
NB = 22
_IN = (P_X, P_Y, P_Z, P_S00, P_S01, P_S02, P_S11, P_S12, P_S22, P_CUT)  # record field of B_k


@njit(cache=True, fastmath=True, error_model="numpy")
def _project_chunk(buf, m, W, tw, fx, fy, cx, cy, lims, width, height, near, far, cov_alpha):
    """Project the m <= PCH splats in the input planes of buf [NB PCH] into its output
    planes, with no branch (so the loop vectorises): B_OK is 1 where the splat reaches a
    pixel, else 0 (the other outputs are then meaningless). float32 throughout."""
    lxp, lxn, lyp, lyn = lims
    wf, hf = F32(width), F32(height)
    lim_cov = cov_alpha * hf * wf
    for jj in range(m):
        j = U64(jj)
        mx, my, mz = buf[j + U64(B_X * PCH)], buf[j + U64(B_Y * PCH)], buf[j + U64(B_Z * PCH)]
        ct = buf[j + U64(B_CUT * PCH)]
        tz = W[6] * mx + W[7] * my + W[8] * mz + tw[2]
        ok = (tz >= near) & (tz <= far) & (ct > F32(0.0))
        tz1 = tz if ok else F32(1.0)
        tx = W[0] * mx + W[1] * my + W[2] * mz + tw[0]
        ty = W[3] * mx + W[4] * my + W[5] * mz + tw[1]
        iz = F32(1.0) / tz1
        rx = min(max(tx * iz, -lxn), lxp)
        ry = min(max(ty * iz, -lyn), lyp)
        j00 = fx * iz
        j11 = fy * iz
        j02 = -fx * rx * iz
        j12 = -fy * ry * iz
        s00, s01, s02 = (buf[j + U64(B_S00 * PCH)], buf[j + U64(B_S01 * PCH)],
                         buf[j + U64(B_S02 * PCH)])
        s11, s12, s22 = (buf[j + U64(B_S11 * PCH)], buf[j + U64(B_S12 * PCH)],
                         buf[j + U64(B_S22 * PCH)])
        u0, u1, u2 = j00 * W[0] + j02 * W[6], j00 * W[1] + j02 * W[7], j00 * W[2] + j02 * W[8]
        v0, v1, v2 = j11 * W[3] + j12 * W[6], j11 * W[4] + j12 * W[7], j11 * W[5] + j12 * W[8]
        su0 = s00 * u0 + s01 * u1 + s02 * u2
        su1 = s01 * u0 + s11 * u1 + s12 * u2
        su2 = s02 * u0 + s12 * u1 + s22 * u2
        A = u0 * su0 + u1 * su1 + u2 * su2 + F32(LOWPASS)
        B = v0 * su0 + v1 * su1 + v2 * su2
        C = (v0 * (s00 * v0 + s01 * v1 + s02 * v2) + v1 * (s01 * v0 + s11 * v1 + s12 * v2)
             + v2 * (s02 * v0 + s12 * v1 + s22 * v2) + F32(LOWPASS))
        det = A * C - B * B
        ok = ok & (det > F32(0.0)) & (A > F32(0.0)) & (C > F32(0.0))
        ok = ok & ((cov_alpha <= F32(0.0)) | (max(abs(A), abs(B), abs(C)) <= lim_cov))
        px = fx * tx * iz + cx
        py = fy * ty * iz + cy
        two_ct = F32(2.0) * ct
        ex = math.sqrt(max(two_ct * A, F32(0.0)))
        ey = math.sqrt(max(two_ct * C, F32(0.0)))
        j0 = _ceil_pos(px - ex - F32(0.5), width)
        j1 = min(_floor_gt(px + ex - F32(0.5), width), width - 1)
        i0 = _ceil_pos(py - ey - F32(0.5), height)
        i1 = min(_floor_gt(py + ey - F32(0.5), height), height - 1)
        ok = ok & (j0 <= j1) & (i0 <= i1)
        idet = F32(1.0) / (det if ok else F32(1.0))
        buf[j + U64(B_PX * PCH)] = px
        buf[j + U64(B_PY * PCH)] = py
        buf[j + U64(B_A * PCH)] = C * idet
        buf[j + U64(B_B * PCH)] = -B * idet
        buf[j + U64(B_C * PCH)] = A * idet
        buf[j + U64(B_TZ * PCH)] = tz
        buf[j + U64(B_IDET * PCH)] = idet
        buf[j + U64(B_J0 * PCH)] = F32(j0)
        buf[j + U64(B_J1 * PCH)] = F32(j1)
        buf[j + U64(B_I0 * PCH)] = F32(i0)
        buf[j + U64(B_I1 * PCH)] = F32(i1)
        buf[j + U64(B_OK * PCH)] = F32(1.0) if ok else F32(0.0)


@njit(cache=True)
def cull_project(c0, c1, centers, r_means, rho, cell_start, pl, cell_mask, view, cam, width,
                 height, near, far, cov_alpha, q, box):
    """Project the splats of cells c0:c1 that survive the frustum test into compact rows of
    q [R, NQ] / box [R, 4] (only splats that reach a pixel); returns (rows, splats tested).
    pl [NP, G]: the packed records as planes (`FastBatch.planes`); cell_mask [C] uint64: the
    rows of each cell to consider (bit j: row cell_start[c] + j, for cells of at most 64 rows;
    ALL_BITS: every row of a cell of any size; 0: skip the cell). The kept rows of a cell are
    gathered in chunks of PCH splats, projected by the vectorised `_project_chunk`, then
    compacted."""
    W, tw, planes, grow = frustum_planes(view, cam, width, height)
    Wf = (F32(W[0]), F32(W[1]), F32(W[2]), F32(W[3]), F32(W[4]), F32(W[5]), F32(W[6]),
          F32(W[7]), F32(W[8]))
    twf = (F32(tw[0]), F32(tw[1]), F32(tw[2]))
    fx, fy, cx, cy = F32(cam[0]), F32(cam[1]), F32(cam[2]), F32(cam[3])
    lp = jac_limits(cam[0], cam[1], cam[2], cam[3], width, height)
    lims = (F32(lp[0]), F32(lp[1]), F32(lp[2]), F32(lp[3]))
    nearf, farf, cova = F32(near), F32(far), F32(cov_alpha)
    buf = np.empty(NB * PCH, np.float32)
    rows = np.empty(PCH, np.int64)  # packed row of each chunk slot
    n = 0
    tested = 0
    for c in range(c0, c1):
        mw = cell_mask[c]
        if mw == U64(0) or sphere_outside(centers[c, 0], centers[c, 1], centers[c, 2],
                                          r_means[c], rho[c], W, tw, planes, grow, near, far):
            continue
        for s0 in range(cell_start[c], cell_start[c + 1], PCH):
            m = _chunk_rows(mw, s0, min(PCH, cell_start[c + 1] - s0), rows)
            for k in range(10):
                f = _IN[k]
                for jj in range(m):
                    buf[U64(k * PCH + jj)] = pl[f, U64(rows[jj])]
            _project_chunk(buf, m, Wf, twf, fx, fy, cx, cy, lims, width, height, nearf, farf,
                           cova)
            tested += m
            for jj in range(m):
                j = U64(jj)
                if buf[j + U64(B_OK * PCH)] == F32(0.0):
                    continue
                i = U64(rows[jj])
                r = U64(n)
                q[r, Q_X] = buf[j + U64(B_PX * PCH)]
                q[r, Q_Y] = buf[j + U64(B_PY * PCH)]
                q[r, Q_A] = buf[j + U64(B_A * PCH)]
                q[r, Q_B] = buf[j + U64(B_B * PCH)]
                q[r, Q_C] = buf[j + U64(B_C * PCH)]
                q[r, Q_O] = pl[P_O, i]
                q[r, Q_CUT] = buf[j + U64(B_CUT * PCH)]
                q[r, Q_R] = pl[P_R, i]
                q[r, Q_G] = pl[P_G, i]
                q[r, Q_BL] = pl[P_B, i]
                q[r, Q_Z] = buf[j + U64(B_TZ * PCH)]
                q[r, Q_DET] = buf[j + U64(B_IDET * PCH)]
                box[r, 0] = np.int32(buf[j + U64(B_J0 * PCH)])
                box[r, 1] = np.int32(buf[j + U64(B_I0 * PCH)])
                box[r, 2] = np.int32(buf[j + U64(B_J1 * PCH)])
                box[r, 3] = np.int32(buf[j + U64(B_I1 * PCH)])
                n += 1
    return n, tested


@njit(cache=True, inline="always")
def _chunk_rows(mask, s0, m, rows):
    """rows[:k] = the rows s0 + j (j < m) that `mask` keeps (every one when mask is ALL_BITS,
    else those whose bit j is set); returns k."""
    if mask == ALL_BITS:
        for j in range(m):
            rows[j] = s0 + j
        return m
    k = 0
    for j in range(m):
        if (mask >> U64(j)) & U64(1):
            rows[k] = s0 + j
            k += 1
    return k


@njit(cache=True)
def depth_order(q, n, keys, k2, rows, r2):
    """Row order [n] front to back: two 11-bit LSD radix passes on the depth's float bits
    >> KEY_SHIFT (depths are positive, so the bits are monotone). Returns the sorted rows."""
    zb = q[:n, Q_Z].copy().view(np.uint32)
    for i in range(n):
        keys[i] = zb[i] >> KEY_SHIFT
        rows[i] = i
    count = np.empty(2049, np.int64)
    src_k, src_r, dst_k, dst_r = keys, rows, k2, r2
    for shift in (0, 11):
        sh = np.uint32(shift)
        count[:] = 0
        for i in range(n):
            count[((src_k[i] >> sh) & np.uint32(2047)) + 1] += 1
        for d in range(2048):
            count[d + 1] += count[d]
        for i in range(n):
            d = (src_k[i] >> sh) & np.uint32(2047)
            j = count[d]
            dst_k[j] = src_k[i]
            dst_r[j] = src_r[i]
            count[d] = j + 1
        src_k, dst_k = dst_k, src_k
        src_r, dst_r = dst_r, src_r
    return src_r


@njit(cache=True)
def sort_bin(q, box, n, order, qs, bs, shift, tiles_x, n_tiles, offsets, inst):
    """Copy rows into depth order (qs [n, NQ], bs [n, 4]: the composite then reads them
    nearly sequentially) and list each tile's sorted rows (tiles of 2^shift px): offsets
    [T+1], inst [M] (grown when short: the returned array)."""
    offsets[:] = 0
    for k in range(n):  # gather (unsigned indices: no wraparound selects) and count per tile
        if k + PF_AHEAD < n:
            prefetch_row(q, order[k + PF_AHEAD])
            prefetch_row(box, order[k + PF_AHEAD])
        r = U64(order[k])
        uk = U64(k)
        for c in range(NQ):
            qs[uk, U64(c)] = q[r, U64(c)]
        b0, b1, b2, b3 = box[r, U64(0)], box[r, U64(1)], box[r, U64(2)], box[r, U64(3)]
        bs[uk, U64(0)] = b0
        bs[uk, U64(1)] = b1
        bs[uk, U64(2)] = b2
        bs[uk, U64(3)] = b3
        for ty in range(b1 >> shift, (b3 >> shift) + 1):
            for tx in range(b0 >> shift, (b2 >> shift) + 1):
                offsets[U64(ty * tiles_x + tx + 1)] += 1
    for t in range(n_tiles):
        offsets[t + 1] += offsets[t]
    if inst.shape[0] < offsets[n_tiles]:
        inst = np.empty(2 * offsets[n_tiles], np.int32)
    fill = offsets[:n_tiles].copy()
    for k in range(n):
        uk = U64(k)
        for ty in range(bs[uk, U64(1)] >> shift, (bs[uk, U64(3)] >> shift) + 1):
            for tx in range(bs[uk, U64(0)] >> shift, (bs[uk, U64(2)] >> shift) + 1):
                t = U64(ty * tiles_x + tx)
                inst[U64(fill[t])] = k
                fill[t] += 1
    return inst


# exp(-x) = (p(x / 8))^8 with p a degree-4 fit of exp(-t) on [0, 5/8] (relative error weighted
# Chebyshev least squares): max relative error 1.4e-5 in float32 for 0 <= x <= 5 (the exp
# table it replaces: 3e-5). Pure arithmetic, so the pixel loop vectorises.
E0, E1, E2, E3, E4 = (F32(0.9999983906745911), F32(-0.9998854398727417), F32(0.49861371517181396),
                      F32(-0.16059421002864838), F32(0.03033546358346939))


@njit(cache=True, fastmath=True, inline="always")
def exp_neg(x):
    """exp(-x) for 0 <= x <= 5 (float32, relative error < 1.4e-5)."""
    t = x * F32(0.125)
    p = E0 + t * (E1 + t * (E2 + t * (E3 + t * E4)))
    p = p * p
    p = p * p
    return p * p


LANES = 8  # pixels per vector window of a splat row (86 % of sim-ready rows are <= 8 px)
ROW = 32 + LANES  # row stride of the tile's pixel state: a window starting in the tile fits
NPIX = 32 * ROW  # pixel state per plane (tiles of at most 32 x 32 px)
O1, O2, O3, O4 = U64(NPIX), U64(2 * NPIX), U64(3 * NPIX), U64(4 * NPIX)  # planes r g b z after T


@njit(cache=True, fastmath=True, inline="always")
def blend_window(pix, pb, d0, last, hca, bdy, hcdy, ct, o, c0, c1, c2, c3, t_stop, lanes):
    """Blend one splat into `lanes` pixels pix[pb + j] of a row (j <= last: inside its box;
    d0: x offset of lane 0 from the splat centre), branch-free so that it vectorises.
    Returns (blends, bits j of the lanes whose T fell below t_stop). The one blend of both
    fast composites (`composite_fast`, `env_fast_view.composite_view`); inlined, so a caller that
    ignores the counts compiles to the pixel updates alone."""
    nb = 0
    stop = U64(0)
    for j in range(lanes):
        p = pb + U64(j)
        dx = d0 + F32(j)
        s = dx * (hca * dx + bdy) + hcdy
        al = min(A_MAX, o * exp_neg(min(max(s, F32(0.0)), ct)))
        Tp = pix[p]
        ok = (s <= ct) & (Tp >= t_stop) & (U64(j) <= last)
        w = al * Tp if ok else F32(0.0)
        pix[p + O1] += w * c0
        pix[p + O2] += w * c1
        pix[p + O3] += w * c2
        pix[p + O4] += w * c3
        Tn = Tp - w
        pix[p] = Tn
        nb += np.int64(ok)
        stop |= U64(Tn < t_stop) << U64(j)
    return nb, stop


@njit(cache=True, inline="always")
def clear_tile(pix, rdone, tw, th):
    """Reset a tile's scratch: T = 1 and r g b z = 0 for its th rows; rdone marks the bit
    columns right of the tile's width tw as stopped."""
    for i in range(th * ROW):
        p = U64(i)
        pix[p] = F32(1.0)
        pix[p + O1] = F32(0.0)
        pix[p + O2] = F32(0.0)
        pix[p + O3] = F32(0.0)
        pix[p + O4] = F32(0.0)
    for r in range(th):
        rdone[r] = ~(ALL_BITS >> U64(64 - tw))


@njit(cache=True, fastmath=True, inline="always")
def finish_tile(pix, x0, y0, x1, y1, t_fill, color, alpha, depth):
    """Write a blended tile's pixels to color [H, W, 3], alpha [H, W], depth [H, W]: a pixel
    with T < t_fill is renormalised to alpha 1 (opaque)."""
    for py in range(y0, y1):
        rb = (py - y0) * ROW - x0
        for px in range(x0, x1):
            p = U64(rb + px)
            Tp = pix[p]
            opaque = Tp < t_fill
            f = F32(1.0) / (F32(1.0) - Tp) if opaque else F32(1.0)
            color[py, px, 0] = pix[p + O1] * f
            color[py, px, 1] = pix[p + O2] * f
            color[py, px, 2] = pix[p + O3] * f
            depth[py, px] = pix[p + O4] * f
            alpha[py, px] = F32(1.0) if opaque else F32(1.0) - Tp


@njit(cache=True, fastmath=True)
def composite_fast(q, box, offsets, inst, t0, x0, y0, x1, y1, t_stop, t_fill, pix, rdone, color,
                   alpha, depth):
    """Blend tile t0's rows inst[offsets[t0]:offsets[t0+1]] (depth order) into the tile's
    pixels; writes color [H, W, 3] (premultiplied), alpha [H, W], depth [H, W] (accumulated
    z). A pixel whose T fell below t_stop takes no more weight; at the end every pixel with
    T < t_fill (>= t_stop) is renormalised to alpha 1 (opaque). Scratch: pix [5 NPIX] (planes
    T r g b z, rows of ROW floats), rdone [32] (bit px - x0: stopped, or outside the tile).
    Tiles are at most 32 x 32 px. Each splat row blends windows of LANES pixels from the
    start of its box (clipped to the tile), without branches (pixels outside the ellipse or
    stopped get weight 0): the loop vectorises. Returns the number of blends (lanes that
    took weight, the padding lanes right of the tile included)."""
    tw = x1 - x0
    th = y1 - y0
    clear_tile(pix, rdone, tw, th)
    n_live = tw * th
    blends = 0
    for k in range(offsets[t0], offsets[t0 + 1]):
        v = inst[k]
        mx, my, ca, cb, cc = q[v, Q_X], q[v, Q_Y], q[v, Q_A], q[v, Q_B], q[v, Q_C]
        o, ct = q[v, Q_O], q[v, Q_CUT]
        c0, c1, c2, c3 = q[v, Q_R], q[v, Q_G], q[v, Q_BL], q[v, Q_Z]
        bx0 = max(box[v, 0], x0)
        bx1 = min(box[v, 2] + 1, x1)
        by0 = max(box[v, 1], y0)
        by1 = min(box[v, 3] + 1, y1)
        if bx1 <= bx0:
            continue
        hca = F32(0.5) * ca
        lo = bx0 - x0
        hi = bx1 - 1 - x0
        boxbits = (ALL_BITS >> U64(63 - (hi - lo))) << U64(lo)
        for py in range(by0, by1):
            ry = py - y0
            if rdone[ry] & boxbits == boxbits:
                continue  # every pixel of this row's box span has stopped
            dy = F32(py) + F32(0.5) - my
            bdy = cb * dy
            hcdy = F32(0.5) * cc * dy * dy
            rb = ry * ROW
            for c in range(lo, hi + 1, LANES):
                nb, stop = blend_window(pix, U64(rb + c), F32(x0 + c) + F32(0.5) - mx, U64(hi - c),
                                   hca, bdy, hcdy, ct, o, c0, c1, c2, c3, t_stop, LANES)
                blends += nb
                new = (stop << U64(c)) & ~rdone[ry]
                rdone[ry] |= new
                n_live -= np.int64(popc64(new))
        if n_live <= 0:
            break
    finish_tile(pix, x0, y0, x1, y1, t_fill, color, alpha, depth)
    return blends


@njit(cache=True)
def render_fast_frame(c0, c1, centers, r_means, rho, cell_start, pk, cell_mask, view, cam, width, height,
                      shift, near, far, cov_alpha, t_stop, t_fill, bg, q, box, qs, bs, keys, rows, inst,
                      color, out_rgb, out_alpha, out_depth, stats):
    """Every phase of one camera in this thread (cells c0:c1 of the packed scene pk, the rows
    cell_mask keeps: `cull_project`).
    Tiles are 2^shift px. Scratch: q / qs [G, NQ], box / bs [G, 4], keys / rows [2, G], inst [M] (grown when short: the
    returned array), color [H, W, 3]; outputs out_rgb [H, W, 3], out_alpha / out_depth [H, W],
    stats [NS]."""
    n, _ = cull_project(c0, c1, centers, r_means, rho, cell_start, pk, cell_mask, view, cam,
                        width, height, near, far, cov_alpha, q, box)
    order = depth_order(q, n, keys[0], keys[1], rows[0], rows[1])
    tile = 1 << shift
    tiles_x = (width + tile - 1) >> shift
    n_tiles = tiles_x * ((height + tile - 1) >> shift)
    offsets = np.empty(n_tiles + 1, np.int64)
    inst = sort_bin(q, box, n, order, qs, bs, shift, tiles_x, n_tiles, offsets, inst)
    pix = np.empty(5 * NPIX, np.float32)
    rdone = np.empty(32, np.uint64)
    blends = 0
    for ty in range(n_tiles // tiles_x):
        for tx in range(tiles_x):
            x0, y0 = tx << shift, ty << shift
            x1, y1 = min(x0 + tile, width), min(y0 + tile, height)
            blends += composite_fast(qs, bs, offsets, inst, ty * tiles_x + tx, x0, y0, x1, y1,
                                     F32(t_stop), F32(t_fill), pix, rdone, color, out_alpha,
                                     out_depth)
    finish_env(color, out_alpha, out_depth, bg, out_rgb, out_depth)
    covered = 0
    for i in range(height):
        for j in range(width):
            if out_alpha[i, j] > 0.0:
                covered += 1
    stats[0] = n
    stats[1] = offsets[n_tiles]
    stats[2] = blends
    stats[3] = covered
    return inst


@njit(parallel=True, cache=True)
def render_fast_frames(scene_of, cell_lo, centers, r_means, rho, cell_start, pk, cell_mask, views, cams,
                       width, height, shift, near, far, cov_alpha, t_stop, t_fill, bg, q, box, keys, rows,
                       color, out_rgb, out_alpha, out_depth, stats, n_workers):
    """Render cameras i < len(scene_of) (camera i sees packed scene scene_of[i]: cells
    cell_lo[s]:cell_lo[s+1]); n_workers draw whole frames from a shared counter. Scratch
    per worker: q [n_workers, 2, G, NQ], box [n_workers, 2, G, 4], keys / rows [n_workers, 2, G],
    color [n_workers, H, W, 3]; outputs [N, H, W(, 3)], stats [N, NS]."""
    n_cams = scene_of.shape[0]
    nxt = new_counter()
    for h in prange(n_workers):
        inst = np.empty(4 * q.shape[1] + 1024, np.int32)
        while True:
            i = fetch_add(nxt, 1)
            if i >= n_cams:
                break
            s = scene_of[i]
            inst = render_fast_frame(cell_lo[s], cell_lo[s + 1], centers, r_means, rho,
                                     cell_start, pk, cell_mask, views[i], cams[i], width, height, shift,
                                     near, far, cov_alpha, t_stop, t_fill, bg, q[h, 0], box[h, 0], q[h, 1],
                                     box[h, 1], keys[h],
                                     rows[h], inst, color[h], out_rgb[i], out_alpha[i],
                                     out_depth[i], stats[i])
