"""Forward-only rendering of a static scene from many views (the env path).

`StaticScene(model)` caches what does not depend on the view (world covariances,
opacities, shortest-axis normals, DC colours) and groups splats into spatial cells
(Morton order, `cell_size` splats each) so whole cells are frustum-culled before any
projection; `render(camera, settings, background)` returns a RenderOutput without autograd.
Scratch buffers are kept between frames, so one StaticScene must not render from two
threads at once.

Exact mode (default): images equal `rasterize` up to float rounding; `raw.radii` /
`raw.means2d` cover only the splats that were projected (culled cells read as 0), and
`raw.grad2d` / `raw.absgrad` are None.
Env LOD (`StaticSceneConfig(lod=True)`, opt-in, NOT part of the exact contract; see
docs/splat_renderer.md "Env LOD" and `env_lod.py`): distant octree nodes are drawn as one merged
Gaussian each; merged Gaussians have no model index, so their splats read radii 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numba
import numpy as np
import torch

from vid2sim.ranges import checked

from ..camera import Camera
from ..model import GaussianModel
from ..sh import C0
from ..types import RasterOutput, RasterSettings, RenderOutput
from .binning import sort_and_bin
from .composite import kernel_tile, raster_forward
from .env_lod import LodTree, build_lod, select_lod
from .env_scene_kernels import (cull_cells, finish_images, project_static, scatter_visible,
                                sigma_cuts)
from .project import NF, camera_arrays

ALPHA_MIN = 1.0 / 255.0


@checked
@dataclass(frozen=True)
class StaticSceneConfig:
    """cell_size: splats per culling cell (Morton-ordered runs).

    lod: env level of detail (approximate; off = exact contract). lod_pixel_radius: an octree
    node is drawn as its one merged Gaussian once its standard deviation projects below this
    many px (0.25: >= 35.8 dB PSNR vs exact on the benchmark street poses; 0 = no merging).
    per_splat_outputs: fill raw.means2d / raw.radii ([N] model order); False leaves them
    0-size (saves writing O(N) per frame when nobody reads them).
    """

    cell_size: int = 256
    lod: bool = False
    lod_pixel_radius: float = 0.25
    per_splat_outputs: bool = True


def _morton_codes(xyz: np.ndarray) -> np.ndarray:
    """30-bit 3D Morton (Z-order) codes [N] uint64 of points xyz [N, 3], 10 bits per axis,
    on one common scale so that octree cells are cubes."""
    lo = xyz.min(0)
    q = ((xyz - lo) / max(float((xyz.max(0) - lo).max()), 1e-9) * 1023).astype(np.uint64)
    code = np.zeros(len(xyz), np.uint64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return code


class StaticScene:
    """A GaussianModel frozen for fast, forward-only, multi-view rendering."""

    def __init__(self, model: GaussianModel, config: StaticSceneConfig = StaticSceneConfig()):
        self.config = config
        with torch.no_grad():
            opacity = torch.sigmoid(model.opacity_logits.float())
            keep = torch.nonzero(opacity >= ALPHA_MIN).squeeze(1)  # others never reach 1/255
            means = model.means.float()[keep]
            q = torch.nn.functional.normalize(model.quats.float()[keep], dim=-1)
            from ..reference import quat_to_rotmat
            R = quat_to_rotmat(q).double()
            ls = model.log_scales.float()[keep]
            s = torch.exp(ls).double()
            M = R * s[:, None, :]
            cov = M @ M.transpose(1, 2)  # [K, 3, 3]
            axis = torch.argmin(ls, dim=1)
            normal = torch.gather(R, 2, axis[:, None, None].expand(-1, 3, 1)).squeeze(2)
            sh = model.sh.float()[keep]
            rgb = torch.clamp_min(C0 * sh[:, 0] + 0.5, 0.0)
            op = opacity[keep].double()
            cut = torch.clamp(torch.log(op * 255.0) + 1e-3, max=4.5)
            rho = torch.sqrt(2.0 * cut.clamp_min(0)) * s.max(dim=1).values
        codes = _morton_codes(means.numpy()) if len(keep) else np.zeros(0, np.uint64)
        order = np.argsort(codes, kind="stable")
        self.num = model.num
        self.sh_degree = model.sh_degree
        self.index = keep.numpy()[order]  # [K] model index of each cached splat
        means_np = np.ascontiguousarray(means.numpy()[order].astype(np.float64))
        c = cov.numpy()[order]
        cov6 = np.stack([c[:, 0, 0], c[:, 0, 1], c[:, 0, 2], c[:, 1, 1], c[:, 1, 2], c[:, 2, 2]], 1)
        opacity_np = op.numpy()[order]
        normal_np = normal.numpy()[order]
        rgb_np = rgb.numpy()[order].astype(np.float64)
        sh_np = sh.numpy()[order]
        self._build_cells(means_np, rho.numpy()[order], config.cell_size)
        self.lod: Optional[LodTree] = None
        if config.lod and len(keep):
            self.lod = build_lod(codes[order], means_np, cov6, opacity_np, sh_np,
                                 rho.numpy()[order], C0)
            t = self.lod
            means_np, cov6 = np.concatenate([means_np, t.means]), np.concatenate([cov6, t.cov])
            opacity_np = np.concatenate([opacity_np, t.opacity])
            normal_np = np.concatenate([normal_np, t.normal])
            rgb_np = np.concatenate([rgb_np, t.rgb])
            sh_np = np.concatenate([sh_np, t.sh])
        # Gaussian arrays [G]: the K splats, then (LOD) the merged nodes
        self.means = means_np
        self.cov = np.ascontiguousarray(cov6)
        self.opacity = np.ascontiguousarray(opacity_np)
        self.cut = sigma_cuts(self.opacity)
        self.normal = np.ascontiguousarray(normal_np)
        self.rgb = np.ascontiguousarray(rgb_np)
        self.sh = np.ascontiguousarray(sh_np)
        self._scratch_rows = 0

    def _build_cells(self, means: np.ndarray, rho: np.ndarray, size: int) -> None:
        n = len(means)
        self.cell_start = np.unique(np.arange(0, n + size, size).clip(max=n))  # [C+1]
        starts = self.cell_start[:-1]
        lo = np.minimum.reduceat(means, starts, axis=0) if n else np.zeros((0, 3))
        hi = np.maximum.reduceat(means, starts, axis=0) if n else np.zeros((0, 3))
        self.centers = (0.5 * (lo + hi)).astype(np.float64)
        self.r_means = 0.5 * np.linalg.norm(hi - lo, axis=1).astype(np.float64)
        self.rho = (np.maximum.reduceat(rho, starts) if n else np.zeros(0)).astype(np.float64)

    def _ensure_scratch(self, H: int, W: int) -> None:
        """Per-frame buffers, reused across renders (grown on demand)."""
        G = len(self.means)
        if self._scratch_rows < G:
            self._sel = np.empty(max(G, 1), np.int64)
            self._stack = np.empty(max(G, 1) + 64, np.int64)
            self._fo = np.empty((max(G, 1), NF), np.float32)
            self._box = np.empty((max(G, 1), 4), np.int32)
            self._radii = np.empty(max(G, 1), np.int32)
            self._scratch_rows = G
        if getattr(self, "_img_shape", None) != (H, W):
            self._T = np.empty((H, W), np.float32)
            self._nc = np.empty((H, W), np.int32)
            self._mi = np.empty((H, W), np.int32)
            self._img_shape = (H, W)

    def select(self, view: np.ndarray, cam: np.ndarray, campos: np.ndarray,
               settings: RasterSettings) -> int:
        """Fill self._sel with the Gaussians to project for this view; returns the count."""
        W, H = settings.width, settings.height
        near, far = float(settings.near), float(settings.far)
        if self.lod is not None:
            t = self.lod
            return select_lod(len(self.index), t.child0, t.nchild, t.center, t.r_means, t.rho,
                              t.ext, t.roots, view, cam, campos, W, H, near, far,
                              float(self.config.lod_pixel_radius), self._sel, self._stack)
        return cull_cells(self.centers, self.r_means, self.rho, self.cell_start, view, cam, W, H,
                          near, far, self._sel)

    def render(self, camera: Camera, settings: RasterSettings | None = None,
               background: Sequence[float] | torch.Tensor = (0.0, 0.0, 0.0)) -> RenderOutput:
        """Render one view (forward only); reads the cached scene, returns [H, W, C] images."""
        settings = settings or RasterSettings(camera.width, camera.height)
        if (settings.width, settings.height) != (camera.width, camera.height):
            raise ValueError(f"RasterSettings size {settings.width}x{settings.height} differs "
                             f"from camera size {camera.width}x{camera.height}")
        W, H, tile = settings.width, settings.height, kernel_tile(settings.tile_size)
        self._ensure_scratch(H, W)
        view, campos, cam = camera_arrays(camera)
        cov_alpha = -1.0 if settings.cov_cull_alpha is None else float(settings.cov_cull_alpha)
        deg = min(settings.active_sh_degree, self.sh_degree)
        n = self.select(view, cam, campos, settings) if len(self.index) else 0
        fo, box, radii = self._fo, self._box, self._radii
        project_static(self._sel, n, self.means, self.cov, self.opacity, self.cut, self.normal,
                       self.rgb, self.sh, deg, view, campos, cam, W, H, float(settings.near),
                       float(settings.far), cov_alpha, fo, box, radii,
                       numba.get_num_threads())
        tiles_x = (W + tile - 1) // tile
        offsets, inst, _, _ = sort_and_bin(fo, box, n, tile, tiles_x,
                                           tiles_x * ((H + tile - 1) // tile), False,
                                           numba.get_num_threads())
        color, normal_acc, rgb, normal = (np.empty((H, W, 3), np.float32) for _ in range(4))
        alpha, depth_acc, median, depth = (np.empty((H, W), np.float32) for _ in range(4))
        raster_forward(fo, box, offsets, inst, W, H, tile, color, alpha, depth_acc, normal_acc,
                       median, self._T, self._nc, self._mi, numba.get_num_threads())
        bg = np.asarray(torch.as_tensor(background, dtype=torch.float32).reshape(3).numpy(),
                        np.float32)
        finish_images(color, alpha, depth_acc, normal_acc, bg, rgb, depth, normal)
        num = self.num if self.config.per_splat_outputs else 0
        means2d = np.empty((num, 2), np.float32)
        radii_out = np.empty(num, np.int32)
        if num:
            scatter_visible(fo, self._sel, n, radii, self.index, num, means2d, radii_out)
        t = torch.from_numpy
        raw = RasterOutput(color_accum=t(color), alpha=t(alpha), depth_accum=t(depth_acc),
                           normal_accum=t(normal_acc), median_depth=t(median),
                           means2d=t(means2d), radii=t(radii_out))
        return RenderOutput(rgb=t(rgb), alpha=raw.alpha, depth=t(depth),
                            median_depth=raw.median_depth, normal=t(normal), raw=raw)
