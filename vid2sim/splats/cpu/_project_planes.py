"""The per-splat projection and its VJP (training, `forward_lanes` / `backward_lanes`) and the
env path's projection of cached Gaussians (`static_lanes`) over chunks of PCH splats held as
planes, so that the arithmetic vectorises (float64 lanes) instead of running one splat at a time.

Each chunk runs in three passes: a scalar gather of the splat's inputs (the libm calls, exp and
log, happen here: without a vector math library LLVM would not vectorise a loop that calls
them) into the planes of a per-thread buffer; one branch-free loop over the chunk (culling and
the clamped Jacobian as selects) that writes the outputs into more planes; and a scalar
scatter into the callers' rows. The math is the one of docs/splat_renderer.md steps 3-8 and
of `vid2sim.splats.reference` (which the tests compare against).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from ._geom import LOWPASS, conic_vjp, cov3d, mm3, quat_rot, quat_rot_vjp, screen_cov, tr3
from ._sh import (C0, C1, C20, C21, C22, C23, C24, C30, C31, C32, C33, C34, C35, C36,
                  sh_basis)

U64 = np.uint64
PCH = 64  # splats per chunk: the vector loop's trip count
SH_PLANES = 48  # 16 coefficients x 3 channels; planes past the active degree hold zeros

# Output planes of both forward projections (training and env path), after their inputs:
# what `scatter_rows` writes into the callers' fo / box / radii rows.
(Q_X, Q_Y, Q_A, Q_B, Q_C, Q_O, Q_CUT, Q_Z, Q_R, Q_G, Q_BL, Q_NX, Q_NY, Q_NZ,
 Q_J0, Q_I0, Q_J1, Q_I1, Q_RAD) = range(17, 36)
NQ = 36  # planes of a forward buffer [NQ * PCH] float64

# input planes of the training forward (planes 0-10 the same as the backward's: `gather_model`)
(PF_MX, PF_MY, PF_MZ, PF_QW, PF_QX, PF_QY, PF_QZ, PF_SX, PF_SY, PF_SZ, PF_O, PF_CUT,
 PF_K) = range(13)

# float64 planes of the backward's buffer [PB * PCH]: inputs (model values and the 2D
# gradient columns), then outputs
(PB_MX, PB_MY, PB_MZ, PB_QW, PB_QX, PB_QY, PB_QZ, PB_SX, PB_SY, PB_SZ, PB_O, PB_K,
 PB_GMX, PB_GMY, PB_GA, PB_GB, PB_GC, PB_GO, PB_GR, PB_GG, PB_GBL, PB_GZ, PB_GNX, PB_GNY,
 PB_GNZ,
 PB_DMX, PB_DMY, PB_DMZ, PB_DQW, PB_DQX, PB_DQY, PB_DQZ, PB_DL0, PB_DL1, PB_DL2, PB_DLOGIT,
 PB_DX, PB_DY, PB_DZ, PB_CR, PB_CG, PB_CB) = range(42)
PB = 42


@njit(cache=True, inline="always")
def sh_layout(sh, deg):
    """sh [N, K, 3] (C-contiguous) as a flat array, the values per splat (3K) and how many of
    them the active degree reads (3 (deg + 1)^2): what `gather_sh` takes."""
    return sh.reshape(-1), 3 * sh.shape[1], 3 * (deg + 1) * (deg + 1)


@njit(cache=True, inline="always")
def lane_buffers(planes):
    """A worker's chunk buffers: float64 [planes * PCH] and the SH planes, float32
    [SH_PLANES * PCH], zeroed (planes past the active degree must stay zero)."""
    return np.empty(planes * PCH, np.float64), np.zeros(SH_PLANES * PCH, np.float32)


@njit(cache=True, inline="always")
def at(k, j):
    """Offset of lane j in plane k."""
    return U64(k * PCH) + j


@njit(cache=True, inline="always")
def gather_model(buf, j, i, means, quats, log_scales, logits):
    """Lane j of the planes both passes share (mean, quaternion, scales, opacity: planes 0-10)
    from splat i; returns its log-scales."""
    buf[at(0, j)] = means[i, 0]
    buf[at(1, j)] = means[i, 1]
    buf[at(2, j)] = means[i, 2]
    buf[at(3, j)] = quats[i, 0]
    buf[at(4, j)] = quats[i, 1]
    buf[at(5, j)] = quats[i, 2]
    buf[at(6, j)] = quats[i, 3]
    l0, l1, l2 = log_scales[i, 0], log_scales[i, 1], log_scales[i, 2]
    buf[at(7, j)] = math.exp(l0)
    buf[at(8, j)] = math.exp(l1)
    buf[at(9, j)] = math.exp(l2)
    buf[at(10, j)] = 1.0 / (1.0 + math.exp(-logits[i]))
    return l0, l1, l2


@njit(cache=True, inline="always")
def smallest_axis(l0, l1, l2):
    """Index (as float) of the smallest of three log-scales, ties to the lowest index."""
    k = 1.0 if l1 < l0 else 0.0
    return 2.0 if l2 < min(l0, l1) else k


@njit(cache=True, inline="always")
def gather_sh(shp, shf, base, k3, j):
    """Copy a splat's first k3 SH values (flat row shf[base:base + k3]) into lane j."""
    for kk in range(k3):
        shp[at(kk, j)] = shf[base + kk]


@njit(cache=True, inline="always")
def _acc(r, g, b, v, shp, k, j):
    return (r + v * shp[at(3 * k, j)], g + v * shp[at(3 * k + 1, j)],
            b + v * shp[at(3 * k + 2, j)])


@njit(cache=True, inline="always")
def sh_color_lane(shp, j, x, y, z):
    """Raw colour SH(d) + 0.5 of lane j for unit direction (x, y, z): all 16 terms."""
    r, g, b = _acc(0.0, 0.0, 0.0, C0, shp, 0, j)
    r, g, b = _acc(r, g, b, -C1 * y, shp, 1, j)
    r, g, b = _acc(r, g, b, C1 * z, shp, 2, j)
    r, g, b = _acc(r, g, b, -C1 * x, shp, 3, j)
    xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
    r, g, b = _acc(r, g, b, C20 * xy, shp, 4, j)
    r, g, b = _acc(r, g, b, C21 * yz, shp, 5, j)
    r, g, b = _acc(r, g, b, C22 * (2.0 * zz - xx - yy), shp, 6, j)
    r, g, b = _acc(r, g, b, C23 * xz, shp, 7, j)
    r, g, b = _acc(r, g, b, C24 * (xx - yy), shp, 8, j)
    r, g, b = _acc(r, g, b, C30 * y * (3.0 * xx - yy), shp, 9, j)
    r, g, b = _acc(r, g, b, C31 * xy * z, shp, 10, j)
    r, g, b = _acc(r, g, b, C32 * y * (4.0 * zz - xx - yy), shp, 11, j)
    r, g, b = _acc(r, g, b, C33 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy), shp, 12, j)
    r, g, b = _acc(r, g, b, C34 * x * (4.0 * zz - xx - yy), shp, 13, j)
    r, g, b = _acc(r, g, b, C35 * z * (xx - yy), shp, 14, j)
    r, g, b = _acc(r, g, b, C36 * x * (xx - 3.0 * yy), shp, 15, j)
    return r + 0.5, g + 0.5, b + 0.5


@njit(cache=True, inline="always")
def _dot(shp, k, j, gr, gg, gb):
    return shp[at(3 * k, j)] * gr + shp[at(3 * k + 1, j)] * gg + shp[at(3 * k + 2, j)] * gb


@njit(cache=True, inline="always")
def sh_dir_vjp_lane(shp, j, x, y, z, gr, gg, gb):
    """d(colour . g)/d(direction) of lane j (all 16 terms; zero planes drop out)."""
    s1, s2, s3 = _dot(shp, 1, j, gr, gg, gb), _dot(shp, 2, j, gr, gg, gb), _dot(shp, 3, j, gr, gg, gb)
    s4, s5, s6 = _dot(shp, 4, j, gr, gg, gb), _dot(shp, 5, j, gr, gg, gb), _dot(shp, 6, j, gr, gg, gb)
    s7, s8, s9 = _dot(shp, 7, j, gr, gg, gb), _dot(shp, 8, j, gr, gg, gb), _dot(shp, 9, j, gr, gg, gb)
    s10, s11 = _dot(shp, 10, j, gr, gg, gb), _dot(shp, 11, j, gr, gg, gb)
    s12, s13 = _dot(shp, 12, j, gr, gg, gb), _dot(shp, 13, j, gr, gg, gb)
    s14, s15 = _dot(shp, 14, j, gr, gg, gb), _dot(shp, 15, j, gr, gg, gb)
    xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
    dx = (-C1 * s3 + C20 * y * s4 + (-2.0 * C22 * x) * s6 + C23 * z * s7 + 2.0 * C24 * x * s8
          + 6.0 * C30 * xy * s9 + C31 * yz * s10 - 2.0 * C32 * xy * s11
          - 6.0 * C33 * xz * s12 + C34 * (4.0 * zz - 3.0 * xx - yy) * s13
          + 2.0 * C35 * xz * s14 + C36 * (3.0 * xx - 3.0 * yy) * s15)
    dy = (-C1 * s1 + C20 * x * s4 + C21 * z * s5 + (-2.0 * C22 * y) * s6 - 2.0 * C24 * y * s8
          + C30 * (3.0 * xx - 3.0 * yy) * s9 + C31 * xz * s10
          + C32 * (4.0 * zz - xx - 3.0 * yy) * s11 - 6.0 * C33 * yz * s12
          - 2.0 * C34 * xy * s13 - 2.0 * C35 * yz * s14 - 6.0 * C36 * xy * s15)
    dz = (C1 * s2 + C21 * y * s5 + 4.0 * C22 * z * s6 + C23 * x * s7
          + C31 * xy * s10 + 8.0 * C32 * yz * s11
          + C33 * (6.0 * zz - 3.0 * xx - 3.0 * yy) * s12 + 8.0 * C34 * xz * s13
          + C35 * (xx - yy) * s14)
    return dx, dy, dz


@njit(cache=True, inline="always")
def camera_cov(W, S3):
    """Sc = W S3 W^T (9-tuples)."""
    return mm3(mm3(W, S3), tr3(W))


@njit(cache=True, inline="always")
def clamped_jacobian(tx, ty, tz, fx, fy, lims):
    """gsplat's projection Jacobian entries with the clamped t_x / t_z, t_y / t_z:
    (j00, j02, j11, j12, txc, tyc, x clamped, y clamped)."""
    lxp, lxn, lyp, lyn = lims
    iz = 1.0 / tz
    rx = tx * iz
    ry = ty * iz
    txc = tz * min(max(rx, -lxn), lxp)
    tyc = tz * min(max(ry, -lyn), lyp)
    return (fx * iz, -fx * txc * (iz * iz), fy * iz, -fy * tyc * (iz * iz), txc, tyc,
            (rx < -lxn) | (rx > lxp), (ry < -lyn) | (ry > lyp))


@njit(cache=True, inline="always")
def sigma2d(Sc, j00, j02, j11, j12):
    """Sigma2d (A, B, C) + low-pass from Sc and J = [[j00, 0, j02], [0, j11, j12]]."""
    A = j00 * j00 * Sc[0] + 2.0 * j00 * j02 * Sc[2] + j02 * j02 * Sc[8] + LOWPASS
    B = j00 * j11 * Sc[1] + j00 * j12 * Sc[2] + j02 * j11 * Sc[5] + j02 * j12 * Sc[8]
    C = j11 * j11 * Sc[4] + 2.0 * j11 * j12 * Sc[5] + j12 * j12 * Sc[8] + LOWPASS
    return A, B, C


@njit(cache=True, inline="always")
def axis_column(R, k):
    """Column k (0.0, 1.0 or 2.0) of R, by selects."""
    return ((R[0] if k == 0.0 else (R[1] if k == 1.0 else R[2])),
            (R[3] if k == 0.0 else (R[4] if k == 1.0 else R[5])),
            (R[6] if k == 0.0 else (R[7] if k == 1.0 else R[8])))


@njit(cache=True, inline="always")
def to_camera(W, tw, mx, my, mz, near, far):
    """A world point in the camera frame (tx, ty, tz) and whether its depth is in [near, far]
    (tz is then 1 where it is not, so that lanes divide safely)."""
    tz = W[6] * mx + W[7] * my + W[8] * mz + tw[2]
    ok = (tz >= near) & (tz <= far)
    tz = tz if ok else 1.0
    tx = W[0] * mx + W[1] * my + W[2] * mz + tw[0]
    ty = W[3] * mx + W[4] * my + W[5] * mz + tw[1]
    return tx, ty, tz, ok


@njit(cache=True, inline="always")
def conic_ok(A, B, C, det, cov_alpha, lim_cov):
    """Sigma2d is invertible (det > 0) and, with covariance culling on (cov_alpha > 0), no
    entry exceeds lim_cov."""
    return (det > 0.0) & ((cov_alpha <= 0.0) | (max(abs(A), abs(B), abs(C)) <= lim_cov))


@njit(cache=True, inline="always")
def radius_box(A, B, C, px, py, cut, width, height):
    """Pixel radius ceil(3 sqrt(lambda_max)) of Sigma2d [[A, B], [B, C]] at (px, py), whether
    that radius reaches the image, and the inclusive pixel box (j0, i0, j1, i1, as floats) of
    the centres (j + 0.5) inside the sigma <= cut ellipse's extent, with whether it is empty."""
    lam = 0.5 * (A + C) + math.sqrt(max(0.25 * (A - C) * (A - C) + B * B, 0.0))
    rad = np.ceil(3.0 * math.sqrt(max(lam, 0.0)))
    onscreen = (px + rad > 0.0) & (px - rad < width) & (py + rad > 0.0) & (py - rad < height)
    ex = math.sqrt(max(2.0 * cut * A, 0.0)) * 1.001 + 1e-3
    ey = math.sqrt(max(2.0 * cut * C, 0.0)) * 1.001 + 1e-3
    j0 = max(np.ceil(px - ex - 0.5), 0.0)
    j1 = min(np.floor(px + ex - 0.5), width - 1.0)
    i0 = max(np.ceil(py - ey - 0.5), 0.0)
    i1 = min(np.floor(py + ey - 0.5), height - 1.0)
    return rad, onscreen, j0, i0, j1, i1, (cut <= 0.0) | (j0 > j1) | (i0 > i1)


@njit(cache=True, inline="always")
def camera_normal(W, nx, ny, nz, tx, ty, tz):
    """A world normal in the camera frame (W n) and the sign that turns it to face the camera."""
    cnx = W[0] * nx + W[1] * ny + W[2] * nz
    cny = W[3] * nx + W[4] * ny + W[5] * nz
    cnz = W[6] * nx + W[7] * ny + W[8] * nz
    return cnx, cny, cnz, (-1.0 if cnx * tx + cny * ty + cnz * tz > 0.0 else 1.0)


@njit(cache=True, inline="always")
def put_outputs(buf, j, ok, px, py, A, B, C, det, o, cut, tz, cr, cg, cb, nx, ny, nz, width,
                height):
    """Lane j's output planes (Q_*) for a splat at (px, py) with Sigma2d (A, B, C): the conic,
    colour, camera normal, the pixel box (empty where culled) and the radius (0 where culled,
    ok False or off the image; the other outputs are then meaningless)."""
    r, onscreen, j0, i0, j1, i1, empty = radius_box(A, B, C, px, py, cut, width, height)
    ok = ok & onscreen
    empty = empty | ~ok
    idet = 1.0 / (det if ok else 1.0)
    buf[at(Q_X, j)] = px
    buf[at(Q_Y, j)] = py
    buf[at(Q_A, j)] = C * idet
    buf[at(Q_B, j)] = -B * idet
    buf[at(Q_C, j)] = A * idet
    buf[at(Q_O, j)] = o
    buf[at(Q_CUT, j)] = cut
    buf[at(Q_Z, j)] = tz
    buf[at(Q_R, j)] = cr
    buf[at(Q_G, j)] = cg
    buf[at(Q_BL, j)] = cb
    buf[at(Q_NX, j)] = nx
    buf[at(Q_NY, j)] = ny
    buf[at(Q_NZ, j)] = nz
    buf[at(Q_J0, j)] = 0.0 if empty else j0
    buf[at(Q_I0, j)] = 0.0 if empty else i0
    buf[at(Q_J1, j)] = -1.0 if empty else j1
    buf[at(Q_I1, j)] = -1.0 if empty else i1
    buf[at(Q_RAD, j)] = max(r, 1.0) if ok else 0.0


@njit(cache=True, error_model="numpy")
def forward_lanes(buf, shp, m, W, tw, campos, cam, lims, width, height, near, far, cov_alpha):
    """Forward of lanes 0..m-1: the output planes (Q_*) from the PF_* input planes."""
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    lim_cov = cov_alpha * height * width
    for jj in range(m):
        j = U64(jj)
        mx, my, mz = buf[at(PF_MX, j)], buf[at(PF_MY, j)], buf[at(PF_MZ, j)]
        tx, ty, tz, ok = to_camera(W, tw, mx, my, mz, near, far)
        _w, _x, _y, _z, _n, R = quat_rot(buf[at(PF_QW, j)], buf[at(PF_QX, j)],
                                         buf[at(PF_QY, j)], buf[at(PF_QZ, j)])
        S3, _L = cov3d(R, buf[at(PF_SX, j)], buf[at(PF_SY, j)], buf[at(PF_SZ, j)])
        j00, j02, j11, j12, _txc, _tyc, _cx, _cy = clamped_jacobian(tx, ty, tz, fx, fy, lims)
        A, B, C = sigma2d(camera_cov(W, S3), j00, j02, j11, j12)
        det = A * C - B * B
        ok = ok & conic_ok(A, B, C, det, cov_alpha, lim_cov)
        px = fx * tx / tz + cx
        py = fy * ty / tz + cy
        vx, vy, vz = mx - campos[0], my - campos[1], mz - campos[2]
        vn = max(math.sqrt(vx * vx + vy * vy + vz * vz), 1e-12)
        cr, cg, cb = sh_color_lane(shp, j, vx / vn, vy / vn, vz / vn)
        # normal: the smallest scale's axis in the camera frame, facing the camera
        nx, ny, nz = axis_column(R, buf[at(PF_K, j)])
        cnx, cny, cnz, f = camera_normal(W, nx, ny, nz, tx, ty, tz)
        put_outputs(buf, j, ok, px, py, A, B, C, det, buf[at(PF_O, j)], buf[at(PF_CUT, j)], tz,
                    max(cr, 0.0), max(cg, 0.0), max(cb, 0.0), f * cnx, f * cny, f * cnz,
                    width, height)


@njit(cache=True, error_model="numpy")
def backward_lanes(buf, shp, m, W, tw, campos, cam, lims):
    """VJP of lanes 0..m-1: the PB_DMX .. PB_CB planes (model gradients, and the view
    direction and clamped-colour gradient the caller's SH gradient needs) from the input
    planes."""
    fx, fy = cam[0], cam[1]
    for jj in range(m):
        j = U64(jj)
        mx, my, mz = buf[at(PB_MX, j)], buf[at(PB_MY, j)], buf[at(PB_MZ, j)]
        tx = W[0] * mx + W[1] * my + W[2] * mz + tw[0]
        ty = W[3] * mx + W[4] * my + W[5] * mz + tw[1]
        tz = W[6] * mx + W[7] * my + W[8] * mz + tw[2]
        qw, qx, qy, qz, qn, R = quat_rot(buf[at(PB_QW, j)], buf[at(PB_QX, j)],
                                         buf[at(PB_QY, j)], buf[at(PB_QZ, j)])
        sx, sy, sz = buf[at(PB_SX, j)], buf[at(PB_SY, j)], buf[at(PB_SZ, j)]
        S3, L = cov3d(R, sx, sy, sz)
        Sc = camera_cov(W, S3)
        j00, j02, j11, j12, txc, tyc, cxm, cym = clamped_jacobian(tx, ty, tz, fx, fy, lims)
        A, B, C = sigma2d(Sc, j00, j02, j11, j12)

        o = buf[at(PB_O, j)]
        buf[at(PB_DLOGIT, j)] = buf[at(PB_GO, j)] * o * (1.0 - o)

        # colour -> view direction (the SH gradient itself is written by the caller)
        vx, vy, vz = mx - campos[0], my - campos[1], mz - campos[2]
        vn = max(math.sqrt(vx * vx + vy * vy + vz * vz), 1e-12)
        dx, dy, dz = vx / vn, vy / vn, vz / vn
        cr, cg, cb = sh_color_lane(shp, j, dx, dy, dz)
        gr = buf[at(PB_GR, j)] if cr >= 0.0 else 0.0
        gg = buf[at(PB_GG, j)] if cg >= 0.0 else 0.0
        gb = buf[at(PB_GBL, j)] if cb >= 0.0 else 0.0
        ddx, ddy, ddz = sh_dir_vjp_lane(shp, j, dx, dy, dz, gr, gg, gb)
        dd = ddx * dx + ddy * dy + ddz * dz
        gmx = (ddx - dx * dd) / vn
        gmy = (ddy - dy * dd) / vn
        gmz = (ddz - dz * dd) / vn

        # conic -> Sigma2d -> (J, Sigma_cam) -> Sigma3d -> (R, s)
        G00, G01, G11 = conic_vjp(A, B, C, buf[at(PB_GA, j)], buf[at(PB_GB, j)],
                                  buf[at(PB_GC, j)])
        a0 = G00 * j00
        a1 = G01 * j11
        b0 = G01 * j00
        b1 = G11 * j11
        q0 = G00 * j02 + G01 * j12
        q1 = G01 * j02 + G11 * j12
        GSc = (j00 * a0, j00 * a1, j00 * q0,
               j11 * b0, j11 * b1, j11 * q1,
               j02 * a0 + j12 * b0, j02 * a1 + j12 * b1, j02 * q0 + j12 * q1)
        JS0 = (j00 * Sc[0] + j02 * Sc[6], j00 * Sc[1] + j02 * Sc[7], j00 * Sc[2] + j02 * Sc[8])
        JS1 = (j11 * Sc[3] + j12 * Sc[6], j11 * Sc[4] + j12 * Sc[7], j11 * Sc[5] + j12 * Sc[8])
        gj00 = 2.0 * (G00 * JS0[0] + G01 * JS1[0])
        gj02 = 2.0 * (G00 * JS0[2] + G01 * JS1[2])
        gj11 = 2.0 * (G01 * JS0[1] + G11 * JS1[1])
        gj12 = 2.0 * (G01 * JS0[2] + G11 * JS1[2])
        GS3 = mm3(mm3(tr3(W), GSc), W)
        GS = (GS3[0] + GS3[0], GS3[1] + GS3[3], GS3[2] + GS3[6],
              GS3[3] + GS3[1], GS3[4] + GS3[4], GS3[5] + GS3[7],
              GS3[6] + GS3[2], GS3[7] + GS3[5], GS3[8] + GS3[8])
        GL = mm3(GS, L)
        buf[at(PB_DL0, j)] = (GL[0] * R[0] + GL[3] * R[3] + GL[6] * R[6]) * sx
        buf[at(PB_DL1, j)] = (GL[1] * R[1] + GL[4] * R[4] + GL[7] * R[7]) * sy
        buf[at(PB_DL2, j)] = (GL[2] * R[2] + GL[5] * R[5] + GL[8] * R[8]) * sz

        # normal -> the smallest scale's column of R
        k = buf[at(PB_K, j)]
        nx, ny, nz = axis_column(R, k)
        cnx = W[0] * nx + W[1] * ny + W[2] * nz
        cny = W[3] * nx + W[4] * ny + W[5] * nz
        cnz = W[6] * nx + W[7] * ny + W[8] * nz
        f = -1.0 if cnx * tx + cny * ty + cnz * tz > 0.0 else 1.0
        gnx, gny, gnz = buf[at(PB_GNX, j)], buf[at(PB_GNY, j)], buf[at(PB_GNZ, j)]
        wx = f * (W[0] * gnx + W[3] * gny + W[6] * gnz)
        wy = f * (W[1] * gnx + W[4] * gny + W[7] * gnz)
        wz = f * (W[2] * gnx + W[5] * gny + W[8] * gnz)
        k0 = wx if k == 0.0 else 0.0
        k1 = wx if k == 1.0 else 0.0
        k2 = wx if k == 2.0 else 0.0
        m0 = wy if k == 0.0 else 0.0
        m1 = wy if k == 1.0 else 0.0
        m2 = wy if k == 2.0 else 0.0
        n0 = wz if k == 0.0 else 0.0
        n1 = wz if k == 1.0 else 0.0
        n2 = wz if k == 2.0 else 0.0
        GR = (GL[0] * sx + k0, GL[1] * sy + k1, GL[2] * sz + k2,
              GL[3] * sx + m0, GL[4] * sy + m1, GL[5] * sz + m2,
              GL[6] * sx + n0, GL[7] * sy + n1, GL[8] * sz + n2)
        dqw, dqx, dqy, dqz = quat_rot_vjp(qw, qx, qy, qz, qn, GR)
        buf[at(PB_DQW, j)] = dqw
        buf[at(PB_DQX, j)] = dqx
        buf[at(PB_DQY, j)] = dqy
        buf[at(PB_DQZ, j)] = dqz

        # camera-frame mean: mean2d, depth, and J
        gx2, gy2 = buf[at(PB_GMX, j)], buf[at(PB_GMY, j)]
        iz = 1.0 / tz
        iz2 = iz * iz
        dtx = fx * iz * gx2
        dty = fy * iz * gy2
        dtz = -fx * tx * iz2 * gx2 - fy * ty * iz2 * gy2 + buf[at(PB_GZ, j)]
        dtz += -fx * iz2 * gj00 - fy * iz2 * gj11
        dtxc = -fx * iz2 * gj02
        dtyc = -fy * iz2 * gj12
        dtz += 2.0 * fx * txc * iz2 * iz * gj02 + 2.0 * fy * tyc * iz2 * iz * gj12
        dtz += (dtxc * txc * iz if cxm else 0.0) + (dtyc * tyc * iz if cym else 0.0)
        dtx += 0.0 if cxm else dtxc
        dty += 0.0 if cym else dtyc
        buf[at(PB_DMX, j)] = W[0] * dtx + W[3] * dty + W[6] * dtz + gmx
        buf[at(PB_DMY, j)] = W[1] * dtx + W[4] * dty + W[7] * dtz + gmy
        buf[at(PB_DMZ, j)] = W[2] * dtx + W[5] * dty + W[8] * dtz + gmz
        buf[at(PB_DX, j)] = dx
        buf[at(PB_DY, j)] = dy
        buf[at(PB_DZ, j)] = dz
        buf[at(PB_CR, j)] = gr
        buf[at(PB_CG, j)] = gg
        buf[at(PB_CB, j)] = gb


@njit(cache=True, inline="always")
def sh_grad_row(d_sh, i, k3, dx, dy, dz, gr, gg, gb):
    """d_sh[i, k, c] = basis_k(d) g_c for the first k3 / 3 coefficients."""
    bs = sh_basis(dx, dy, dz)
    for k in range(k3 // 3):
        d_sh[i, k, 0] = bs[k] * gr
        d_sh[i, k, 1] = bs[k] * gg
        d_sh[i, k, 2] = bs[k] * gb


assert (PF_MX, PF_MY, PF_MZ, PF_QW, PF_QX, PF_QY, PF_QZ, PF_SX, PF_SY, PF_SZ, PF_O) == tuple(range(11))
assert (PB_MX, PB_MY, PB_MZ, PB_QW, PB_QX, PB_QY, PB_QZ, PB_SX, PB_SY, PB_SZ, PB_O) == tuple(range(11))


# input planes of the env path's forward (cached world covariances, normals and colours)
(PS_MX, PS_MY, PS_MZ, PS_S00, PS_S01, PS_S02, PS_S11, PS_S12, PS_S22, PS_CUT, PS_NX, PS_NY,
 PS_NZ, PS_R, PS_G, PS_BL, PS_O) = range(17)


@njit(cache=True, error_model="numpy")
def static_lanes(buf, shp, m, deg, W, tw, campos, cam, lims, width, height, near, far,
                 cov_alpha):
    """The env path's projection (`env_scene_kernels.project_static`) of lanes 0..m-1: the
    output planes (Q_*) from the PS_* input planes, with the same arithmetic in the same order
    as its one-splat form had (the same bits) and the culling tests as selects. deg 0 takes
    the cached colours (PS_R .. PS_BL) unclamped."""
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    lxp, lxn, lyp, lyn = lims
    lim_cov = cov_alpha * height * width
    for jj in range(m):
        j = U64(jj)
        mx, my, mz = buf[at(PS_MX, j)], buf[at(PS_MY, j)], buf[at(PS_MZ, j)]
        tx, ty, tz, ok = to_camera(W, tw, mx, my, mz, near, far)
        iz = 1.0 / tz
        rx = min(max(tx * iz, -lxn), lxp)
        ry = min(max(ty * iz, -lyn), lyp)
        j00 = fx * iz
        j11 = fy * iz
        j02 = -fx * rx * iz
        j12 = -fy * ry * iz
        A, B, C = screen_cov(W, j00, j02, j11, j12, buf[at(PS_S00, j)], buf[at(PS_S01, j)],
                             buf[at(PS_S02, j)], buf[at(PS_S11, j)], buf[at(PS_S12, j)],
                             buf[at(PS_S22, j)])
        det = A * C - B * B
        ok = ok & conic_ok(A, B, C, det, cov_alpha, lim_cov)
        px = fx * tx * iz + cx
        py = fy * ty * iz + cy
        vx, vy, vz = mx - campos[0], my - campos[1], mz - campos[2]
        vn = max(math.sqrt(vx * vx + vy * vy + vz * vz), 1e-12)
        cr, cg, cb = sh_color_lane(shp, j, vx / vn, vy / vn, vz / vn)
        cnx, cny, cnz, f = camera_normal(W, buf[at(PS_NX, j)], buf[at(PS_NY, j)],
                                         buf[at(PS_NZ, j)], tx, ty, tz)
        put_outputs(buf, j, ok, px, py, A, B, C, det, buf[at(PS_O, j)], buf[at(PS_CUT, j)], tz,
                    buf[at(PS_R, j)] if deg == 0 else max(cr, 0.0),
                    buf[at(PS_G, j)] if deg == 0 else max(cg, 0.0),
                    buf[at(PS_BL, j)] if deg == 0 else max(cb, 0.0), f * cnx, f * cny, f * cnz,
                    width, height)

