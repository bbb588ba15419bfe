"""Per-splat projection: forward (projection, culling, colour, normal, pixel box) and
backward kernels of the differentiable renderer, and what every path shares: the projected
record's columns (F_*), `camera_arrays`, `view_parts`, `sigma_cut`.

Forward reads the model arrays for a candidate list `idx` and writes one row per candidate;
backward reads per-visible-splat 2D gradients and writes the model gradients.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ._geom import (conic_vjp, cov3d, jac_limits, mm3, pixel_box, project_cov, quat_rot,
                    quat_rot_vjp, radius_of, tr3)
from ._sched import CHUNK, fetch_add, n_chunks, new_counter
from ._sh import sh_basis, sh_color, sh_dir_vjp

SIGMA_CUTOFF = 4.5
ALPHA_MIN = 1.0 / 255.0
CUT_MARGIN = 1e-3  # slack on the per-splat sigma cutoff used only to bound tiles/skip early

# Columns of the per-candidate float output `fo` [C, NF].
F_X, F_Y, F_A, F_B, F_C, F_O, F_CUT, F_Z, F_R, F_G, F_BL, F_NX, F_NY, F_NZ = range(14)
NF = 16


def camera_arrays(camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(world_to_cam [4,4] f64, centre [3] f64, (fx, fy, cx, cy) f64) of a Camera for the
    kernels."""
    view = np.ascontiguousarray(camera.world_to_cam.detach().double().numpy())
    R, t = view[:3, :3], view[:3, 3]
    return view, np.ascontiguousarray(-R.T @ t), np.array(
        [camera.fx, camera.fy, camera.cx, camera.cy], np.float64)


@njit(cache=True)
def sigma_cut(opacity):
    """Largest sigma at which a splat of this opacity can still reach alpha >= 1/255."""
    if opacity * 255.0 < 1.0:
        return -1.0
    return min(SIGMA_CUTOFF, math.log(opacity * 255.0) + CUT_MARGIN)


@njit(cache=True)
def screen_and_box(t, Sc, opacity, cut, cam, lims, cov_alpha, width, height, fo, c, box):
    """Shared steps 4-7 for candidate c: writes fo[c] geometry and box[c]; returns radius (0 = culled)."""
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    tx, ty, tz = t
    A, B, C, j00, j02, j11, j12, txc, tyc, cxm, cym = project_cov(tx, ty, tz, Sc, fx, fy, lims)
    det = A * C - B * B
    if not det > 0.0:
        return 0
    if cov_alpha > 0.0 and max(abs(A), abs(B), abs(C)) > cov_alpha * height * width:
        return 0
    mx = fx * tx / tz + cx
    my = fy * ty / tz + cy
    r = radius_of(A, B, C)
    if mx + r <= 0.0 or mx - r >= width or my + r <= 0.0 or my - r >= height:
        return 0
    fo[c, F_X] = mx
    fo[c, F_Y] = my
    fo[c, F_A] = C / det
    fo[c, F_B] = -B / det
    fo[c, F_C] = A / det
    fo[c, F_O] = opacity
    fo[c, F_CUT] = cut
    fo[c, F_Z] = tz
    # Pixel box (inclusive) of the sigma <= cut ellipse's axis-aligned extent (centres j + 0.5);
    # empty (j1 < j0) when the splat can reach no pixel.
    box[c, 0] = 0
    box[c, 1] = 0
    box[c, 2] = -1
    box[c, 3] = -1
    pixel_box(mx, my, cut, A, C, width, height, box, c)
    return max(r, 1)


@njit(cache=True)
def cam_normal(R, k, W, t):
    """Column k of R in the camera frame, flipped to face the camera; and the flip sign."""
    nx, ny, nz = R[k], R[3 + k], R[6 + k]
    cnx = W[0] * nx + W[1] * ny + W[2] * nz
    cny = W[3] * nx + W[4] * ny + W[5] * nz
    cnz = W[6] * nx + W[7] * ny + W[8] * nz
    f = -1.0 if cnx * t[0] + cny * t[1] + cnz * t[2] > 0.0 else 1.0
    return f * cnx, f * cny, f * cnz, f


@njit(cache=True)
def argmin3(a, b, c):
    """Index of the smallest of three (ties: lowest index)."""
    k = 0
    m = a
    if b < m:
        k = 1
        m = b
    if c < m:
        k = 2
    return k


@njit(cache=True)
def view_parts(view):
    """(W 9-tuple, tw 3-tuple) from a float64 [4, 4] world-to-camera matrix."""
    W = (view[0, 0], view[0, 1], view[0, 2], view[1, 0], view[1, 1], view[1, 2],
         view[2, 0], view[2, 1], view[2, 2])
    return W, (view[0, 3], view[1, 3], view[2, 3])


@njit(cache=True, inline="always")
def _project_one(c, idx, means, quats, log_scales, logits, sh, deg, W, tw, campos, cam, lims,
                 width, height, near, far, cov_alpha, fo, box, radii):
    """project_forward for candidate c."""
    i = idx[c]
    mx, my, mz = means[i, 0], means[i, 1], means[i, 2]
    tz = W[6] * mx + W[7] * my + W[8] * mz + tw[2]
    radii[c] = 0
    if not (tz >= near and tz <= far):
        return
    tx = W[0] * mx + W[1] * my + W[2] * mz + tw[0]
    ty = W[3] * mx + W[4] * my + W[5] * mz + tw[1]
    t = (tx, ty, tz)
    w, x, y, z, n, R = quat_rot(quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3])
    S3, L = cov3d(R, math.exp(log_scales[i, 0]), math.exp(log_scales[i, 1]),
                  math.exp(log_scales[i, 2]))
    Sc = mm3(mm3(W, S3), tr3(W))
    opacity = 1.0 / (1.0 + math.exp(-logits[i]))
    r = screen_and_box(t, Sc, opacity, sigma_cut(opacity), cam, lims, cov_alpha, width, height, fo, c, box)
    radii[c] = r
    if r == 0:
        return
    vx, vy, vz = mx - campos[0], my - campos[1], mz - campos[2]
    vn = max(math.sqrt(vx * vx + vy * vy + vz * vz), 1e-12)
    cr, cg, cb = sh_color(deg, sh[i], vx / vn, vy / vn, vz / vn)
    fo[c, F_R] = max(cr, 0.0)
    fo[c, F_G] = max(cg, 0.0)
    fo[c, F_BL] = max(cb, 0.0)
    k = argmin3(log_scales[i, 0], log_scales[i, 1], log_scales[i, 2])
    nx, ny, nz, f = cam_normal(R, k, W, t)
    fo[c, F_NX] = nx
    fo[c, F_NY] = ny
    fo[c, F_NZ] = nz


@njit(parallel=True, cache=True)
def project_forward(idx, means, quats, log_scales, logits, sh, deg, view, campos, cam,
                    width, height, near, far, cov_alpha, fo, box, radii, n_workers=1):
    """Project candidates idx [C] -> fo [C, NF] float32, box [C, 4] int32 (pixel box
    j0, i0, j1, i1 inclusive), radii [C] int32. n_workers draw chunks of candidates from
    a shared counter (dynamic balance)."""
    W, tw = view_parts(view)
    lims = jac_limits(cam[0], cam[1], cam[2], cam[3], width, height)
    n = idx.shape[0]
    n_items = n_chunks(n, CHUNK)
    nxt = new_counter()
    for _h in prange(n_workers):
        while True:
            ch = fetch_add(nxt, 1)
            if ch >= n_items:
                break
            for c in range(ch * CHUNK, min(n, (ch + 1) * CHUNK)):
                _project_one(c, idx, means, quats, log_scales, logits, sh, deg, W, tw, campos,
                             cam, lims, width, height, near, far, cov_alpha, fo, box, radii)


# Columns of the per-visible-splat 2D gradient `g2` [V, NG] (raster backward output).
G_MX, G_MY, G_A, G_B, G_C, G_O, G_R, G_G, G_BL, G_Z, G_NX, G_NY, G_NZ, G_AX, G_AY = range(15)
NG = 16


@njit(cache=True, inline="always")
def _backward_one(v, ids, means, quats, log_scales, logits, sh, deg, W, tw, campos, cam, lims,
                  g2, d_means, d_quats, d_logs, d_logits, d_sh, grad2d, absgrad, want_abs):
    """project_backward for visible splat v."""
    fx, fy = cam[0], cam[1]
    i = ids[v]
    g = g2[v]
    grad2d[i, 0] += g[G_MX]
    grad2d[i, 1] += g[G_MY]
    if want_abs:
        absgrad[i, 0] += g[G_AX]
        absgrad[i, 1] += g[G_AY]
    mx, my, mz = means[i, 0], means[i, 1], means[i, 2]
    tx = W[0] * mx + W[1] * my + W[2] * mz + tw[0]
    ty = W[3] * mx + W[4] * my + W[5] * mz + tw[1]
    tz = W[6] * mx + W[7] * my + W[8] * mz + tw[2]
    t = (tx, ty, tz)
    qw, qx, qy, qz, qn, R = quat_rot(quats[i, 0], quats[i, 1], quats[i, 2], quats[i, 3])
    sx, sy, sz = math.exp(log_scales[i, 0]), math.exp(log_scales[i, 1]), math.exp(log_scales[i, 2])
    S3, L = cov3d(R, sx, sy, sz)
    Sc = mm3(mm3(W, S3), tr3(W))
    A, B, C, j00, j02, j11, j12, txc, tyc, cxm, cym = project_cov(tx, ty, tz, Sc, fx, fy, lims)

    # opacity
    o = 1.0 / (1.0 + math.exp(-logits[i]))
    d_logits[i] = g[G_O] * o * (1.0 - o)

    # colour -> sh and view direction
    vx, vy, vz = mx - campos[0], my - campos[1], mz - campos[2]
    vn = max(math.sqrt(vx * vx + vy * vy + vz * vz), 1e-12)
    dx, dy, dz = vx / vn, vy / vn, vz / vn
    cr, cg, cb = sh_color(deg, sh[i], dx, dy, dz)
    gr = g[G_R] if cr >= 0.0 else 0.0
    gg = g[G_G] if cg >= 0.0 else 0.0
    gb = g[G_BL] if cb >= 0.0 else 0.0
    bs = sh_basis(dx, dy, dz)
    for k in range((deg + 1) * (deg + 1)):
        d_sh[i, k, 0] = bs[k] * gr
        d_sh[i, k, 1] = bs[k] * gg
        d_sh[i, k, 2] = bs[k] * gb
    ddx, ddy, ddz = sh_dir_vjp(deg, sh[i], dx, dy, dz, gr, gg, gb)
    dd = ddx * dx + ddy * dy + ddz * dz
    gmx = (ddx - dx * dd) / vn
    gmy = (ddy - dy * dd) / vn
    gmz = (ddz - dz * dd) / vn

    # conic -> Sigma2d -> (J, Sigma_cam) -> Sigma3d -> (R, s)
    G00, G01, G11 = conic_vjp(A, B, C, g[G_A], g[G_B], g[G_C])
    # G_Sc = J^T G J, J = [[j00, 0, j02], [0, j11, j12]]
    a0 = G00 * j00
    a1 = G01 * j11
    b0 = G01 * j00
    b1 = G11 * j11
    q0 = G00 * j02 + G01 * j12
    q1 = G01 * j02 + G11 * j12
    GSc = (j00 * a0, j00 * a1, j00 * q0,
           j11 * b0, j11 * b1, j11 * q1,
           j02 * a0 + j12 * b0, j02 * a1 + j12 * b1, j02 * q0 + j12 * q1)
    # G_J = 2 G J Sc  (2x3)
    JS0 = (j00 * Sc[0] + j02 * Sc[6], j00 * Sc[1] + j02 * Sc[7], j00 * Sc[2] + j02 * Sc[8])
    JS1 = (j11 * Sc[3] + j12 * Sc[6], j11 * Sc[4] + j12 * Sc[7], j11 * Sc[5] + j12 * Sc[8])
    gj00 = 2.0 * (G00 * JS0[0] + G01 * JS1[0])
    gj02 = 2.0 * (G00 * JS0[2] + G01 * JS1[2])
    gj11 = 2.0 * (G01 * JS0[1] + G11 * JS1[1])
    gj12 = 2.0 * (G01 * JS0[2] + G11 * JS1[2])
    GS3 = mm3(mm3(tr3(W), GSc), W)
    # symmetrise (Sigma3d is symmetric; G_L = (G + G^T) L)
    GS = (GS3[0] + GS3[0], GS3[1] + GS3[3], GS3[2] + GS3[6],
          GS3[3] + GS3[1], GS3[4] + GS3[4], GS3[5] + GS3[7],
          GS3[6] + GS3[2], GS3[7] + GS3[5], GS3[8] + GS3[8])
    GL = mm3(GS, L)
    GR = (GL[0] * sx, GL[1] * sy, GL[2] * sz, GL[3] * sx, GL[4] * sy, GL[5] * sz,
          GL[6] * sx, GL[7] * sy, GL[8] * sz)
    d_logs[i, 0] = (GL[0] * R[0] + GL[3] * R[3] + GL[6] * R[6]) * sx
    d_logs[i, 1] = (GL[1] * R[1] + GL[4] * R[4] + GL[7] * R[7]) * sy
    d_logs[i, 2] = (GL[2] * R[2] + GL[5] * R[5] + GL[8] * R[8]) * sz

    # normal -> R column
    k = argmin3(log_scales[i, 0], log_scales[i, 1], log_scales[i, 2])
    nx, ny, nz, f = cam_normal(R, k, W, t)
    gnx, gny, gnz = g[G_NX], g[G_NY], g[G_NZ]
    wx = f * (W[0] * gnx + W[3] * gny + W[6] * gnz)
    wy = f * (W[1] * gnx + W[4] * gny + W[7] * gnz)
    wz = f * (W[2] * gnx + W[5] * gny + W[8] * gnz)
    if k == 0:
        GR = (GR[0] + wx, GR[1], GR[2], GR[3] + wy, GR[4], GR[5], GR[6] + wz, GR[7], GR[8])
    elif k == 1:
        GR = (GR[0], GR[1] + wx, GR[2], GR[3], GR[4] + wy, GR[5], GR[6], GR[7] + wz, GR[8])
    else:
        GR = (GR[0], GR[1], GR[2] + wx, GR[3], GR[4], GR[5] + wy, GR[6], GR[7], GR[8] + wz)
    dqw, dqx, dqy, dqz = quat_rot_vjp(qw, qx, qy, qz, qn, GR)
    d_quats[i, 0] = dqw
    d_quats[i, 1] = dqx
    d_quats[i, 2] = dqy
    d_quats[i, 3] = dqz

    # camera-frame mean: mean2d, depth, and J
    iz = 1.0 / tz
    dtx = fx * iz * g[G_MX]
    dty = fy * iz * g[G_MY]
    dtz = -fx * tx * iz * iz * g[G_MX] - fy * ty * iz * iz * g[G_MY] + g[G_Z]
    dtz += -fx * iz * iz * gj00 - fy * iz * iz * gj11
    dtxc = -fx * iz * iz * gj02
    dtyc = -fy * iz * iz * gj12
    dtz += 2.0 * fx * txc * iz * iz * iz * gj02 + 2.0 * fy * tyc * iz * iz * iz * gj12
    if cxm:
        dtz += dtxc * txc * iz
    else:
        dtx += dtxc
    if cym:
        dtz += dtyc * tyc * iz
    else:
        dty += dtyc
    d_means[i, 0] = W[0] * dtx + W[3] * dty + W[6] * dtz + gmx
    d_means[i, 1] = W[1] * dtx + W[4] * dty + W[7] * dtz + gmy
    d_means[i, 2] = W[2] * dtx + W[5] * dty + W[8] * dtz + gmz


@njit(parallel=True, cache=True)
def project_backward(ids, means, quats, log_scales, logits, sh, deg, view, campos, cam,
                     width, height, g2, d_means, d_quats, d_logs, d_logits, d_sh, grad2d,
                     absgrad, want_abs, n_workers=1):
    """Chain per-visible-splat 2D gradients g2 [V, NG] back to the model parameters.

    Writes rows ids[v] of d_means [N,3], d_quats [N,4], d_logs [N,3], d_logits [N],
    d_sh [N,K,3]; adds dL/dmean2d into grad2d [N,2] and the AbsGS sums into absgrad [N,2].
    """
    W, tw = view_parts(view)
    lims = jac_limits(cam[0], cam[1], cam[2], cam[3], width, height)
    n = ids.shape[0]
    n_items = n_chunks(n, CHUNK)
    nxt = new_counter()
    for _h in prange(n_workers):
        while True:
            ch = fetch_add(nxt, 1)
            if ch >= n_items:
                break
            for v in range(ch * CHUNK, min(n, (ch + 1) * CHUNK)):
                _backward_one(v, ids, means, quats, log_scales, logits, sh, deg, W, tw, campos,
                              cam, lims, g2, d_means, d_quats, d_logs, d_logits, d_sh, grad2d,
                              absgrad, want_abs)
