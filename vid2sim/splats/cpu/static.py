"""Forward-only rendering of a static scene from many views (the env path).

`StaticScene(model)` caches what does not depend on the view (world covariances,
opacities, shortest-axis normals, DC colours) and groups splats into spatial cells
(Morton order, `cell_size` splats each) so whole cells are frustum-culled before any
projection; `render(camera, settings, background)` returns a RenderOutput without autograd.
Images equal `rasterize` up to float rounding; `raw.radii`/`raw.means2d` cover only the
splats that were projected (culled cells read as 0), and `raw.grad2d`/`raw.absgrad` are None.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from ..camera import Camera
from ..model import GaussianModel
from ..sh import C0
from ..types import RasterOutput, RasterSettings, RenderOutput
from .function import camera_arrays, composite
from .preprocess import NF
from .static_kernels import (compact, cull_cells, finish_images, project_static,
                             scatter_visible, sigma_cuts)

ALPHA_MIN = 1.0 / 255.0


@dataclass(frozen=True)
class StaticSceneConfig:
    """cell_size: splats per culling cell (Morton-ordered runs)."""

    cell_size: int = 256


def _morton_order(xyz: np.ndarray) -> np.ndarray:
    """Order [N] of points xyz [N, 3] along a 3D Morton (Z-order) curve, 10 bits per axis."""
    lo, hi = xyz.min(0), xyz.max(0)
    q = ((xyz - lo) / np.maximum(hi - lo, 1e-9) * 1023).astype(np.uint64)
    code = np.zeros(len(xyz), np.uint64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return np.argsort(code, kind="stable")


class StaticScene:
    """A GaussianModel frozen for fast, forward-only, multi-view rendering."""

    def __init__(self, model: GaussianModel, config: StaticSceneConfig = StaticSceneConfig()):
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
        order = _morton_order(means.numpy())
        self.num = model.num
        self.sh_degree = model.sh_degree
        self.index = keep.numpy()[order]  # [K] model index of each cached splat
        self.means = np.ascontiguousarray(means.numpy()[order])
        c = cov.numpy()[order]
        self.cov = np.ascontiguousarray(np.stack([c[:, 0, 0], c[:, 0, 1], c[:, 0, 2], c[:, 1, 1],
                                                  c[:, 1, 2], c[:, 2, 2]], 1))
        self.opacity = np.ascontiguousarray(op.numpy()[order])
        self.cut = sigma_cuts(self.opacity)
        self.normal = np.ascontiguousarray(normal.numpy()[order])
        self.rgb = np.ascontiguousarray(rgb.numpy()[order])
        self.sh = np.ascontiguousarray(sh.numpy()[order])
        self._build_cells(rho.numpy()[order], config.cell_size)

    def _build_cells(self, rho: np.ndarray, size: int) -> None:
        n = len(self.means)
        self.cell_start = np.arange(0, n + size, size).clip(max=n)
        self.cell_start = np.unique(self.cell_start)  # [C+1]
        starts = self.cell_start[:-1]
        lo = np.minimum.reduceat(self.means, starts, axis=0) if n else np.zeros((0, 3))
        hi = np.maximum.reduceat(self.means, starts, axis=0) if n else np.zeros((0, 3))
        self.centers = (0.5 * (lo + hi)).astype(np.float64)
        self.r_means = 0.5 * np.linalg.norm(hi - lo, axis=1).astype(np.float64)
        self.rho = (np.maximum.reduceat(rho, starts) if n else np.zeros(0)).astype(np.float64)

    def render(self, camera: Camera, settings: RasterSettings | None = None,
               background: Sequence[float] | torch.Tensor = (0.0, 0.0, 0.0)) -> RenderOutput:
        """Render one view (forward only); reads the cached scene, returns [H, W, C] images."""
        settings = settings or RasterSettings(camera.width, camera.height)
        if (settings.width, settings.height) != (camera.width, camera.height):
            raise ValueError(f"RasterSettings size {settings.width}x{settings.height} differs "
                             f"from camera size {camera.width}x{camera.height}")
        W, H = settings.width, settings.height
        view, campos, cam = camera_arrays(camera)
        cov_alpha = -1.0 if settings.cov_cull_alpha is None else float(settings.cov_cull_alpha)
        deg = min(settings.active_sh_degree, self.sh_degree)
        cells = cull_cells(self.centers, self.r_means, self.rho, view, cam, W, H,
                           float(settings.near), float(settings.far))
        counts = self.cell_start[cells + 1] - self.cell_start[cells]
        row_start = np.zeros(len(cells) + 1, np.int64)
        np.cumsum(counts, out=row_start[1:])
        rows = int(row_start[-1])
        fo = np.empty((rows, NF), np.float32)
        box = np.empty((rows, 4), np.int32)
        radii = np.empty(rows, np.int32)
        src = np.empty(rows, np.int64)
        project_static(cells, self.cell_start, row_start, self.means, self.cov, self.opacity,
                       self.cut, self.normal, self.rgb, self.sh, deg, view, campos, cam, W, H,
                       float(settings.near), float(settings.far), cov_alpha, fo, box, radii, src)
        fo_v, box_v, ids = compact(fo, box, radii, src)
        (_, _, color, alpha, depth_acc, normal_acc, median, _, _, _) = composite(
            fo_v, box_v, W, H, settings.tile_size)
        rgb = np.empty((H, W, 3), np.float32)
        depth = np.empty((H, W), np.float32)
        normal = np.empty((H, W, 3), np.float32)
        bg = np.asarray(torch.as_tensor(background, dtype=torch.float32).reshape(3).numpy(),
                        np.float32)
        finish_images(color, alpha, depth_acc, normal_acc, bg, rgb, depth, normal)
        means2d = np.empty((self.num, 2), np.float32)
        radii_out = np.empty(self.num, np.int32)
        scatter_visible(fo_v, ids, self.index, radii, self.num, means2d, radii_out)
        t = torch.from_numpy
        raw = RasterOutput(color_accum=t(color), alpha=t(alpha), depth_accum=t(depth_acc),
                           normal_accum=t(normal_acc), median_depth=t(median),
                           means2d=t(means2d), radii=t(radii_out))
        return RenderOutput(rgb=t(rgb), alpha=raw.alpha, depth=t(depth),
                            median_depth=raw.median_depth, normal=t(normal), raw=raw)
