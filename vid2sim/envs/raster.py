"""CPU triangle z-buffer rasteriser for the env camera (mesh-rgb variant, obstacles, people).

`rasterize(...)` draws flat-coloured triangles with perspective-correct depth (1/z is
interpolated linearly in screen space) and clips every triangle against the near plane
(z = NEAR) so geometry that reaches behind the camera is cut, never wrapped around.
Conventions: OpenCV camera (x right, y down, z forward), depth = camera z, +inf where empty;
pixel (i, j) is sampled at its centre (j + 0.5, i + 0.5), as the splat renderer
(docs/splat_renderer.md). A pixel is covered when all three edge functions are >= 0 (both
windings are drawn: collision meshes do not have consistent winding).

`rasterize` is the numba kernel; `rasterize_reference` is the plain numpy version it is
tested against (tests/test_envs_raster.py). `rasterize_into` draws over an existing layer
(the splat render) in place: the z-buffer composite of the two, in one pass.
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
    rgb = np.zeros((height, width, 3), dtype=np.uint8)
    depth = np.full((height, width), np.inf, dtype=np.float32)
    rasterize_into(vertices, faces, face_colors, K, world_to_cam, rgb, depth, near)
    return rgb, depth


def rasterize_into(vertices: np.ndarray, faces: np.ndarray, face_colors: np.ndarray,
                   K: np.ndarray, world_to_cam: np.ndarray, rgb: np.ndarray, depth: np.ndarray,
                   near: float = NEAR) -> None:
    """Draw a triangle mesh over a layer in place: rgb [H, W, 3] u8 and depth [H, W] f32
    (C-contiguous) take a triangle's colour and depth where it is nearer than depth (ties keep
    the layer). For a layer whose depth is > 0 or +inf this is
    `compositing.composite(rgb, depth, *rasterize(...))` without the second image."""
    _check(vertices, faces, face_colors)
    if rgb.dtype != np.uint8 or depth.dtype != np.float32 or rgb.shape != depth.shape + (3,) \
            or not (rgb.flags.c_contiguous and depth.flags.c_contiguous):
        raise ValueError("rasterize_into: rgb must be C-contiguous [H, W, 3] uint8 and depth [H, W] float32")
    if len(faces) == 0:
        return
    verts = np.ascontiguousarray(vertices, dtype=np.float32)
    cam = _transform(verts, np.asarray(world_to_cam, dtype=np.float64))  # [V, 3]
    Kd = np.asarray(K, dtype=np.float64)
    _raster_kernel(cam, np.ascontiguousarray(faces, dtype=np.int32),
                   np.ascontiguousarray(face_colors, dtype=np.uint8), Kd[0, 0], Kd[0, 1],
                   Kd[0, 2], Kd[1, 1], Kd[1, 2], float(near), rgb, depth)


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
def _span(a: float, b: float, lo: float, hi: float) -> tuple[float, float]:
    """Narrow [lo, hi] to the px where a * px + b >= 0."""
    if a > 0.0:
        lo = max(lo, -b / a)
    elif a < 0.0:
        hi = min(hi, -b / a)
    elif b < 0.0:
        hi = lo - 1.0
    return lo, hi


@njit(cache=True)
def _draw_tri(u0, v0, w0, u1, v1, w1, u2, v2, w2, r, g, b, rgb, depth):
    """Fill one screen triangle; (u, v) pixels, w = 1/z. Keeps the nearest per pixel.

    Each row visits only the span where the three edge functions can be >= 0 (one pixel of
    slack each side) and then applies the exact per-pixel test, so thin slivers cost their
    rows, not their bounding box."""
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
    a0, a1 = -(v2 - v1) * inv, -(v0 - v2) * inv  # d e0 / d px, d e1 / d px
    for i in range(y0, y1 + 1):
        py = i + 0.5
        b0 = ((u2 - u1) * (py - v1) + (v2 - v1) * u1) * inv  # e0 = a0 px + b0
        b1 = ((u0 - u2) * (py - v2) + (v0 - v2) * u2) * inv
        lo, hi = _span(a0, b0, x0 + 0.5, x1 + 0.5)
        lo, hi = _span(a1, b1, lo, hi)
        lo, hi = _span(-a0 - a1, 1.0 - b0 - b1, lo, hi)
        if lo > hi:
            continue
        j0 = max(x0, int(math.floor(lo - 0.5)) - 1)
        j1 = min(x1, int(math.ceil(hi - 0.5)) + 1)
        for j in range(j0, j1 + 1):
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
def _project(cam, fx, skew, cx, fy, cy, near, width, height):
    """Per vertex: screen u, v, 1/z [V] and an outcode [V] (bits: left, right, top, bottom,
    behind the near plane) for rejecting whole faces outside the view."""
    n = cam.shape[0]
    su, sv, sw = np.empty(n), np.empty(n), np.empty(n)
    code = np.zeros(n, np.int32)
    for i in range(n):
        z = cam[i, 2]
        if z < near:
            code[i] = 16
            continue
        iz = 1.0 / z
        u = (fx * cam[i, 0] + skew * cam[i, 1]) * iz + cx
        v = fy * cam[i, 1] * iz + cy
        su[i], sv[i], sw[i] = u, v, iz
        code[i] = (u < 0.0) * 1 + (u > width) * 2 + (v < 0.0) * 4 + (v > height) * 8
    return su, sv, sw, code


@njit(cache=True)
def _raster_kernel(cam, faces, colors, fx, skew, cx, fy, cy, near, rgb, depth):
    """Project vertices once, reject faces outside the view, clip those crossing the near
    plane, fill the rest in order (serial; one env = one core)."""
    H, W = depth.shape
    su, sv, sw, code = _project(cam, fx, skew, cx, fy, cy, near, W, H)
    P = np.empty((3, 3))
    Q = np.empty((4, 3))
    qu, qv, qw = np.empty(4), np.empty(4), np.empty(4)
    for f in range(faces.shape[0]):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        if code[a] & code[b] & code[c]:
            continue  # all behind, or all beyond one image border
        r, g, bl = colors[f, 0], colors[f, 1], colors[f, 2]
        if not ((code[a] | code[b] | code[c]) & 16):
            _draw_tri(su[a], sv[a], sw[a], su[b], sv[b], sw[b], su[c], sv[c], sw[c], r, g, bl,
                      rgb, depth)
            continue
        for k in range(3):
            vi = faces[f, k]
            P[k, 0], P[k, 1], P[k, 2] = cam[vi, 0], cam[vi, 1], cam[vi, 2]
        n = _clip_near(P, 3, near, Q)
        for k in range(n):
            iz = 1.0 / Q[k, 2]
            qu[k] = (fx * Q[k, 0] + skew * Q[k, 1]) * iz + cx
            qv[k] = fy * Q[k, 1] * iz + cy
            qw[k] = iz
        for k in range(1, n - 1):
            _draw_tri(qu[0], qv[0], qw[0], qu[k], qv[k], qw[k], qu[k + 1], qv[k + 1], qw[k + 1],
                      r, g, bl, rgb, depth)


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
