"""Approximate env frames at RL rates (issue 8): one 128x72 frame in ~2 ms of one core.

NOT exact (the exact env path is `frame.py`); what is traded, each measured as PSNR/SSIM
against the exact render by benchmarks/env_render.py:

- colour: one RGB per splat, no view-dependent SH (`simready.sim_ready` bakes each splat's
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

Per frame in one thread: cull culling cells (bounding spheres, `static_kernels.sphere_outside`)
and project only the splats of the cells that survive, straight into a compact list; radix
sort by depth; bin into small tiles; composite tile by tile front to back (per-pixel and
per-tile early stop); finish over the background. `render_fast_frames` runs N cameras
(possibly different packed scenes) over a shared counter, one frame per worker at a time.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit, prange, types
from numba.extending import intrinsic

from ._geom import jac_limits, screen_cov
from ._sched import fetch_add, new_counter
from .frame import finish_env
from .static_kernels import frustum_planes, sphere_outside

F32 = np.float32
U64 = np.uint64
# packed splat record [G, NP] float32 (model data, view independent)
P_X, P_Y, P_Z, P_S00, P_S01, P_S02, P_S11, P_S12, P_S22, P_O, P_R, P_G, P_B, P_CUT = range(14)
NP = 16
# projected splat record [R, NQ] float32 (one camera)
Q_X, Q_Y, Q_A, Q_B, Q_C, Q_O, Q_CUT, Q_R, Q_G, Q_BL, Q_Z, Q_DET = range(12)
NQ = 12
A_MAX = F32(0.99)
ALL_BITS = np.uint64(0xFFFFFFFFFFFFFFFF)
S_MAX = 4.5  # the exact renderer's cut-off on s (3 sigma)
KEY_SHIFT = np.uint32(10)  # depth key: float bits >> 10 (22 bits, two 11-bit radix passes)
# stats columns per frame: splats in view, tile instances, blends, covered pixels
NS = 4


@njit(cache=True)
def pack_splats(means, cov, opacity, rgb):
    """Packed records [G, NP] float32 from means [G, 3], world covariances [G, 6] (xx xy xz
    yy yz zz), opacities [G] and colours [G, 3]; P_CUT = min(ln(255 o), S_MAX): the largest
    Gaussian power s = d^T Sigma^-1 d / 2 at which o exp(-s) still reaches 1/255, within the
    exact renderer's 3-sigma cut-off."""
    G = means.shape[0]
    pk = np.zeros((G, NP), np.float32)
    for i in range(G):
        for q in range(3):
            pk[i, P_X + q] = means[i, q]
            pk[i, P_R + q] = rgb[i, q]
        for q in range(6):
            pk[i, P_S00 + q] = cov[i, q]
        o = opacity[i]
        pk[i, P_O] = o
        pk[i, P_CUT] = min(math.log(max(o * 255.0, 1.0)), S_MAX)
    return pk


@njit(cache=True, fastmath=True, inline="always")
def _project_one(rec, W, tw, fx, fy, cx, cy, lims, width, height, near, far, cov_alpha, q, box,
                 j):
    """Project one packed record into q[j], box[j]; returns 1 when it reaches a pixel."""
    mx, my, mz = rec[P_X], rec[P_Y], rec[P_Z]
    tz = W[6] * mx + W[7] * my + W[8] * mz + tw[2]
    if not (tz >= near and tz <= far):
        return 0
    ct = rec[P_CUT]
    if ct <= 0.0:
        return 0
    tx = W[0] * mx + W[1] * my + W[2] * mz + tw[0]
    ty = W[3] * mx + W[4] * my + W[5] * mz + tw[1]
    iz = F32(1.0) / tz
    lxp, lxn, lyp, lyn = lims
    rx = min(max(tx * iz, -lxn), lxp)
    ry = min(max(ty * iz, -lyn), lyp)
    j00 = fx * iz
    j11 = fy * iz
    j02 = -fx * rx * iz
    j12 = -fy * ry * iz
    s00, s01, s02 = rec[P_S00], rec[P_S01], rec[P_S02]
    s11, s12, s22 = rec[P_S11], rec[P_S12], rec[P_S22]
    A, B, C = screen_cov(W, j00, j02, j11, j12, s00, s01, s02, s11, s12, s22)
    det = A * C - B * B
    if not det > 0.0:
        return 0
    if cov_alpha > 0.0 and max(abs(A), abs(B), abs(C)) > cov_alpha * height * width:
        return 0
    px = fx * tx * iz + cx
    py = fy * ty * iz + cy
    ex = math.sqrt(2.0 * ct * A)
    ey = math.sqrt(2.0 * ct * C)
    j0 = max(math.ceil(px - ex - 0.5), 0)
    j1 = min(math.floor(px + ex - 0.5), width - 1)
    i0 = max(math.ceil(py - ey - 0.5), 0)
    i1 = min(math.floor(py + ey - 0.5), height - 1)
    if j0 > j1 or i0 > i1:
        return 0
    idet = 1.0 / det
    o = q[j]
    o[Q_X] = px
    o[Q_Y] = py
    o[Q_A] = C * idet
    o[Q_B] = -B * idet
    o[Q_C] = A * idet
    o[Q_O] = rec[P_O]
    o[Q_CUT] = ct
    o[Q_R] = rec[P_R]
    o[Q_G] = rec[P_G]
    o[Q_BL] = rec[P_B]
    o[Q_Z] = tz
    o[Q_DET] = idet  # det of the conic (a c - b^2)
    box[j, 0] = j0
    box[j, 1] = i0
    box[j, 2] = j1
    box[j, 3] = i1
    return 1


@njit(cache=True)
def cull_project(c0, c1, centers, r_means, rho, cell_start, pk, view, cam, width, height, near,
                 far, cov_alpha, q, box):
    """Project the splats of cells c0:c1 that survive the frustum test into compact rows of
    q [R, NQ] / box [R, 4] (only splats that reach a pixel); returns (rows, splats tested)."""
    W, tw, planes, grow = frustum_planes(view, cam, width, height)
    Wf = (F32(W[0]), F32(W[1]), F32(W[2]), F32(W[3]), F32(W[4]), F32(W[5]), F32(W[6]),
          F32(W[7]), F32(W[8]))
    twf = (F32(tw[0]), F32(tw[1]), F32(tw[2]))
    fx, fy, cx, cy = F32(cam[0]), F32(cam[1]), F32(cam[2]), F32(cam[3])
    lp = jac_limits(cam[0], cam[1], cam[2], cam[3], width, height)
    lims = (F32(lp[0]), F32(lp[1]), F32(lp[2]), F32(lp[3]))
    nearf, farf, cova = F32(near), F32(far), F32(cov_alpha)
    n = 0
    tested = 0
    for c in range(c0, c1):
        if sphere_outside(centers[c, 0], centers[c, 1], centers[c, 2], r_means[c], rho[c], W,
                          tw, planes, grow, near, far):
            continue
        for i in range(cell_start[c], cell_start[c + 1]):
            n += _project_one(pk[i], Wf, twf, fx, fy, cx, cy, lims, width, height, nearf, farf,
                              cova, q, box, n)
        tested += cell_start[c + 1] - cell_start[c]
    return n, tested


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


@intrinsic
def ctz64(typingctx, x):
    """Count of trailing zero bits of a uint64 (x != 0)."""
    if x != types.uint64:
        return None
    sig = types.uint64(types.uint64)

    def codegen(context, builder, sig, args):
        return builder.cttz(args[0], ir.Constant(ir.IntType(1), 1))

    return sig, codegen


@intrinsic
def popc64(typingctx, x):
    """Number of set bits of a uint64."""
    if x != types.uint64:
        return None
    sig = types.uint64(types.uint64)

    def codegen(context, builder, sig, args):
        return builder.ctpop(args[0])

    return sig, codegen


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
def _window(pix, pb, d0, last, hca, bdy, hcdy, ct, o, c0, c1, c2, c3, t_stop, lanes):
    """Blend one splat into `lanes` pixels pix[pb + j] of a row (j <= last: inside its box;
    d0: x offset of lane 0 from the splat centre), branch-free so that it vectorises.
    Returns (blends, bits j of the lanes whose T fell below t_stop)."""
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
    for i in range(th * ROW):
        p = U64(i)
        pix[p] = F32(1.0)
        pix[p + O1] = F32(0.0)
        pix[p + O2] = F32(0.0)
        pix[p + O3] = F32(0.0)
        pix[p + O4] = F32(0.0)
    for r in range(th):
        rdone[r] = ~(ALL_BITS >> U64(64 - tw))
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
                nb, stop = _window(pix, U64(rb + c), F32(x0 + c) + F32(0.5) - mx, U64(hi - c),
                                   hca, bdy, hcdy, ct, o, c0, c1, c2, c3, t_stop, LANES)
                blends += nb
                new = (stop << U64(c)) & ~rdone[ry]
                rdone[ry] |= new
                n_live -= np.int64(popc64(new))
        if n_live <= 0:
            break
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
    return blends


@njit(cache=True)
def render_fast_frame(c0, c1, centers, r_means, rho, cell_start, pk, view, cam, width, height,
                      shift, near, far, cov_alpha, t_stop, t_fill, bg, q, box, qs, bs, keys, rows, inst,
                      color, out_rgb, out_alpha, out_depth, stats):
    """Every phase of one camera in this thread (cells c0:c1 of the packed scene pk).
    Tiles are 2^shift px. Scratch: q / qs [G, NQ], box / bs [G, 4], keys / rows [2, G], inst [M] (grown when short: the
    returned array), color [H, W, 3]; outputs out_rgb [H, W, 3], out_alpha / out_depth [H, W],
    stats [NS]."""
    n, _ = cull_project(c0, c1, centers, r_means, rho, cell_start, pk, view, cam, width,
                        height, near, far, cov_alpha, q, box)
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
def render_fast_frames(scene_of, cell_lo, centers, r_means, rho, cell_start, pk, views, cams,
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
                                     cell_start, pk, views[i], cams[i], width, height, shift,
                                     near, far, cov_alpha, t_stop, t_fill, bg, q[h, 0], box[h, 0], q[h, 1],
                                     box[h, 1], keys[h],
                                     rows[h], inst, color[h], out_rgb[i], out_alpha[i],
                                     out_depth[i], stats[i])
