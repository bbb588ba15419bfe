"""One env camera through the fast kernels straight to what the envs read.

`FastView(batch).draw(world_to_cam, fx, fy, cx, cy)` renders scene 0 of a `FastBatch` and
returns (rgb [H, W, 3] uint8, depth [H, W] float32, +inf where the coverage is below
`empty_alpha`): the pixels of `FastBatch.render` followed by `envs.rendering.view_outputs`,
bit for bit (tests/test_splats_fastview.py), in one numba call with no torch tensors and no
Camera object. Each FastView keeps its own scratch (one per env; not thread-safe); the packed
batch is only read, so many views may share it. `composite_view` blends exactly as
`env_fast_frame.composite_fast` (the same `blend_window`, same pixels) but finds the stopped pixels
by scanning the tile every CHECK_EVERY splats instead of reducing a stop mask after every
blended row (~8 % less CPU at the GoPro scene's expert poses).
`finish_u8` is the fused finish; `finish_u8_reference` is the plain numpy version.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from numba import njit

from ._bits import popc64
from .env_fast_batch import TILE_SHIFT, T_STOP, FastBatch
from .env_fast_frame import (ALL_BITS, LANES, NPIX, NQ, Q_A, Q_B, Q_BL, Q_C, Q_CUT, Q_G, Q_O,
                             Q_R, Q_X, Q_Y, Q_Z, ROW, blend_window, clear_tile, cull_project,
                             depth_order, finish_tile, sort_bin)

U64 = np.uint64
CHECK_EVERY = 32  # splats between two scans of the tile for stopped pixels

F32 = np.float32


@njit(cache=True)
def finish_u8(color, alpha, depth_acc, bg, empty_alpha, rgb_u8, depth):
    """color [H, W, 3] (premultiplied), alpha [H, W], depth_acc [H, W] -> rgb_u8 [H, W, 3]
    = u8(clip(color + (1 - alpha) bg, 0, 1) 255 + 0.5), depth [H, W] = depth_acc / alpha
    (+inf where alpha < empty_alpha; 0 where alpha is 0 and empty_alpha is 0). float32."""
    H, W = alpha.shape
    one, lo = F32(1.0), F32(1e-6)
    for i in range(H):
        for j in range(W):
            a = alpha[i, j]
            for c in range(3):
                v = color[i, j, c] + (one - a) * bg[c]
                v = min(max(v, F32(0.0)), one)
                rgb_u8[i, j, c] = np.uint8(v * F32(255.0) + F32(0.5))
            d = depth_acc[i, j] / max(a, lo) if a > F32(0.0) else F32(0.0)
            depth[i, j] = np.inf if a < empty_alpha else d


def finish_u8_reference(color: np.ndarray, alpha: np.ndarray, depth_acc: np.ndarray,
                        bg: np.ndarray, empty_alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """Plain numpy `finish_u8`: (rgb [H, W, 3] uint8, depth [H, W] float32)."""
    one = np.float32(1.0)
    rgb = color + (one - alpha)[..., None] * bg.astype(np.float32)  # [H, W, 3] float32
    rgb_u8 = (rgb.clip(0.0, 1.0) * np.float32(255.0) + np.float32(0.5)).astype(np.uint8)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(alpha > 0, depth_acc / np.maximum(alpha, np.float32(1e-6)), 0).astype(np.float32)
    d[alpha < empty_alpha] = np.inf
    return rgb_u8, d


@njit(cache=True, fastmath=True)
def _scan_stopped(pix, tw, th, t_stop, rdone):
    """rdone[r] = bits of the tile's row r whose T is below t_stop (or outside the tile);
    returns how many pixels are still live."""
    live = 0
    for r in range(th):
        bits = ~(ALL_BITS >> U64(64 - tw))
        rb = r * ROW
        for x in range(tw):
            bits |= U64(pix[U64(rb + x)] < t_stop) << U64(x)
        rdone[r] = bits
        live += tw - np.int64(popc64(bits & (ALL_BITS >> U64(64 - tw))))
    return live


@njit(cache=True, fastmath=True)
def composite_view(q, box, offsets, inst, t0, x0, y0, x1, y1, t_stop, t_fill, pix, rdone, color,
                   alpha, depth):
    """`env_fast_frame.composite_fast`'s pixels (same blends in the same order) with the stopped
    pixels found by a scan of the tile every CHECK_EVERY splats instead of per blended row."""
    tw = x1 - x0
    th = y1 - y0
    clear_tile(pix, rdone, tw, th)
    since = 0
    for k in range(offsets[t0], offsets[t0 + 1]):
        v = inst[k]
        bx0 = max(box[v, 0], x0)
        bx1 = min(box[v, 2] + 1, x1)
        if bx1 <= bx0:
            continue
        by0 = max(box[v, 1], y0)
        by1 = min(box[v, 3] + 1, y1)
        mx, my, ca, cb, cc = q[v, Q_X], q[v, Q_Y], q[v, Q_A], q[v, Q_B], q[v, Q_C]
        o, ct = q[v, Q_O], q[v, Q_CUT]
        c0, c1, c2, c3 = q[v, Q_R], q[v, Q_G], q[v, Q_BL], q[v, Q_Z]
        hca = F32(0.5) * ca
        lo = bx0 - x0
        hi = bx1 - 1 - x0
        boxbits = (ALL_BITS >> U64(63 - (hi - lo))) << U64(lo)
        for py in range(by0, by1):
            ry = py - y0
            if rdone[ry] & boxbits == boxbits:
                continue  # every pixel of this row's box span had stopped at the last scan
            dy = F32(py) + F32(0.5) - my
            bdy = cb * dy
            hcdy = F32(0.5) * cc * dy * dy
            rb = ry * ROW
            for c in range(lo, hi + 1, LANES):
                blend_window(pix, U64(rb + c), F32(x0 + c) + F32(0.5) - mx, U64(hi - c), hca,
                             bdy, hcdy, ct, o, c0, c1, c2, c3, t_stop, LANES)  # counts unused
        since += 1
        if since == CHECK_EVERY:
            since = 0
            if _scan_stopped(pix, tw, th, t_stop, rdone) <= 0:
                break
    finish_tile(pix, x0, y0, x1, y1, t_fill, color, alpha, depth)


@njit(cache=True)
def render_view_u8(c0, c1, centers, r_means, rho, cell_start, pk, cell_mask, view, cam, width, height,
                   shift, near, far, cov_alpha, t_stop, t_fill, bg, empty_alpha, q, box, qs, bs,
                   keys, rows, inst, offsets, pix, rdone, color, alpha, depth_acc, rgb_u8, depth):
    """`env_fast_frame.render_fast_frame`'s phases for one camera (cells c0:c1; the composite by
    `composite_view`), finished by `finish_u8`. Scratch: q / qs [G, NQ], box / bs [G, 4], keys / rows [2, G], inst [M]
    (grown when short: the returned array), offsets [T+1], pix [5 NPIX], rdone [32],
    color [H, W, 3], alpha / depth_acc [H, W]; outputs rgb_u8 [H, W, 3], depth [H, W]."""
    n, _ = cull_project(c0, c1, centers, r_means, rho, cell_start, pk, cell_mask, view, cam,
                        width, height, near, far, cov_alpha, q, box)
    order = depth_order(q, n, keys[0], keys[1], rows[0], rows[1])
    tile = 1 << shift
    tiles_x = (width + tile - 1) >> shift
    tiles_y = (height + tile - 1) >> shift
    inst = sort_bin(q, box, n, order, qs, bs, shift, tiles_x, tiles_x * tiles_y, offsets, inst)
    for ty in range(tiles_y):
        for tx in range(tiles_x):
            x0, y0 = tx << shift, ty << shift
            composite_view(qs, bs, offsets, inst, ty * tiles_x + tx, x0, y0, min(x0 + tile, width),
                           min(y0 + tile, height), F32(t_stop), F32(t_fill), pix, rdone, color,
                           alpha, depth_acc)
    finish_u8(color, alpha, depth_acc, bg, F32(empty_alpha), rgb_u8, depth)
    return inst


class FastView:
    """Scene 0 of a FastBatch drawn for one W x H camera at a time (not thread-safe)."""

    def __init__(self, batch: FastBatch, width: int, height: int, near: float, far: float,
                 cov_cull_alpha: float | None, t_stop: float = T_STOP, empty_alpha: float = 0.5,
                 background: Sequence[float] = (0.0, 0.0, 0.0), tile_shift: int = TILE_SHIFT) -> None:
        if not 0 <= tile_shift <= 5:
            raise ValueError("FastView: tiles are 1 to 32 px (tile_shift 0 to 5)")
        self.batch, self.W, self.H, self.shift = batch, int(width), int(height), int(tile_shift)
        self.near, self.far = float(near), float(far)
        self.cov_alpha = -1.0 if cov_cull_alpha is None else float(cov_cull_alpha)
        self.t_stop = max(float(t_stop), 1e-4)
        self.empty_alpha = float(empty_alpha)
        self.bg = np.asarray(background, np.float32).reshape(3)
        G = batch.max_rows
        self._q, self._box = np.empty((2, G, NQ), np.float32), np.empty((2, G, 4), np.int32)
        self._keys, self._rows = np.empty((2, G), np.uint32), np.empty((2, G), np.int32)
        self._inst = np.empty(4 * batch.max_rows + 1024, np.int32)
        tile = 1 << self.shift
        n_tiles = ((self.W + tile - 1) >> self.shift) * ((self.H + tile - 1) >> self.shift)
        self._offsets = np.empty(n_tiles + 1, np.int64)
        self._pix, self._rdone = np.empty(5 * NPIX, np.float32), np.empty(32, np.uint64)
        self._color = np.empty((self.H, self.W, 3), np.float32)
        self._alpha = np.empty((self.H, self.W), np.float32)
        self._depth_acc = np.empty((self.H, self.W), np.float32)
        self._cam = np.empty(4, np.float64)

    def draw(self, world_to_cam: np.ndarray, fx: float, fy: float, cx: float, cy: float,
             cell_mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(rgb [H, W, 3] uint8, depth [H, W] float32, +inf where empty): new arrays.
        cell_mask [C] uint64: the rows of each culling cell to draw (`cull_project`; a view
        set's mask, `env_view_sets.ViewSets.mask`); None: every splat."""
        b = self.batch
        mask = b.all_cells if cell_mask is None else cell_mask
        view = np.ascontiguousarray(world_to_cam, dtype=np.float64)  # [4, 4]
        self._cam[:] = (fx, fy, cx, cy)
        rgb = np.empty((self.H, self.W, 3), np.uint8)
        depth = np.empty((self.H, self.W), np.float32)
        self._inst = render_view_u8(
            b.cell_lo[0], b.cell_lo[1], b.centers, b.r_means, b.rho, b.cell_start, b.packed, mask, view,
            self._cam, self.W, self.H, self.shift, self.near, self.far, self.cov_alpha,
            self.t_stop, self.t_stop, self.bg, self.empty_alpha, self._q[0], self._box[0],
            self._q[1], self._box[1], self._keys, self._rows, self._inst, self._offsets, self._pix,
            self._rdone, self._color, self._alpha, self._depth_acc, rgb, depth)
        return rgb, depth
