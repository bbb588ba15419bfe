"""Env-path level of detail (opt-in; NOT part of the exact renderer contract).

An octree over the Morton-ordered splats of a StaticScene: a node at level L groups the
splats whose 30-bit Morton codes agree above bit 3L, and carries one merged Gaussian:
weights w_i = o_i a_i (opacity x footprint a_i = product of the two largest scales),
moment-matched mean and covariance, w-weighted SH coefficients, shortest covariance axis
as normal, and opacity min(0.99, sum o_i a_i / A, 1 - prod(1 - o_i)) with A the footprint
of the merged covariance (so the integrated alpha is kept where members do not overlap).
Per view, `select_lod` walks the tree top-down and emits a node's merged Gaussian once its
standard deviation (sqrt of the largest eigenvalue of the merged covariance), seen from the
nearest member mean, projects below `pixel_radius` px; otherwise it descends to the children.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from .env_scene_kernels import frustum_planes, sphere_outside, sigma_cuts

MAX_LEVEL = 10  # Morton codes have 10 bits per axis


@dataclass
class LodTree:
    """Merged Gaussians (indices K.. in the scene's Gaussian arrays) and the node graph.

    child0 [M] int64   first child: a splat index (level 1) or a Gaussian index (level >= 2)
    nchild [M] int64   number of children (contiguous)
    center [M, 3], r_means [M]  bounding sphere of the member means
    rho [M]            max sigma<=cut extent of anything emitted below the node (m)
    ext [M]            merged standard deviation (m), for the pixel-size test
    roots [R] int64    Gaussian indices of the top-level nodes
    means [M, 3], cov [M, 6], opacity [M], cut [M], normal [M, 3], rgb [M, 3], sh [M, K, 3]
    """

    child0: np.ndarray
    nchild: np.ndarray
    center: np.ndarray
    r_means: np.ndarray
    rho: np.ndarray
    ext: np.ndarray
    roots: np.ndarray
    means: np.ndarray
    cov: np.ndarray
    opacity: np.ndarray
    cut: np.ndarray
    normal: np.ndarray
    rgb: np.ndarray
    sh: np.ndarray


def _sym6(m: np.ndarray) -> np.ndarray:
    """[n, 3, 3] -> [n, 6] (xx, xy, xz, yy, yz, zz)."""
    return np.stack([m[:, 0, 0], m[:, 0, 1], m[:, 0, 2], m[:, 1, 1], m[:, 1, 2], m[:, 2, 2]], 1)


def _full(c6: np.ndarray) -> np.ndarray:
    """[n, 6] -> [n, 3, 3]."""
    a, b, c, d, e, f = c6.T
    return np.stack([np.stack([a, b, c], 1), np.stack([b, d, e], 1), np.stack([c, e, f], 1)], 1)


def build_lod(codes: np.ndarray, means: np.ndarray, cov6: np.ndarray, opacity: np.ndarray,
              sh: np.ndarray, rho: np.ndarray, c0: float) -> LodTree:
    """Build the tree over K Morton-sorted splats (codes [K] sorted, means [K, 3], cov6 [K, 6],
    opacity [K], sh [K, Kc, 3], rho [K] sigma<=cut extents)."""
    K = len(codes)
    eig = np.clip(np.linalg.eigvalsh(_full(cov6)), 0.0, None)  # ascending
    area = np.sqrt(eig[:, 1] * eig[:, 2])
    w = opacity * np.maximum(area, 1e-12)
    # Per-element sums, combined bottom-up: w, w mu, w (Sigma + mu mu^T), w sh, o a, log(1-o)
    S = dict(w=w, wm=w[:, None] * means,
             wM=w[:, None] * (cov6 + _sym6(means[:, :, None] * means[:, None, :])),
             wsh=w[:, None] * sh.reshape(K, -1).astype(np.float64),
             oa=opacity * area, l1o=np.log1p(-np.minimum(opacity, 0.999999)),
             lo=means.copy(), hi=means.copy(), rho=rho.copy())
    starts_prev = np.arange(K)  # element starts (in splat order) of the previous level
    base_prev = 0  # Gaussian index of the previous level's first element (splats: 0)
    parts = []
    base = K
    for L in range(1, MAX_LEVEL + 1):
        keys = codes >> np.uint64(3 * L)
        starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])  # splat starts of nodes
        cidx = np.searchsorted(starts_prev, starts)  # first child (previous-level element)
        nc = np.diff(np.r_[cidx, len(starts_prev)])
        S = {k: (np.minimum.reduceat(v, cidx, axis=0) if k == "lo" else
                 np.maximum.reduceat(v, cidx, axis=0) if k in ("hi", "rho") else
                 np.add.reduceat(v, cidx, axis=0)) for k, v in S.items()}
        g = _merge(S, c0, sh.shape[1:])
        S["rho"] = np.maximum(S["rho"], g["rho_self"])
        g["rho"] = S["rho"]
        g["child0"] = cidx + base_prev
        g["nchild"] = nc
        g["ext"] = g["sigma"]
        parts.append(g)
        starts_prev, base_prev = starts, base
        base += len(starts)
        if len(starts) <= 8:
            break
    cat = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return LodTree(child0=cat["child0"].astype(np.int64), nchild=cat["nchild"].astype(np.int64),
                   center=cat["center"], r_means=cat["r_means"], rho=cat["rho"], ext=cat["ext"],
                   roots=np.arange(base_prev, base, dtype=np.int64), means=cat["means"],
                   cov=cat["cov"], opacity=cat["opacity"], cut=sigma_cuts(cat["opacity"]),
                   normal=cat["normal"], rgb=cat["rgb"], sh=cat["sh"].astype(np.float32))


def _merge(S: dict, c0: float, sh_shape: tuple) -> dict:
    """Merged Gaussian per node from its summed moments S."""
    w = S["w"]
    mu = S["wm"] / w[:, None]
    cov6 = S["wM"] / w[:, None] - _sym6(mu[:, :, None] * mu[:, None, :])
    evals, evecs = np.linalg.eigh(_full(cov6))
    evals = np.clip(evals, 1e-12, None)
    area = np.sqrt(evals[:, 1] * evals[:, 2])
    opacity = np.minimum.reduce([np.full_like(w, 0.99), S["oa"] / area, 1.0 - np.exp(S["l1o"])])
    opacity = np.maximum(opacity, 0.0)
    cut = sigma_cuts(opacity)
    sh = (S["wsh"] / w[:, None]).reshape(len(w), *sh_shape)
    center = 0.5 * (S["lo"] + S["hi"])
    return dict(means=mu, cov=cov6, opacity=opacity, normal=evecs[:, :, 0],
                rgb=np.clip(c0 * sh[:, 0] + 0.5, 0.0, None), sh=sh, center=center,
                r_means=0.5 * np.linalg.norm(S["hi"] - S["lo"], axis=1),
                rho_self=np.sqrt(2.0 * np.clip(cut, 0.0, None) * evals[:, 2]),
                sigma=np.sqrt(evals[:, 2]))


@njit(cache=True)
def select_lod(K, child0, nchild, center, r_means, rho, ext, roots, view, cam, campos, width,
               height, near, far, pixel_radius, sel, stack):
    """Write into sel the Gaussian indices to project for this view (splats < K, merged
    nodes >= K); returns the count. Nodes outside the frustum are dropped whole."""
    W, tw, planes, grow = frustum_planes(view, cam, width, height)
    f = max(cam[0], cam[1])
    n = 0
    top = 0
    for r in range(roots.shape[0]):
        stack[top] = roots[r]
        top += 1
    while top > 0:
        top -= 1
        g = stack[top]
        m = g - K
        x, y, z = center[m, 0], center[m, 1], center[m, 2]
        if sphere_outside(x, y, z, r_means[m], rho[m], W, tw, planes, grow, near, far):
            continue
        dx, dy, dz = x - campos[0], y - campos[1], z - campos[2]
        dist = np.sqrt(dx * dx + dy * dy + dz * dz) - r_means[m]
        if dist > 0.0 and f * ext[m] <= pixel_radius * dist:
            sel[n] = g
            n += 1
            continue
        c0 = child0[m]
        if c0 < K:  # level 1: children are splats
            for i in range(c0, c0 + nchild[m]):
                sel[n] = i
                n += 1
        else:
            for c in range(c0, c0 + nchild[m]):
                stack[top] = c
                top += 1
    return n
