"""Points on triangle-mesh surfaces: uniform by area, or about one per spacing^2 (deterministic per seed)."""

from __future__ import annotations

import numpy as np


def sample_surface(vertices: np.ndarray, faces: np.ndarray, n: int, seed: int = 0
                   ) -> np.ndarray:
    """`n` points [n, 3] uniformly by area on a triangle mesh (deterministic for a seed)."""
    tri = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]  # [F, 3, 3]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if len(tri) == 0 or area.sum() <= 0:
        raise ValueError("cannot sample an empty (zero-area) mesh")
    rng = np.random.default_rng(seed)
    idx = rng.choice(len(tri), size=n, p=area / area.sum())
    u, v = rng.random(n), rng.random(n)
    out = u + v > 1
    u[out], v[out] = 1 - u[out], 1 - v[out]
    t = tri[idx]
    return t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])


def points_by_spacing(vertices: np.ndarray, faces: np.ndarray, spacing: float, seed: int = 0
                      ) -> np.ndarray:
    """Surface points with about one per spacing^2 of area, plus every vertex: [P, 3]."""
    v, f = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    if len(f) == 0:
        return v.copy()
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    n = int(np.ceil(area.sum() / spacing ** 2))
    extra = sample_surface(v, f, n, seed) if n > 0 and area.sum() > 0 else np.zeros((0, 3))
    return np.concatenate([v, tri.mean(axis=1), extra])
