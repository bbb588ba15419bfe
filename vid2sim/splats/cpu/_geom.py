"""Per-splat projection math (docs/splat_renderer.md steps 3-8) and its hand-written VJP.

Scalar numba device functions in float64; 3x3 matrices are row-major 9-tuples.
"""

from __future__ import annotations

import math

from numba import njit

LOWPASS = 0.3
FOV_CLAMP = 0.3


@njit(cache=True)
def quat_rot(qw, qx, qy, qz):
    """Normalised quaternion (w, x, y, z), its norm, and R as a 9-tuple."""
    n = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    inv = 1.0 / max(n, 1e-12)
    w, x, y, z = qw * inv, qx * inv, qy * inv, qz * inv
    R = (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
         2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
         2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y))
    return w, x, y, z, n, R


@njit(cache=True)
def quat_rot_vjp(w, x, y, z, n, G):
    """dL/dq (unnormalised quaternion) from dL/dR (9-tuple G) and the normalised q."""
    gw = 2.0 * (-z * G[1] + y * G[2] + z * G[3] - x * G[5] - y * G[6] + x * G[7])
    gx = 2.0 * (y * G[1] + z * G[2] + y * G[3] - 2.0 * x * G[4] - w * G[5] + z * G[6]
                + w * G[7] - 2.0 * x * G[8])
    gy = 2.0 * (-2.0 * y * G[0] + x * G[1] + w * G[2] + x * G[3] + z * G[5] - w * G[6]
                + z * G[7] - 2.0 * y * G[8])
    gz = 2.0 * (-2.0 * z * G[0] - w * G[1] + x * G[2] + w * G[3] - 2.0 * z * G[4]
                + y * G[5] + x * G[6] + y * G[7])
    dot = w * gw + x * gx + y * gy + z * gz
    inv = 1.0 / max(n, 1e-12)
    return (gw - w * dot) * inv, (gx - x * dot) * inv, (gy - y * dot) * inv, (gz - z * dot) * inv


@njit(cache=True)
def mm3(a, b):
    """a @ b for 9-tuples."""
    return (a[0] * b[0] + a[1] * b[3] + a[2] * b[6], a[0] * b[1] + a[1] * b[4] + a[2] * b[7],
            a[0] * b[2] + a[1] * b[5] + a[2] * b[8],
            a[3] * b[0] + a[4] * b[3] + a[5] * b[6], a[3] * b[1] + a[4] * b[4] + a[5] * b[7],
            a[3] * b[2] + a[4] * b[5] + a[5] * b[8],
            a[6] * b[0] + a[7] * b[3] + a[8] * b[6], a[6] * b[1] + a[7] * b[4] + a[8] * b[7],
            a[6] * b[2] + a[7] * b[5] + a[8] * b[8])


@njit(cache=True)
def tr3(a):
    """Transpose of a 9-tuple."""
    return (a[0], a[3], a[6], a[1], a[4], a[7], a[2], a[5], a[8])


@njit(cache=True)
def cov3d(R, sx, sy, sz):
    """Sigma3d = R S S^T R^T as a 9-tuple, with L = R S."""
    L = (R[0] * sx, R[1] * sy, R[2] * sz, R[3] * sx, R[4] * sy, R[5] * sz,
         R[6] * sx, R[7] * sy, R[8] * sz)
    return mm3(L, tr3(L)), L


@njit(cache=True)
def jac_limits(fx, fy, cx, cy, width, height):
    """gsplat's clamp limits (lim_x+, lim_x-, lim_y+, lim_y-) on t_x/t_z and t_y/t_z."""
    lxp = (width - cx) / fx + FOV_CLAMP * (0.5 * width / fx)
    lxn = cx / fx + FOV_CLAMP * (0.5 * width / fx)
    lyp = (height - cy) / fy + FOV_CLAMP * (0.5 * height / fy)
    lyn = cy / fy + FOV_CLAMP * (0.5 * height / fy)
    return lxp, lxn, lyp, lyn


@njit(cache=True)
def conic_vjp(A, B, C, ga, gb, gc):
    """dL/d(Sigma2d) as a symmetric matrix (G00, G01, G11) from dL/d(conic a, b, c).

    conic = Sigma2d^-1; b appears once in sigma (b dx dy), so dL/dK01 = dL/dK10 = gb/2.
    """
    det = A * C - B * B
    k00, k01, k11 = C / det, -B / det, A / det
    h = 0.5 * gb
    # G_sigma = -K G_K K
    t00 = ga * k00 + h * k01
    t01 = ga * k01 + h * k11
    t10 = h * k00 + gc * k01
    t11 = h * k01 + gc * k11
    g00 = -(k00 * t00 + k01 * t10)
    g01 = -(k00 * t01 + k01 * t11)
    g11 = -(k01 * t01 + k11 * t11)
    return g00, g01, g11


@njit(cache=True, inline="always")
def screen_cov(W, j00, j02, j11, j12, s00, s01, s02, s11, s12, s22):
    """Screen-space 2D covariance (A, B, C) + low-pass of a world covariance (upper triangle
    s00..s22) under the projection Jacobian rows J (j00, j02; j11, j12) times the view rotation
    W [9]: rows u, v of J W, then (J W) S (J W)^T. Inlined into the exact and fast kernels."""
    u0, u1, u2 = j00 * W[0] + j02 * W[6], j00 * W[1] + j02 * W[7], j00 * W[2] + j02 * W[8]
    v0, v1, v2 = j11 * W[3] + j12 * W[6], j11 * W[4] + j12 * W[7], j11 * W[5] + j12 * W[8]
    su0 = s00 * u0 + s01 * u1 + s02 * u2
    su1 = s01 * u0 + s11 * u1 + s12 * u2
    su2 = s02 * u0 + s12 * u1 + s22 * u2
    A = u0 * su0 + u1 * su1 + u2 * su2 + LOWPASS
    B = v0 * su0 + v1 * su1 + v2 * su2
    C = (v0 * (s00 * v0 + s01 * v1 + s02 * v2) + v1 * (s01 * v0 + s11 * v1 + s12 * v2)
         + v2 * (s02 * v0 + s12 * v1 + s22 * v2) + LOWPASS)
    return A, B, C


@njit(cache=True, inline="always")
def pixel_box(mx, my, cut, A, C, width, height, box, row):
    """Write into box[row] the inclusive pixel box (j0, i0, j1, i1) of centres inside the
    cut-off ellipse of a splat at (mx, my) with covariance diagonal (A, C); box is left
    untouched when cut <= 0 or the box misses the image (callers pre-fill it empty)."""
    if cut <= 0.0:
        return
    ex = math.sqrt(2.0 * cut * A) * 1.001 + 1e-3
    ey = math.sqrt(2.0 * cut * C) * 1.001 + 1e-3
    j0 = max(math.ceil(mx - ex - 0.5), 0)
    j1 = min(math.floor(mx + ex - 0.5), width - 1)
    i0 = max(math.ceil(my - ey - 0.5), 0)
    i1 = min(math.floor(my + ey - 0.5), height - 1)
    if j0 <= j1 and i0 <= i1:
        box[row, 0] = j0
        box[row, 1] = i0
        box[row, 2] = j1
        box[row, 3] = i1
