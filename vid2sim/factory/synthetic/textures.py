"""Procedural textures evaluated from world coordinates + material id (vectorised numpy).

Rich high-frequency detail (bricks, slab joints, window grids, grain) so SIFT finds features;
detail finer than a pixel's footprint is faded out (a cheap mip-map) to avoid flicker.
"""

from __future__ import annotations

import numpy as np

from vid2sim.factory.synthetic.geometry import (
    ASPHALT, BRICK, CAR, KERB, PLANT, PLANTER, PLASTER, POLE, SIDEWALK,
)

SUN = np.array([0.35, -0.55, 0.76]) / np.linalg.norm([0.35, -0.55, 0.76])
SKY_HORIZON = np.array([0.86, 0.89, 0.93], np.float32)
SKY_ZENITH = np.array([0.42, 0.60, 0.86], np.float32)


def hash2(ix: np.ndarray, iy: np.ndarray, seed: int = 0) -> np.ndarray:
    """Deterministic integer hash of lattice cells -> float32 in [0, 1)."""
    h = (ix.astype(np.int32).view(np.uint32) * np.uint32(374761393)
         + iy.astype(np.int32).view(np.uint32) * np.uint32(668265263) + np.uint32((seed * 982451653) & 0xFFFFFFFF))
    h = (h ^ (h >> np.uint32(13))) * np.uint32(1274126177)
    h = h ^ (h >> np.uint32(16))
    return (h & np.uint32(0xFFFFFF)).astype(np.float32) / np.float32(0x1000000)


def value_noise(u: np.ndarray, v: np.ndarray, freq: float, seed: int = 0) -> np.ndarray:
    """Smooth value noise in [0, 1) at `freq` cells per metre."""
    x, y = u * freq, v * freq
    ix, iy = np.floor(x), np.floor(y)
    fx, fy = x - ix, y - iy
    fx, fy = fx * fx * (3 - 2 * fx), fy * fy * (3 - 2 * fy)
    ix, iy = ix.astype(np.int32), iy.astype(np.int32)
    a, b = hash2(ix, iy, seed), hash2(ix + 1, iy, seed)
    c, d = hash2(ix, iy + 1, seed), hash2(ix + 1, iy + 1, seed)
    return (a + (b - a) * fx) + ((c + (d - c) * fx) - (a + (b - a) * fx)) * fy


def detail(fp: np.ndarray, size: float) -> np.ndarray:
    """Weight in [0, 1] of a feature of `size` metres given the pixel footprint `fp` (m)."""
    return np.clip(1.6 - 1.2 * fp / size, 0.0, 1.0)


def fbm(u: np.ndarray, v: np.ndarray, fp: np.ndarray, freqs: tuple[float, ...], seed: int = 0) -> np.ndarray:
    """Zero-mean multi-octave noise, octaves finer than the footprint faded out."""
    out = np.zeros_like(u)
    for k, f in enumerate(freqs):
        out += (value_noise(u, v, f, seed + k) - 0.5) * detail(fp, 1.0 / f) / (1 + k * 0.5)
    return out


def surface_uv(p: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Planar texture coordinates chosen by the dominant normal axis; u, v [N]."""
    ax = np.argmax(np.abs(n), axis=1)
    u = np.where(ax == 2, p[:, 0], np.where(ax == 0, p[:, 1], p[:, 0]))
    v = np.where(ax == 2, p[:, 1], p[:, 2])
    return u.astype(np.float32), v.astype(np.float32)


def _lines(coord: np.ndarray, period: float, width: float) -> np.ndarray:
    """1 on joint lines of `width` every `period` metres, else 0."""
    f = np.mod(coord, period)
    return ((f < width / 2) | (f > period - width / 2)).astype(np.float32)


def _asphalt(u, v, p, fp, col, c):
    g = 0.30 + 0.20 * fbm(u, v, fp, (3.0, 11.0, 37.0, 120.0), 11)
    grain = hash2(np.floor(u * 90), np.floor(v * 90), 12)
    g = g + 0.10 * detail(fp, 1 / 90) * ((grain > 0.93) * 0.8 - (grain < 0.05) * 0.6)
    rgb = np.stack([g, g, g * 1.03], 1)
    y_mid = -c.kerb_width - c.road_width / 2
    dash = (np.abs(v - y_mid) < 0.07) & (np.mod(u, 6.0) < 3.0)
    park = np.abs(v - (-c.kerb_width - 2.4)) < 0.06
    bay = (np.abs(np.mod(u, 6.5) - 3.25) > 3.19) & (v > -c.kerb_width - 2.4) & (v < -c.kerb_width)
    paint = (dash | park | bay)[:, None]
    return np.where(paint, np.array([0.85, 0.85, 0.80], np.float32) + 0.05 * rgb, rgb)


def _sidewalk(u, v, p, fp, col, c):
    slab = hash2(np.floor(u / 0.6), np.floor(v / 0.6), 21)
    g = 0.60 + 0.12 * (slab - 0.5) + 0.22 * fbm(u, v, fp, (5.0, 19.0, 61.0, 160.0), 22)
    joint = np.maximum(_lines(u, 0.6, 0.015), _lines(v, 0.6, 0.015)) * detail(fp, 0.015)
    g = g * (1 - 0.45 * joint)
    return np.stack([g * 1.02, g, g * 0.95], 1)


def _kerb(u, v, p, fp, col, c):
    g = 0.72 + 0.08 * fbm(u, v, fp, (20.0, 70.0), 31)
    speck = hash2(np.floor(u * 120), np.floor(v * 120), 32)
    g = g - 0.25 * detail(fp, 1 / 120) * (speck > 0.85)
    g = g * (1 - 0.5 * _lines(p[:, 0], 1.0, 0.01) * detail(fp, 0.01))
    return np.stack([g, g, g], 1)


def _windows(u, z, fp, inst, base):
    """Window grid on a facade; per-building spacing from its instance id."""
    r1, r2 = hash2(inst, inst * 3, 41), hash2(inst, inst * 5, 42)
    sx, sz = 2.6 + 1.0 * r1, 3.0 + 0.4 * r2  # spacing [N]
    ww, wh = 1.0 + 0.5 * r2, 1.5 + 0.3 * r1
    lu = np.mod(u + 7.3 * r1, sx) - (sx - ww) / 2  # [N] window-local coordinates
    lz = np.mod(z, sz) - 0.9
    floor = np.floor(z / sz)
    inside = (lu > 0) & (lu < ww) & (lz > 0) & (lz < wh) & (floor >= 1)
    shop = (floor < 1) & (z > 0.5) & (z < 2.6) & (np.mod(u + 3 * r2, 6.0) < 4.2)
    frame = inside & ((lu < 0.08) | (lu > ww - 0.08) | (lz < 0.08) | (lz > wh - 0.08)
                      | (np.abs(lu - ww / 2) < 0.035) | (np.abs(lz - wh * 0.62) < 0.035))
    glass_id = hash2(np.floor((u + 7.3 * r1) / sx), floor, 43)
    refl = 0.10 + 0.25 * glass_id[:, None] + 0.15 * np.clip((lz / np.maximum(wh, 1e-3)), 0, 1)[:, None]
    clutter = 1 + 0.9 * fbm(u + 13 * r1, z, fp, (2.0, 7.0, 23.0), 44)  # reflections / displays
    glass = refl * clutter[:, None] * np.array([0.55, 0.70, 0.85], np.float32)
    rgb = np.where((inside | shop)[:, None], glass, base)
    sill = (lz > -0.12) & (lz < 0) & (lu > -0.1) & (lu < ww + 0.1) & (floor >= 1)
    rgb = np.where((frame | sill)[:, None], np.array([0.92, 0.92, 0.88], np.float32), rgb)
    return rgb


def _brick(u, v, p, fp, col, c, inst, front):
    course = np.floor(v / 0.075)
    bu = u + 0.12 * np.mod(course, 2)
    brick = hash2(np.floor(bu / 0.24), course, 51)
    mortar = np.maximum(_lines(v, 0.075, 0.012), _lines(bu, 0.24, 0.012)) * detail(fp, 0.012)
    tint = 0.75 + 0.5 * brick[:, None]
    rgb = col * tint * (1 + 0.3 * fbm(u, v, fp, (30.0, 90.0), 52))[:, None]
    rgb = np.where(mortar[:, None] > 0.5, np.array([0.78, 0.76, 0.72], np.float32), rgb)
    return np.where(front[:, None], _windows(u, v, fp, inst, rgb), rgb)


def _plaster(u, v, p, fp, col, c, inst, front):
    stain = 0.85 + 0.45 * fbm(u, v, fp, (0.7, 3.0, 13.0, 47.0, 150.0), 61)
    rgb = col * stain[:, None]
    band = (np.mod(v, 3.2) < 0.18) & (v > 1.0)
    rgb = np.where(band[:, None], col * 0.72, rgb)
    return np.where(front[:, None], _windows(u, v, fp, inst, rgb), rgb)


def _pole(u, v, p, fp, col, c):
    g = 1 + 0.4 * fbm(p[:, 0] + p[:, 1], p[:, 2], fp, (8.0, 40.0), 71)
    ring = _lines(p[:, 2], 0.8, 0.05) * detail(fp, 0.05)
    return col * (g * (1 - 0.4 * ring))[:, None]


def _planter(u, v, p, fp, col, c):
    plank = hash2(np.floor(p[:, 2] / 0.12), np.floor(u / 1.0), 81)
    g = 0.8 + 0.35 * plank + 0.3 * fbm(u, v * 4, fp, (6.0, 30.0), 82)
    g = g * (1 - 0.5 * _lines(p[:, 2], 0.12, 0.012) * detail(fp, 0.012))
    return col * g[:, None]


def _plant(u, v, p, fp, col, c):
    g = 0.9 + 1.2 * fbm(u + 0.37 * p[:, 2], v + 0.61 * p[:, 2], fp, (6.0, 17.0, 43.0, 110.0), 92)
    return col * g[:, None]


def _car(u, v, p, fp, col, c):
    g = 1 + 0.25 * fbm(u, v, fp, (3.0, 15.0, 45.0), 101)
    rgb = col * g[:, None]
    low = p[:, 2] < -c.kerb_height + 0.38
    rgb = np.where(low[:, None], np.array([0.07, 0.07, 0.08], np.float32), rgb)
    trim = np.abs(p[:, 2] - (-c.kerb_height + 0.6)) < 0.03
    return np.where(trim[:, None], np.array([0.8, 0.8, 0.8], np.float32), rgb)


_SIMPLE = {ASPHALT: _asphalt, SIDEWALK: _sidewalk, KERB: _kerb, POLE: _pole, PLANTER: _planter,
           PLANT: _plant, CAR: _car}


def albedo(p: np.ndarray, n: np.ndarray, mat: np.ndarray, col: np.ndarray, inst: np.ndarray,
           fp: np.ndarray, conf) -> np.ndarray:
    """Surface colour [N, 3] float32 at world points p [N, 3] with normals n [N, 3]."""
    p = p.astype(np.float32)
    fp = fp.astype(np.float32)
    u, v = surface_uv(p, n)
    out = np.zeros((len(p), 3), np.float32)
    for m in np.unique(mat):
        sel = np.nonzero(mat == m)[0]
        args = (u[sel], v[sel], p[sel], fp[sel], col[sel], conf)
        if m in _SIMPLE:
            out[sel] = _SIMPLE[m](*args)
        elif m in (BRICK, PLASTER):
            front = np.abs(n[sel, 1]) > 0.9
            fn = _brick if m == BRICK else _plaster
            out[sel] = fn(*args, inst[sel].astype(np.int64), front)
        else:
            out[sel] = col[sel]
    return out


def shade(rgb: np.ndarray, n: np.ndarray, conf=None) -> np.ndarray:
    """Lambert with a sun and sky ambient; n [N, 3] world normals facing the viewer. The street's
    lighting (`StreetConfig.sun_direction`, `ambient`, `sun_strength`) when `conf` is given."""
    sun, ambient, strength = SUN, 0.50, 0.55
    if conf is not None:
        sun = np.asarray(conf.sun_direction, np.float64) / np.linalg.norm(conf.sun_direction)
        ambient, strength = conf.ambient, conf.sun_strength
    lam = np.clip(n[:, 0] * sun[0] + n[:, 1] * sun[1] + n[:, 2] * sun[2], 0.0, 1.0).astype(np.float32)
    amb = ambient + 0.12 * n[:, 2].astype(np.float32)
    return rgb * (amb + strength * lam)[:, None]


def sky(d: np.ndarray) -> np.ndarray:
    """Sky gradient for world ray directions d [N, 3]."""
    s = np.clip(d[:, 2], 0.0, 1.0).astype(np.float32) ** 0.6
    return SKY_HORIZON + (SKY_ZENITH - SKY_HORIZON) * s[:, None]
