"""Numba kernels of the forward-only static-scene path: cell frustum culling and
projection from cached world-frame covariances, opacities, normals and DC colours."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ._geom import jac_limits, mm3, tr3
from ._sh import sh_color
from .preprocess import (F_BL, F_G, F_NX, F_NY, F_NZ, F_R, cam_normal, screen_and_box, sigma_cut,
                         view_parts)

EDGE_MARGIN_PX = 3.0  # low-pass dilation (<= 1.65 px at 3 sigma) + pixel-centre rounding


@njit(cache=True)
def cull_cells(centers, r_means, rho, view, cam, width, height, near, far):
    """Indices of cells [C] whose splats may be visible.

    A cell is dropped when all its means are outside [near, far], or when every splat's
    sigma<=cut ellipsoid (radius rho) lies outside a side plane widened so that the
    linearised (clamped-Jacobian) projection of such a splat cannot reach the image.
    """
    W, tw = view_parts(view)
    fx, fy, cx, cy = cam[0], cam[1], cam[2], cam[3]
    lxp, lxn, lyp, lyn = jac_limits(fx, fy, cx, cy, width, height)
    grow = math.sqrt(1.0 + max(lxp, lxn, lyp, lyn) ** 2)
    planes = ((width - cx + EDGE_MARGIN_PX) / fx, (cx + EDGE_MARGIN_PX) / fx,
              (height - cy + EDGE_MARGIN_PX) / fy, (cy + EDGE_MARGIN_PX) / fy)
    keep = np.empty(centers.shape[0], np.int64)
    nk = 0
    for c in range(centers.shape[0]):
        x, y, z = centers[c, 0], centers[c, 1], centers[c, 2]
        tx = W[0] * x + W[1] * y + W[2] * z + tw[0]
        ty = W[3] * x + W[4] * y + W[5] * z + tw[1]
        tz = W[6] * x + W[7] * y + W[8] * z + tw[2]
        rm = r_means[c]
        if tz + rm < near or tz - rm > far:
            continue
        ext = rho[c] * grow
        out = False
        for q in range(4):
            a = planes[q]
            u = tx if q == 0 else (-tx if q == 1 else (ty if q == 2 else -ty))
            if u - a * tz > rm * math.sqrt(1.0 + a * a) + ext:
                out = True
        if not out:
            keep[nk] = c
            nk += 1
    return keep[:nk]


@njit(parallel=True, cache=True)
def project_static(cells, cell_start, row_start, means, cov, opacity, cut, normal_w, rgb, sh, deg,
                   view, campos, cam, width, height, near, far, cov_alpha, fo, box, radii,
                   src):
    """Project the splats of the kept cells; row row_start[j] + k holds splat
    cell_start[cells[j]] + k. Writes fo/box/radii like project_forward and src (splat index)."""
    W, tw = view_parts(view)
    WT = tr3(W)
    lims = jac_limits(cam[0], cam[1], cam[2], cam[3], width, height)
    for j in prange(cells.shape[0]):
        c = cells[j]
        s0 = cell_start[c]
        for k in range(cell_start[c + 1] - s0):
            i = s0 + k
            r_ = row_start[j] + k
            src[r_] = i
            radii[r_] = 0
            mx, my, mz = means[i, 0], means[i, 1], means[i, 2]
            tz = W[6] * mx + W[7] * my + W[8] * mz + tw[2]
            if not (tz >= near and tz <= far):
                continue
            tx = W[0] * mx + W[1] * my + W[2] * mz + tw[0]
            ty = W[3] * mx + W[4] * my + W[5] * mz + tw[1]
            S3 = (cov[i, 0], cov[i, 1], cov[i, 2], cov[i, 1], cov[i, 3], cov[i, 4],
                  cov[i, 2], cov[i, 4], cov[i, 5])
            Sc = mm3(mm3(W, S3), WT)
            t = (tx, ty, tz)
            rad = screen_and_box(t, Sc, opacity[i], cut[i], cam, lims, cov_alpha, width, height, fo,
                                 r_, box)
            radii[r_] = rad
            if rad == 0:
                continue
            if deg == 0:
                fo[r_, F_R] = rgb[i, 0]
                fo[r_, F_G] = rgb[i, 1]
                fo[r_, F_BL] = rgb[i, 2]
            else:
                vx, vy, vz = mx - campos[0], my - campos[1], mz - campos[2]
                vn = max(math.sqrt(vx * vx + vy * vy + vz * vz), 1e-12)
                cr, cg, cb = sh_color(deg, sh[i], vx / vn, vy / vn, vz / vn)
                fo[r_, F_R] = max(cr, 0.0)
                fo[r_, F_G] = max(cg, 0.0)
                fo[r_, F_BL] = max(cb, 0.0)
            Rn = (normal_w[i, 0], 0.0, 0.0, normal_w[i, 1], 0.0, 0.0, normal_w[i, 2], 0.0, 0.0)
            nx, ny, nz, f = cam_normal(Rn, 0, W, t)
            fo[r_, F_NX] = nx
            fo[r_, F_NY] = ny
            fo[r_, F_NZ] = nz


@njit(cache=True)
def compact(fo, box, radii, src):
    """Rows with radii > 0: (fo [V, NF], box [V, 4], splat index [V]) in row order."""
    n = 0
    for r in range(radii.shape[0]):
        if radii[r] > 0:
            n += 1
    fo_v = np.empty((n, fo.shape[1]), np.float32)
    box_v = np.empty((n, 4), np.int32)
    ids = np.empty(n, np.int64)
    j = 0
    for r in range(radii.shape[0]):
        if radii[r] > 0:
            fo_v[j] = fo[r]
            box_v[j] = box[r]
            ids[j] = src[r]
            j += 1
    return fo_v, box_v, ids


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
def scatter_visible(fo_v, ids, index, radii, num, means2d, radii_out):
    """means2d [num, 2] / radii_out [num] in model order from the projected rows."""
    means2d[:] = 0.0
    radii_out[:] = 0
    j = 0
    for r in range(radii.shape[0]):
        if radii[r] > 0:
            m = index[ids[j]]
            means2d[m, 0] = fo_v[j, 0]
            means2d[m, 1] = fo_v[j, 1]
            radii_out[m] = radii[r]
            j += 1


@njit(cache=True)
def sigma_cuts(opacity):
    """sigma_cut for every splat [N] (float64)."""
    out = np.empty(opacity.shape[0], np.float64)
    for i in range(opacity.shape[0]):
        out[i] = sigma_cut(opacity[i])
    return out
