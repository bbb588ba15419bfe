"""CPU triangle z-buffer rasteriser for the env camera (mesh-rgb variant, obstacles, people).

`rasterize(...)` draws flat-coloured triangles with perspective-correct depth (1/z is
interpolated linearly in screen space) and clips every triangle against the near plane
(z = NEAR) so geometry that reaches behind the camera is cut, never wrapped around.
Conventions: OpenCV camera (x right, y down, z forward), depth = camera z, +inf where empty;
pixel (i, j) is sampled at its centre (j + 0.5, i + 0.5), as the splat renderer
(docs/splat_renderer.md). A pixel is covered when all three edge functions are >= 0 (both
windings are drawn: collision meshes do not have consistent winding).

`rasterize` is the numba kernel; `rasterize_reference` is the plain numpy version it is
tested against (tests/test_envs_raster.py).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

NEAR = 0.05  # m: near clipping plane


def camera_vertices(vertices: np.ndarray, world_to_cam: np.ndarray) -> np.ndarray:
    """World points [V, 3] -> camera-frame points [V, 3] (float64)."""
    w2c = np.asarray(world_to_cam, dtype=np.float64)
    return np.asarray(vertices, dtype=np.float64) @ w2c[:3, :3].T + w2c[:3, 3]  # [V, 3]


def _check(vertices: np.ndarray, faces: np.ndarray, face_colors: np.ndarray) -> None:
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ValueError(f"vertices must be [V, 3], got {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"faces must be [F, 3], got {faces.shape}")
    if face_colors.shape != faces.shape:
        raise ValueError(f"face_colors must be [F, 3] like faces, got {face_colors.shape}")


def rasterize(vertices: np.ndarray, faces: np.ndarray, face_colors: np.ndarray,
              K: np.ndarray, world_to_cam: np.ndarray, width: int, height: int,
              near: float = NEAR) -> tuple[np.ndarray, np.ndarray]:
    """Draw a triangle mesh: (rgb [H, W, 3] u8 (black where empty), depth [H, W] f32)."""
    _check(vertices, faces, face_colors)
    rgb = np.zeros((height, width, 3), dtype=np.uint8)
    depth = np.full((height, width), np.inf, dtype=np.float32)
    if len(faces) == 0:
        return rgb, depth
    verts = np.ascontiguousarray(vertices, dtype=np.float32)
    cam = _transform(verts, np.asarray(world_to_cam, dtype=np.float64))  # [V, 3]
    Kd = np.asarray(K, dtype=np.float64)
    _raster_kernel(cam, np.ascontiguousarray(faces, dtype=np.int32),
                   np.ascontiguousarray(face_colors, dtype=np.uint8), Kd[0, 0], Kd[0, 1],
                   Kd[0, 2], Kd[1, 1], Kd[1, 2], float(near), rgb, depth)
    return rgb, depth


@njit(cache=True)
def _transform(v: np.ndarray, w2c: np.ndarray) -> np.ndarray:
    """World points [V, 3] f32 -> camera frame [V, 3] f64 (one pass; no BLAS threads)."""
    out = np.empty((v.shape[0], 3))
    for i in range(v.shape[0]):
        x, y, z = v[i, 0], v[i, 1], v[i, 2]
        for r in range(3):
            out[i, r] = w2c[r, 0] * x + w2c[r, 1] * y + w2c[r, 2] * z + w2c[r, 3]
    return out


@njit(cache=True)
def _clip_near(P: np.ndarray, n_in: int, near: float, out: np.ndarray) -> int:
    """Sutherland-Hodgman clip of polygon P[:n_in] (camera xyz) to z >= near; rows -> out."""
    n = 0
    for k in range(n_in):
        a = P[k]
        b = P[(k + 1) % n_in]
        a_in = a[2] >= near
        b_in = b[2] >= near
        if a_in:
            out[n, 0] = a[0]
            out[n, 1] = a[1]
            out[n, 2] = a[2]
            n += 1
        if a_in != b_in:
            t = (near - a[2]) / (b[2] - a[2])
            out[n, 0] = a[0] + t * (b[0] - a[0])
            out[n, 1] = a[1] + t * (b[1] - a[1])
            out[n, 2] = near
            n += 1
    return n


@njit(cache=True)
def _draw_tri(u0, v0, w0, u1, v1, w1, u2, v2, w2, r, g, b, rgb, depth):
    """Fill one screen triangle; (u, v) pixels, w = 1/z. Keeps the nearest per pixel."""
    H, W = depth.shape
    area = (u1 - u0) * (v2 - v0) - (v1 - v0) * (u2 - u0)
    if abs(area) < 1e-12:
        return
    x0 = max(int(math.ceil(min(u0, u1, u2) - 0.5)), 0)
    x1 = min(int(math.floor(max(u0, u1, u2) - 0.5)), W - 1)
    y0 = max(int(math.ceil(min(v0, v1, v2) - 0.5)), 0)
    y1 = min(int(math.floor(max(v0, v1, v2) - 0.5)), H - 1)
    if x0 > x1 or y0 > y1:
        return
    inv = 1.0 / area
    for i in range(y0, y1 + 1):
        py = i + 0.5
        for j in range(x0, x1 + 1):
            px = j + 0.5
            e0 = ((u2 - u1) * (py - v1) - (v2 - v1) * (px - u1)) * inv
            e1 = ((u0 - u2) * (py - v2) - (v0 - v2) * (px - u2)) * inv
            e2 = 1.0 - e0 - e1
            if e0 < 0.0 or e1 < 0.0 or e2 < 0.0:
                continue
            z = 1.0 / (e0 * w0 + e1 * w1 + e2 * w2)
            if z < depth[i, j]:
                depth[i, j] = z
                rgb[i, j, 0] = r
                rgb[i, j, 1] = g
                rgb[i, j, 2] = b


@njit(cache=True)
def _raster_kernel(cam, faces, colors, fx, skew, cx, fy, cy, near, rgb, depth):
    """Clip, project and fill every face in order (serial; one env = one core)."""
    P = np.empty((3, 3))
    Q = np.empty((4, 3))
    su = np.empty(4)
    sv = np.empty(4)
    sw = np.empty(4)
    for f in range(faces.shape[0]):
        zmin = 1e30
        for k in range(3):
            vi = faces[f, k]
            P[k, 0] = cam[vi, 0]
            P[k, 1] = cam[vi, 1]
            P[k, 2] = cam[vi, 2]
            zmin = min(zmin, P[k, 2])
        if max(P[0, 2], P[1, 2], P[2, 2]) < near:
            continue
        if zmin >= near:
            n = 3
            Q[:3] = P
        else:
            n = _clip_near(P, 3, near, Q)
        for k in range(n):
            iz = 1.0 / Q[k, 2]
            su[k] = (fx * Q[k, 0] + skew * Q[k, 1]) * iz + cx
            sv[k] = fy * Q[k, 1] * iz + cy
            sw[k] = iz
        r, g, b = colors[f, 0], colors[f, 1], colors[f, 2]
        for k in range(1, n - 1):
            _draw_tri(su[0], sv[0], sw[0], su[k], sv[k], sw[k], su[k + 1], sv[k + 1],
                      sw[k + 1], r, g, b, rgb, depth)


def _clip_near_reference(P: np.ndarray, near: float) -> np.ndarray:
    """Plain-Python Sutherland-Hodgman clip of a triangle [3, 3] to z >= near -> [n, 3]."""
    out = []
    for k in range(3):
        a, b = P[k], P[(k + 1) % 3]
        if a[2] >= near:
            out.append(a)
        if (a[2] >= near) != (b[2] >= near):
            t = (near - a[2]) / (b[2] - a[2])
            out.append(np.array([*(a[:2] + t * (b[:2] - a[:2])), near]))
    return np.array(out).reshape(-1, 3)


def rasterize_reference(vertices: np.ndarray, faces: np.ndarray, face_colors: np.ndarray,
                        K: np.ndarray, world_to_cam: np.ndarray, width: int, height: int,
                        near: float = NEAR) -> tuple[np.ndarray, np.ndarray]:
    """Plain numpy rasteriser with the same rules as `rasterize` (slow; tests only)."""
    _check(vertices, faces, face_colors)
    rgb = np.zeros((height, width, 3), dtype=np.uint8)
    depth = np.full((height, width), np.inf, dtype=np.float32)
    cam = camera_vertices(vertices, world_to_cam)  # [V, 3]
    K = np.asarray(K, dtype=np.float64)
    jj, ii = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)  # [H, W]
    for f, tri in enumerate(faces):
        poly = _clip_near_reference(cam[tri], near)  # [n, 3]
        if len(poly) < 3:
            continue
        uvw = np.stack([(K[0, 0] * poly[:, 0] + K[0, 1] * poly[:, 1]) / poly[:, 2] + K[0, 2],
                        K[1, 1] * poly[:, 1] / poly[:, 2] + K[1, 2], 1.0 / poly[:, 2]], 1)
        for k in range(1, len(poly) - 1):
            _fill_reference(uvw[[0, k, k + 1]], face_colors[f], jj, ii, rgb, depth)
    return rgb, depth


def _fill_reference(uvw: np.ndarray, color: np.ndarray, jj: np.ndarray, ii: np.ndarray,
                    rgb: np.ndarray, depth: np.ndarray) -> None:
    """Fill one screen triangle (rows u, v, 1/z) over the whole image with numpy."""
    (u0, v0, w0), (u1, v1, w1), (u2, v2, w2) = uvw
    area = (u1 - u0) * (v2 - v0) - (v1 - v0) * (u2 - u0)
    if abs(area) < 1e-12:
        return
    e0 = ((u2 - u1) * (ii - v1) - (v2 - v1) * (jj - u1)) / area  # [H, W]
    e1 = ((u0 - u2) * (ii - v2) - (v0 - v2) * (jj - u2)) / area
    e2 = 1.0 - e0 - e1
    inside = (e0 >= 0) & (e1 >= 0) & (e2 >= 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = 1.0 / (e0 * w0 + e1 * w1 + e2 * w2)
    win = inside & (z < depth)
    depth[win] = z[win]
    rgb[win] = color
