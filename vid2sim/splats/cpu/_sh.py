"""Real SH (3DGS constants) evaluation and its vector-Jacobian product, as numba device functions.

Colours are evaluated per splat and channel; `sh` rows are [K, 3] float32.
"""

from __future__ import annotations

from numba import njit

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C20, C21, C22, C23, C24 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
                           -1.0925484305920792, 0.5462742152960396)
C30, C31, C32, C33, C34, C35, C36 = (-0.5900435899266435, 2.890611442640554,
                                     -0.4570457994644658, 0.3731763325901154,
                                     -0.4570457994644658, 1.445305721320277,
                                     -0.5900435899266435)


@njit(cache=True)
def sh_basis(x, y, z):
    """All 16 basis values (degrees 0..3) for unit direction (x, y, z); callers use the first K."""
    xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
    return (C0, -C1 * y, C1 * z, -C1 * x,
            C20 * xy, C21 * yz, C22 * (2.0 * zz - xx - yy), C23 * xz, C24 * (xx - yy),
            C30 * y * (3.0 * xx - yy), C31 * xy * z, C32 * y * (4.0 * zz - xx - yy),
            C33 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy), C34 * x * (4.0 * zz - xx - yy),
            C35 * z * (xx - yy), C36 * x * (xx - 3.0 * yy))


@njit(cache=True, inline="always")
def _acc(r, g, b, v, shrow, k):
    return r + v * shrow[k, 0], g + v * shrow[k, 1], b + v * shrow[k, 2]


@njit(cache=True, inline="always")
def sh_color(deg, shrow, x, y, z):
    """Raw colour SH(d) + 0.5 per channel (callers clamp at 0); shrow [K, 3]. Same terms,
    same order as summing sh_basis(x, y, z)[k] * shrow[k] for k = 0 .. (deg+1)^2 - 1,
    unrolled per band (no basis tuple indexed at run time)."""
    r = C0 * shrow[0, 0]
    g = C0 * shrow[0, 1]
    b = C0 * shrow[0, 2]
    if deg >= 1:
        r, g, b = _acc(r, g, b, -C1 * y, shrow, 1)
        r, g, b = _acc(r, g, b, C1 * z, shrow, 2)
        r, g, b = _acc(r, g, b, -C1 * x, shrow, 3)
    if deg >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        r, g, b = _acc(r, g, b, C20 * xy, shrow, 4)
        r, g, b = _acc(r, g, b, C21 * yz, shrow, 5)
        r, g, b = _acc(r, g, b, C22 * (2.0 * zz - xx - yy), shrow, 6)
        r, g, b = _acc(r, g, b, C23 * xz, shrow, 7)
        r, g, b = _acc(r, g, b, C24 * (xx - yy), shrow, 8)
        if deg >= 3:
            r, g, b = _acc(r, g, b, C30 * y * (3.0 * xx - yy), shrow, 9)
            r, g, b = _acc(r, g, b, C31 * xy * z, shrow, 10)
            r, g, b = _acc(r, g, b, C32 * y * (4.0 * zz - xx - yy), shrow, 11)
            r, g, b = _acc(r, g, b, C33 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy), shrow, 12)
            r, g, b = _acc(r, g, b, C34 * x * (4.0 * zz - xx - yy), shrow, 13)
            r, g, b = _acc(r, g, b, C35 * z * (xx - yy), shrow, 14)
            r, g, b = _acc(r, g, b, C36 * x * (xx - 3.0 * yy), shrow, 15)
    return r + 0.5, g + 0.5, b + 0.5


@njit(cache=True)
def _dot(shrow, k, gr, gg, gb):
    return shrow[k, 0] * gr + shrow[k, 1] * gg + shrow[k, 2] * gb


@njit(cache=True)
def sh_dir_vjp(deg, shrow, x, y, z, gr, gg, gb):
    """d(colour . g)/d(direction) for unit direction (x, y, z) (before normalisation)."""
    dx = 0.0
    dy = 0.0
    dz = 0.0
    if deg < 1:
        return dx, dy, dz
    s1, s2, s3 = _dot(shrow, 1, gr, gg, gb), _dot(shrow, 2, gr, gg, gb), _dot(shrow, 3, gr, gg, gb)
    dy += -C1 * s1
    dz += C1 * s2
    dx += -C1 * s3
    if deg >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        s4, s5, s6 = _dot(shrow, 4, gr, gg, gb), _dot(shrow, 5, gr, gg, gb), _dot(shrow, 6, gr, gg, gb)
        s7, s8 = _dot(shrow, 7, gr, gg, gb), _dot(shrow, 8, gr, gg, gb)
        dx += C20 * y * s4 + (-2.0 * C22 * x) * s6 + C23 * z * s7 + 2.0 * C24 * x * s8
        dy += C20 * x * s4 + C21 * z * s5 + (-2.0 * C22 * y) * s6 - 2.0 * C24 * y * s8
        dz += C21 * y * s5 + 4.0 * C22 * z * s6 + C23 * x * s7
        if deg >= 3:
            s9, s10 = _dot(shrow, 9, gr, gg, gb), _dot(shrow, 10, gr, gg, gb)
            s11, s12 = _dot(shrow, 11, gr, gg, gb), _dot(shrow, 12, gr, gg, gb)
            s13, s14 = _dot(shrow, 13, gr, gg, gb), _dot(shrow, 14, gr, gg, gb)
            s15 = _dot(shrow, 15, gr, gg, gb)
            dx += (6.0 * C30 * xy * s9 + C31 * yz * s10 - 2.0 * C32 * xy * s11
                   - 6.0 * C33 * xz * s12 + C34 * (4.0 * zz - 3.0 * xx - yy) * s13
                   + 2.0 * C35 * xz * s14 + C36 * (3.0 * xx - 3.0 * yy) * s15)
            dy += (C30 * (3.0 * xx - 3.0 * yy) * s9 + C31 * xz * s10
                   + C32 * (4.0 * zz - xx - 3.0 * yy) * s11 - 6.0 * C33 * yz * s12
                   - 2.0 * C34 * xy * s13 - 2.0 * C35 * yz * s14 - 6.0 * C36 * xy * s15)
            dz += (C31 * xy * s10 + 8.0 * C32 * yz * s11
                   + C33 * (6.0 * zz - 3.0 * xx - 3.0 * yy) * s12 + 8.0 * C34 * xz * s13
                   + C35 * (xx - yy) * s14)
    return dx, dy, dz
