"""`rasterize` for the cpu backend: a torch.autograd.Function over the numba kernels.

Forward: project -> bin -> per-tile composite (numba, parallel). Backward is hand-written:
per-tile back-to-front pass -> per-splat projection VJP. grad2d / absgrad of the returned
RasterOutput are filled (added into) by backward, as docs/splat_renderer.md specifies.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numba
import numpy as np
import torch

from ..camera import Camera
from ..sh import sh_degree_from_coeffs
from ..types import RasterOutput, RasterSettings
from .binning import sort_and_bin
from .composite import kernel_tile, raster_backward, raster_forward
from .project import F_X, F_Y, NF, camera_arrays, project_backward, project_forward


def _np32(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().to(torch.float32).cpu().numpy())


@dataclass
class Frame:
    """Everything forward keeps for backward and for the caller (numpy, float32)."""

    ids: np.ndarray  # [V] int64 visible splat indices (model order)
    fo: np.ndarray  # [V, NF] per-visible-splat screen quantities
    box: np.ndarray  # [V, 4] int32 pixel box (j0, i0, j1, i1 inclusive)
    tile_offsets: np.ndarray  # [n_tiles + 1]
    inst: np.ndarray  # [M] visible index per (tile, depth) instance
    row_start: np.ndarray  # [V + 1] visible splat v's instances: pos[row_start[v]:...]
    pos: np.ndarray  # [M] instance slots grouped by visible splat
    color: np.ndarray  # [H, W, 3]
    alpha: np.ndarray  # [H, W]
    depth: np.ndarray  # [H, W]
    normal: np.ndarray  # [H, W, 3]
    median: np.ndarray  # [H, W]
    T_final: np.ndarray  # [H, W]
    n_contrib: np.ndarray  # [H, W] int32
    med_idx: np.ndarray  # [H, W] int32
    means2d: np.ndarray  # [N, 2]
    radii: np.ndarray  # [N] int32


def composite(fo: np.ndarray, box: np.ndarray, width: int, height: int, tile: int,
              want_median: bool = True) -> tuple:
    """Bin the visible splats (fo [V, NF], box [V, 4]) and composite all tiles."""
    tiles_x = (width + tile - 1) // tile
    n_tiles = tiles_x * ((height + tile - 1) // tile)
    offsets, inst, row_start, pos = sort_and_bin(fo, box, fo.shape[0], tile, tiles_x, n_tiles,
                                                 True, numba.get_num_threads())
    color = np.empty((height, width, 3), np.float32)
    normal = np.empty((height, width, 3), np.float32)
    alpha, depth, median, T_final = (np.empty((height, width), np.float32) for _ in range(4))
    n_contrib = np.empty((height, width), np.int32)
    med_idx = np.empty((height, width), np.int32)
    raster_forward(fo, box, offsets, inst, width, height, tile, color, alpha, depth, normal,
                   median, T_final, n_contrib, med_idx, numba.get_num_threads(), want_median)
    return (offsets, inst, row_start, pos, color, alpha, depth, normal, median, T_final,
            n_contrib, med_idx)


_SCRATCH = threading.local()


def _scratch(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-thread (idx [n] = 0..n-1, fo [n, NF], box [n, 4]) reused across forwards: the
    full-N projection rows are only read until the visible rows are copied out."""
    cur = getattr(_SCRATCH, "bufs", None)
    if cur is None or cur[0].shape[0] != n:
        cur = (np.arange(n, dtype=np.int64), np.empty((n, NF), np.float32),
               np.empty((n, 4), np.int32))
        _SCRATCH.bufs = cur
    return cur


def forward_frame(means, quats, log_scales, logits, sh, deg: int, camera: Camera,
                  settings: RasterSettings) -> Frame:
    """Run the whole forward on float32 numpy inputs."""
    view, campos, cam = camera_arrays(camera)
    W, H, tile = settings.width, settings.height, kernel_tile(settings.tile_size)
    N = means.shape[0]
    idx, fo, box = _scratch(N)
    radii = np.empty(N, np.int32)
    cov_alpha = -1.0 if settings.cov_cull_alpha is None else float(settings.cov_cull_alpha)
    project_forward(idx, means, quats, log_scales, logits, sh, deg,
                    view, campos, cam, W, H, float(settings.near), float(settings.far),
                    cov_alpha, fo, box, radii, numba.get_num_threads())
    ids = np.flatnonzero(radii)
    fo_v, box_v = fo[ids], box[ids]
    parts = composite(fo_v, box_v, W, H, tile, settings.median_depth)
    means2d = np.zeros((N, 2), np.float32)
    means2d[ids, 0] = fo_v[:, F_X]
    means2d[ids, 1] = fo_v[:, F_Y]
    return Frame(ids, fo_v, box_v, *parts, means2d=means2d, radii=radii)


class _Rasterize(torch.autograd.Function):
    """Inputs: the five model tensors + a Setup holder; outputs: the raw images."""

    @staticmethod
    def forward(ctx, means, quats, log_scales, logits, sh, setup):
        arrays = [_np32(t) for t in (means, quats, log_scales, logits, sh)]
        frame = forward_frame(*arrays, setup.deg, setup.camera, setup.settings)
        ctx.setup, ctx.frame, ctx.arrays = setup, frame, arrays
        dt = means.dtype
        outs = [torch.from_numpy(a).to(dt) for a in
                (frame.color, frame.alpha, frame.depth, frame.normal, frame.median,
                 frame.means2d)]
        radii = torch.from_numpy(frame.radii)
        ctx.mark_non_differentiable(outs[5], radii)
        return (*outs, radii)

    @staticmethod
    def backward(ctx, d_color, d_alpha, d_depth, d_normal, d_median, _d_m2d, _d_radii):
        setup, fr = ctx.setup, ctx.frame
        means, quats, log_scales, logits, sh = ctx.arrays
        H, W = fr.alpha.shape
        grads = [np.zeros((H, W, 3), np.float32) if g is None else _np32(g)
                 for g in (d_color, d_normal)]
        d_color_np, d_normal_np = grads
        d_alpha_np, d_depth_np, d_median_np = (np.zeros((H, W), np.float32) if g is None
                                               else _np32(g)
                                               for g in (d_alpha, d_depth, d_median))
        g2 = raster_backward(fr.fo, fr.box, fr.tile_offsets, fr.inst, fr.row_start, fr.pos,
                             fr.ids.shape[0], W, H,
                             kernel_tile(setup.settings.tile_size), fr.T_final, fr.n_contrib,
                             fr.med_idx,
                             d_color_np, d_alpha_np, d_depth_np, d_normal_np, d_median_np,
                             numba.get_num_threads())
        out = [np.zeros_like(a) for a in (means, quats, log_scales, logits, sh)]
        # grad2d / absgrad: the kernel adds straight into the caller's float32 buffers
        direct = setup.grad2d.dtype == torch.float32
        grad2d = setup.grad2d.numpy() if direct else np.zeros(setup.grad2d.shape, np.float32)
        want_abs = setup.absgrad is not None
        absgrad = (setup.absgrad.numpy() if direct and want_abs
                   else np.zeros(setup.grad2d.shape, np.float32))
        view, campos, cam = camera_arrays(setup.camera)
        project_backward(fr.ids, means, quats, log_scales, logits, sh, setup.deg, view, campos,
                         cam, W, H, g2, *out, grad2d, absgrad, want_abs,
                         numba.get_num_threads())
        if not direct:
            setup.grad2d.add_(torch.from_numpy(grad2d).to(setup.grad2d.dtype))
            if want_abs:
                setup.absgrad.add_(torch.from_numpy(absgrad).to(setup.absgrad.dtype))
        dt = setup.dtype
        return (*(torch.from_numpy(a).to(dt) for a in out), None)


@dataclass
class _Setup:
    camera: Camera
    settings: RasterSettings
    deg: int
    grad2d: torch.Tensor
    absgrad: torch.Tensor | None
    dtype: torch.dtype


def _zeros2(n: int, dt: torch.dtype) -> torch.Tensor:
    """Zero [n, 2] tensor; float32 via numpy (avoids a torch OpenMP region whose spinning
    workers would compete with the numba threads)."""
    if dt == torch.float32:
        return torch.from_numpy(np.zeros((n, 2), np.float32))
    return torch.zeros(n, 2, dtype=dt)


def check_inputs(means, quats, log_scales, opacity_logits, sh, camera, settings) -> None:
    """ValueError naming the offending input when shapes or sizes disagree."""
    if (settings.width, settings.height) != (camera.width, camera.height):
        raise ValueError(f"RasterSettings size {settings.width}x{settings.height} differs from "
                         f"camera size {camera.width}x{camera.height}")
    n = means.shape[0]
    for name, t, shape in (("means", means, (n, 3)), ("quats", quats, (n, 4)),
                           ("log_scales", log_scales, (n, 3)),
                           ("opacity_logits", opacity_logits, (n,))):
        if tuple(t.shape) != shape:
            raise ValueError(f"cpu rasterize: {name} must be {shape}, got {tuple(t.shape)}")
    if sh.ndim != 3 or sh.shape[0] != n or sh.shape[2] != 3:
        raise ValueError(f"cpu rasterize: sh must be [N, K, 3], got {tuple(sh.shape)}")


def rasterize(means, quats, log_scales, opacity_logits, sh, camera: Camera,
              settings: RasterSettings, absgrad: bool = False) -> RasterOutput:
    """Raw accumulations (RasterOutput) for one camera; differentiable w.r.t. the model.

    After `loss.backward()`, `out.grad2d` [N, 2] holds dL/dmeans2d and, with absgrad=True,
    `out.absgrad` [N, 2] the AbsGS sum of per-pixel |dL_p/dmeans2d|.
    """
    check_inputs(means, quats, log_scales, opacity_logits, sh, camera, settings)
    dt, N = means.dtype, means.shape[0]
    deg = min(settings.active_sh_degree, sh_degree_from_coeffs(sh.shape[1]))
    setup = _Setup(camera, settings, deg, _zeros2(N, dt), _zeros2(N, dt) if absgrad else None, dt)
    color, alpha, depth, normal, median, means2d, radii = _Rasterize.apply(
        means, quats, log_scales, opacity_logits, sh, setup)
    return RasterOutput(color_accum=color, alpha=alpha, depth_accum=depth,
                        normal_accum=normal, median_depth=median, means2d=means2d,
                        radii=radii, absgrad=setup.absgrad, grad2d=setup.grad2d)
