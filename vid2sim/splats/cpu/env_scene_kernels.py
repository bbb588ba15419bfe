"""Numba kernels of the forward-only static-scene path: cell frustum culling, projection
of a selected list of cached Gaussians (world covariances, opacities, normals, colours),
and the image finish. All write into caller-owned (reused) buffers."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from ._geom import jac_limits
from ._project_planes import (NQ, PCH, PS_CUT, PS_MX, PS_MY, PS_MZ, PS_NX, PS_O, PS_R, PS_S00,
                              U64, at, gather_sh, lane_buffers, sh_layout, static_lanes)
from ._sched import CHUNK, fetch_add, n_chunks, new_counter
from .project import F_X, F_Y, scatter_rows, sigma_cut, view_parts

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
def static_chunk(r0, m, sel, means, cov, opacity, cut, normal_w, rgb, shf, ks, k3, deg, W, tw,
                 campos, cam, lims, width, height, near, far, cov_alpha, fo, box, radii, normals,
                 buf, shp):
    """Rows r0 .. r0+m-1 (m <= PCH) of project_static: gather Gaussians sel[r] into lanes,
    project them (`static_lanes`), scatter the rows. normals=False leaves fo's normal
    columns unwritten."""
    for jj in range(m):
        i = sel[r0 + jj]
        j = U64(jj)
        buf[at(PS_MX, j)] = means[i, 0]
        buf[at(PS_MY, j)] = means[i, 1]
        buf[at(PS_MZ, j)] = means[i, 2]
        for q in range(6):
            buf[at(PS_S00 + q, j)] = cov[i, q]
        buf[at(PS_CUT, j)] = cut[i]
        buf[at(PS_O, j)] = opacity[i]
        for q in range(3):
            buf[at(PS_NX + q, j)] = normal_w[i, q]
            buf[at(PS_R + q, j)] = rgb[i, q]
        if deg > 0:
            gather_sh(shp, shf, i * ks, k3, j)
    static_lanes(buf, shp, m, deg, W, tw, campos, cam, lims, np.float64(width),
                 np.float64(height), near, far, cov_alpha)
    scatter_rows(buf, m, r0, fo, box, radii, normals)


@njit(parallel=True, cache=True)
def project_static(sel, n_sel, means, cov, opacity, cut, normal_w, rgb, sh, deg, view, campos,
                   cam, width, height, near, far, cov_alpha, fo, box, radii, n_workers=1):
    """Project Gaussians sel[:n_sel]; row r holds Gaussian sel[r]: fo [R, NF] (as
    project_forward), box [R, 4] pixel box (empty, j1 < j0, when it reaches no pixel or is
    culled) and radii [R] (0 = culled). Same math as project.project_forward, with
    Sigma2d = (J W) Sigma3d (J W)^T evaluated directly from the cached world covariance."""
    W, tw = view_parts(view)
    lims = jac_limits(cam[0], cam[1], cam[2], cam[3], width, height)
    shf, ks, k3 = sh_layout(sh, deg)
    n_items = n_chunks(n_sel, CHUNK)
    nxt = new_counter()
    for _h in prange(n_workers):
        buf, shp = lane_buffers(NQ)
        while True:
            ch = fetch_add(nxt, 1)
            if ch >= n_items:
                break
            end = min(n_sel, (ch + 1) * CHUNK)
            for r0 in range(ch * CHUNK, end, PCH):
                static_chunk(r0, min(PCH, end - r0), sel, means, cov, opacity, cut, normal_w,
                             rgb, shf, ks, k3, deg, W, tw, campos, cam, lims, width, height,
                             near, far, cov_alpha, fo, box, radii, True, buf, shp)


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
