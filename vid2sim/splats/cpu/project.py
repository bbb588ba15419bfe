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

from ._geom import jac_limits
from ._project_planes import (NQ, PB, PB_CB, PB_CG, PB_CR, PB_DL0, PB_DL1, PB_DL2, PB_DLOGIT,
                              PB_DMX, PB_DMY, PB_DMZ, PB_DQW, PB_DQX, PB_DQY, PB_DQZ, PB_DX,
                              PB_DY, PB_DZ, PB_GMX, PB_K, PCH, PF_CUT, PF_K, PF_O, Q_I0, Q_I1,
                              Q_J0, Q_J1, Q_NX, Q_NY, Q_NZ, Q_RAD, Q_X, U64, at,
                              backward_lanes, forward_lanes, gather_model, gather_sh,
                              lane_buffers, sh_grad_row, sh_layout, smallest_axis)
from ._sched import CHUNK, fetch_add, n_chunks, new_counter

SIGMA_CUTOFF = 4.5
ALPHA_MIN = 1.0 / 255.0
CUT_MARGIN = 1e-3  # slack on the per-splat sigma cutoff used only to bound tiles/skip early

# Columns of the per-candidate float output `fo` [C, NF].
F_X, F_Y, F_A, F_B, F_C, F_O, F_CUT, F_Z, F_R, F_G, F_BL, F_NX, F_NY, F_NZ = range(14)
NF = 16


@njit(cache=True, inline="always")
def scatter_rows(buf, m, r0, fo, box, radii, normals):
    """Rows r0 .. r0+m-1 of fo [R, NF] (culled rows left as they were; the normal columns only
    with normals), box [R, 4] (empty where culled) and radii [R] from the output planes."""
    for jj in range(m):
        r = r0 + jj
        j = U64(jj)
        box[r, 0] = np.int32(buf[at(Q_J0, j)])
        box[r, 1] = np.int32(buf[at(Q_I0, j)])
        box[r, 2] = np.int32(buf[at(Q_J1, j)])
        box[r, 3] = np.int32(buf[at(Q_I1, j)])
        rad = buf[at(Q_RAD, j)]
        radii[r] = np.int32(rad)
        if rad == 0.0:
            continue
        for q in range(F_NX):  # F_X .. F_BL, the same order as Q_X .. Q_BL
            fo[r, q] = buf[at(Q_X + q, j)]
        if normals:
            fo[r, F_NX] = buf[at(Q_NX, j)]
            fo[r, F_NY] = buf[at(Q_NY, j)]
            fo[r, F_NZ] = buf[at(Q_NZ, j)]


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
def view_parts(view):
    """(W 9-tuple, tw 3-tuple) from a float64 [4, 4] world-to-camera matrix."""
    W = (view[0, 0], view[0, 1], view[0, 2], view[1, 0], view[1, 1], view[1, 2],
         view[2, 0], view[2, 1], view[2, 2])
    return W, (view[0, 3], view[1, 3], view[2, 3])


@njit(cache=True)
def _forward_chunk(c0, m, idx, means, quats, log_scales, logits, shf, ks, k3, W, tw, campos,
                   cam, lims, width, height, near, far, cov_alpha, fo, box, radii, buf, shp):
    """Candidates c0 .. c0+m-1 (m <= PCH): gather, project in lanes, scatter the rows."""
    for jj in range(m):
        i = idx[c0 + jj]
        j = U64(jj)
        l0, l1, l2 = gather_model(buf, j, i, means, quats, log_scales, logits)
        buf[at(PF_CUT, j)] = sigma_cut(buf[at(PF_O, j)])
        buf[at(PF_K, j)] = smallest_axis(l0, l1, l2)
        gather_sh(shp, shf, i * ks, k3, j)
    forward_lanes(buf, shp, m, W, tw, campos, cam, lims, np.float64(width),
                  np.float64(height), near, far, cov_alpha)
    scatter_rows(buf, m, c0, fo, box, radii, True)


@njit(parallel=True, cache=True)
def project_forward(idx, means, quats, log_scales, logits, sh, deg, view, campos, cam,
                    width, height, near, far, cov_alpha, fo, box, radii, n_workers=1):
    """Project candidates idx [C] -> fo [C, NF] float32, box [C, 4] int32 (pixel box
    j0, i0, j1, i1 inclusive; empty, j1 < j0, when the splat reaches no pixel centre),
    radii [C] int32 (0 = culled; the fo rows of culled candidates are left as they were,
    their boxes empty). sh [N, K, 3] C-contiguous. n_workers draw chunks of candidates from a shared
    counter (dynamic balance); each projects PCH candidates at a time in vector lanes."""
    W, tw = view_parts(view)
    lims = jac_limits(cam[0], cam[1], cam[2], cam[3], width, height)
    n = idx.shape[0]
    shf, ks, k3 = sh_layout(sh, deg)
    n_items = n_chunks(n, CHUNK)
    nxt = new_counter()
    for _h in prange(n_workers):
        buf, shp = lane_buffers(NQ)
        while True:
            ch = fetch_add(nxt, 1)
            if ch >= n_items:
                break
            end = min(n, (ch + 1) * CHUNK)
            for c0 in range(ch * CHUNK, end, PCH):
                _forward_chunk(c0, min(PCH, end - c0), idx, means, quats, log_scales, logits,
                               shf, ks, k3, W, tw, campos, cam, lims, width, height, near, far,
                               cov_alpha, fo, box, radii, buf, shp)


# Columns of the per-visible-splat 2D gradient `g2` [V, NG] (raster backward output).
G_MX, G_MY, G_A, G_B, G_C, G_O, G_R, G_G, G_BL, G_Z, G_NX, G_NY, G_NZ, G_AX, G_AY = range(15)
NG = 16


@njit(cache=True)
def _backward_chunk(v0, m, ids, means, quats, log_scales, logits, shf, ks, k3, W, tw, campos,
                    cam, lims, g2, d_means, d_quats, d_logs, d_logits, d_sh, grad2d, absgrad,
                    want_abs, buf, shp):
    """Visible splats v0 .. v0+m-1 (m <= PCH): gather, VJP in lanes, scatter the rows."""
    for jj in range(m):
        v = v0 + jj
        i = ids[v]
        j = U64(jj)
        l0, l1, l2 = gather_model(buf, j, i, means, quats, log_scales, logits)
        buf[at(PB_K, j)] = smallest_axis(l0, l1, l2)
        for q in range(13):  # G_MX .. G_NZ, in the same order as PB_GMX .. PB_GNZ
            buf[at(PB_GMX + q, j)] = g2[v, G_MX + q]
        gather_sh(shp, shf, i * ks, k3, j)
    backward_lanes(buf, shp, m, W, tw, campos, cam, lims)
    for jj in range(m):
        v = v0 + jj
        i = ids[v]
        j = U64(jj)
        grad2d[i, 0] += g2[v, G_MX]
        grad2d[i, 1] += g2[v, G_MY]
        if want_abs:
            absgrad[i, 0] += g2[v, G_AX]
            absgrad[i, 1] += g2[v, G_AY]
        d_means[i, 0] = buf[at(PB_DMX, j)]
        d_means[i, 1] = buf[at(PB_DMY, j)]
        d_means[i, 2] = buf[at(PB_DMZ, j)]
        d_quats[i, 0] = buf[at(PB_DQW, j)]
        d_quats[i, 1] = buf[at(PB_DQX, j)]
        d_quats[i, 2] = buf[at(PB_DQY, j)]
        d_quats[i, 3] = buf[at(PB_DQZ, j)]
        d_logs[i, 0] = buf[at(PB_DL0, j)]
        d_logs[i, 1] = buf[at(PB_DL1, j)]
        d_logs[i, 2] = buf[at(PB_DL2, j)]
        d_logits[i] = buf[at(PB_DLOGIT, j)]
        sh_grad_row(d_sh, i, k3, buf[at(PB_DX, j)], buf[at(PB_DY, j)], buf[at(PB_DZ, j)],
                    buf[at(PB_CR, j)], buf[at(PB_CG, j)], buf[at(PB_CB, j)])


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
    shf, ks, k3 = sh_layout(sh, deg)
    n_items = n_chunks(n, CHUNK)
    nxt = new_counter()
    for _h in prange(n_workers):
        buf, shp = lane_buffers(PB)
        while True:
            ch = fetch_add(nxt, 1)
            if ch >= n_items:
                break
            end = min(n, (ch + 1) * CHUNK)
            for v0 in range(ch * CHUNK, end, PCH):
                _backward_chunk(v0, min(PCH, end - v0), ids, means, quats, log_scales, logits,
                                shf, ks, k3, W, tw, campos, cam, lims, g2, d_means, d_quats,
                                d_logs, d_logits, d_sh, grad2d, absgrad, want_abs, buf, shp)
