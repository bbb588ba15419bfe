"""Numba kernels of the forward-only static-scene path: cell frustum culling, projection
of a selected list of cached Gaussians (world covariances, opacities, normals, colours),
and the image finish. All write into caller-owned (reused) buffers."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ._geom import jac_limits, pixel_box, screen_cov
from ._sched import CHUNK, fetch_add, n_chunks, new_counter
from ._sh import sh_color
from .project import (F_A, F_B, F_BL, F_C, F_CUT, F_G, F_NX, F_NY, F_NZ, F_O, F_R, F_X, F_Y,
                      F_Z, sigma_cut, view_parts)

EDGE_MARGIN_PX = 3.0  # low-pass dilation (<= 1.65 px at 3 sigma) + pixel-centre rounding


@njit(cache=True)
def frustum_planes(view, cam, width, height):
    """(W, tw, side-plane slopes (x+, x-, y+, y-), extent growth factor) for sphere tests."""
    W, tw = view_parts(view)
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    lxp, lxn, lyp, lyn = jac_limits(fx, fy, cx, cy, width, height)
    grow = math.sqrt(1.0 + max(lxp, lxn, lyp, lyn) ** 2)
    planes = ((width - cx + EDGE_MARGIN_PX) / fx, (cx + EDGE_MARGIN_PX) / fx,
              (height - cy + EDGE_MARGIN_PX) / fy, (cy + EDGE_MARGIN_PX) / fy)
    return W, tw, planes, grow


@njit(cache=True)
def sphere_outside(x, y, z, rm, rho, W, tw, planes, grow, near, far):
    """True when no splat with mean within rm of (x, y, z) and sigma<=cut extent <= rho can
    reach the image: all means outside [near, far], or the widened extent is beyond a side
    plane (so the linearised, clamped-Jacobian projection cannot reach the image)."""
    tx = W[0] * x + W[1] * y + W[2] * z + tw[0]
    ty = W[3] * x + W[4] * y + W[5] * z + tw[1]
    tz = W[6] * x + W[7] * y + W[8] * z + tw[2]
    if tz + rm < near or tz - rm > far:
        return True
    ext = rho * grow
    for q in range(4):
        a = planes[q]
        u = tx if q == 0 else (-tx if q == 1 else (ty if q == 2 else -ty))
        if u - a * tz > rm * math.sqrt(1.0 + a * a) + ext:
            return True
    return False


@njit(cache=True)
def cull_cells(centers, r_means, rho, cell_start, view, cam, width, height, near, far, sel):
    """Write into sel the splat indices of every cell that may be visible; returns the count."""
    W, tw, planes, grow = frustum_planes(view, cam, width, height)
    n = 0
    for c in range(centers.shape[0]):
        if sphere_outside(centers[c, 0], centers[c, 1], centers[c, 2], r_means[c], rho[c], W,
                          tw, planes, grow, near, far):
            continue
        for i in range(cell_start[c], cell_start[c + 1]):
            sel[n] = i
            n += 1
    return n


@njit(cache=True)
def _set_empty(box, r):
    box[r, 0] = 0
    box[r, 1] = 0
    box[r, 2] = -1
    box[r, 3] = -1


@njit(cache=True, inline="always")
def _static_one(r, sel, means, cov, opacity, cut, normal_w, rgb, sh, deg, W, tw, campos, cam,
                lims, width, height, near, far, cov_alpha, fo, box, radii, normals=True):
    """project_static for row r (normals=False leaves fo's normal columns unwritten)."""
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    lxp, lxn, lyp, lyn = lims
    i = sel[r]
    radii[r] = 0
    _set_empty(box, r)
    mx, my, mz = means[i, 0], means[i, 1], means[i, 2]
    tz = W[6] * mx + W[7] * my + W[8] * mz + tw[2]
    if not (tz >= near and tz <= far):
        return
    tx = W[0] * mx + W[1] * my + W[2] * mz + tw[0]
    ty = W[3] * mx + W[4] * my + W[5] * mz + tw[1]
    iz = 1.0 / tz
    rx = min(max(tx * iz, -lxn), lxp)
    ry = min(max(ty * iz, -lyn), lyp)
    j00 = fx * iz
    j11 = fy * iz
    j02 = -fx * rx * iz
    j12 = -fy * ry * iz
    s00, s01, s02 = cov[i, 0], cov[i, 1], cov[i, 2]
    s11, s12, s22 = cov[i, 3], cov[i, 4], cov[i, 5]
    A, B, C = screen_cov(W, j00, j02, j11, j12, s00, s01, s02, s11, s12, s22)
    det = A * C - B * B
    if not det > 0.0:
        return
    if cov_alpha > 0.0 and max(abs(A), abs(B), abs(C)) > cov_alpha * height * width:
        return
    px = fx * tx * iz + cx
    py = fy * ty * iz + cy
    lam = 0.5 * (A + C) + math.sqrt(max(0.25 * (A - C) * (A - C) + B * B, 0.0))
    rad = math.ceil(3.0 * math.sqrt(max(lam, 0.0)))
    if px + rad <= 0.0 or px - rad >= width or py + rad <= 0.0 or py - rad >= height:
        return
    radii[r] = max(rad, 1)
    ct = cut[i]
    idet = 1.0 / det
    fo[r, F_X] = px
    fo[r, F_Y] = py
    fo[r, F_A] = C * idet
    fo[r, F_B] = -B * idet
    fo[r, F_C] = A * idet
    fo[r, F_O] = opacity[i]
    fo[r, F_CUT] = ct
    fo[r, F_Z] = tz
    pixel_box(px, py, ct, A, C, width, height, box, r)
    if deg == 0:
        fo[r, F_R] = rgb[i, 0]
        fo[r, F_G] = rgb[i, 1]
        fo[r, F_BL] = rgb[i, 2]
    else:
        vx, vy, vz = mx - campos[0], my - campos[1], mz - campos[2]
        vn = max(math.sqrt(vx * vx + vy * vy + vz * vz), 1e-12)
        cr, cg, cb = sh_color(deg, sh[i], vx / vn, vy / vn, vz / vn)
        fo[r, F_R] = max(cr, 0.0)
        fo[r, F_G] = max(cg, 0.0)
        fo[r, F_BL] = max(cb, 0.0)
    if not normals:
        return
    nx, ny, nz = normal_w[i, 0], normal_w[i, 1], normal_w[i, 2]
    cnx = W[0] * nx + W[1] * ny + W[2] * nz
    cny = W[3] * nx + W[4] * ny + W[5] * nz
    cnz = W[6] * nx + W[7] * ny + W[8] * nz
    f = -1.0 if cnx * tx + cny * ty + cnz * tz > 0.0 else 1.0
    fo[r, F_NX] = f * cnx
    fo[r, F_NY] = f * cny
    fo[r, F_NZ] = f * cnz


@njit(parallel=True, cache=True)
def project_static(sel, n_sel, means, cov, opacity, cut, normal_w, rgb, sh, deg, view, campos,
                   cam, width, height, near, far, cov_alpha, fo, box, radii, n_workers=1):
    """Project Gaussians sel[:n_sel]; row r holds Gaussian sel[r]: fo [R, NF] (as
    project_forward), box [R, 4] pixel box (empty, j1 < j0, when it reaches no pixel or is
    culled) and radii [R] (0 = culled). Same math as project.project_forward, with
    Sigma2d = (J W) Sigma3d (J W)^T evaluated directly from the cached world covariance."""
    W, tw = view_parts(view)
    lims = jac_limits(cam[0], cam[1], cam[2], cam[3], width, height)
    n_items = n_chunks(n_sel, CHUNK)
    nxt = new_counter()
    for _h in prange(n_workers):
        while True:
            ch = fetch_add(nxt, 1)
            if ch >= n_items:
                break
            for r in range(ch * CHUNK, min(n_sel, (ch + 1) * CHUNK)):
                _static_one(r, sel, means, cov, opacity, cut, normal_w, rgb, sh, deg, W, tw,
                            campos, cam, lims, width, height, near, far, cov_alpha, fo, box,
                            radii)


@njit(cache=True)
def finish_images(color, alpha, depth_acc, normal_acc, bg, rgb, depth, normal):
    """render.finish in numba: rgb over bg, depth = depth_acc / alpha, unit normals."""
    H, W = alpha.shape
    for i in range(H):
        for j in range(W):
            a = alpha[i, j]
            for c in range(3):
                rgb[i, j, c] = color[i, j, c] + (1.0 - a) * bg[c]
            covered = a > 0.0
            depth[i, j] = depth_acc[i, j] / max(a, 1e-6) if covered else 0.0
            nx, ny, nz = normal_acc[i, j, 0], normal_acc[i, j, 1], normal_acc[i, j, 2]
            nn = np.sqrt(nx * nx + ny * ny + nz * nz)
            if covered and nn > 0.0:
                inv = 1.0 / max(nn, 1e-12)
                normal[i, j, 0] = nx * inv
                normal[i, j, 1] = ny * inv
                normal[i, j, 2] = nz * inv
            else:
                normal[i, j, 0] = 0.0
                normal[i, j, 1] = 0.0
                normal[i, j, 2] = 0.0


@njit(cache=True)
def scatter_visible(fo, sel, n_sel, radii, index, num, means2d, radii_out):
    """means2d [num, 2] / radii_out [num] in model order from rows r < n_sel with
    radii > 0 and sel[r] < len(index) (merged LOD Gaussians have no model index)."""
    means2d[:] = 0.0
    radii_out[:] = 0
    K = index.shape[0]
    for r in range(n_sel):
        if radii[r] > 0 and sel[r] < K:
            m = index[sel[r]]
            means2d[m, 0] = fo[r, F_X]
            means2d[m, 1] = fo[r, F_Y]
            radii_out[m] = radii[r]


@njit(cache=True)
def sigma_cuts(opacity):
    """sigma_cut for every splat [N] (float64)."""
    out = np.empty(opacity.shape[0], np.float64)
    for i in range(opacity.shape[0]):
        out[i] = sigma_cut(opacity[i])
    return out
