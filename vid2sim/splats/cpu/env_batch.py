"""Batched env rendering: N cameras (one per env, possibly different scenes) in one call.

`SceneBatch(scenes)` packs StaticScenes once (concatenated arrays, global cell rows);
`.render(cameras, scene_ids)` renders every camera in one numba call (`env_frame.render_frames`),
one whole frame per worker. `render_many(scenes, cameras, scene_ids)` does both (an actor
stepping the same envs should keep its SceneBatch: packing copies the scenes).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numba
import numpy as np
import torch

from ..camera import Camera
from ..types import RasterSettings
from .composite import kernel_tile
from .env_frame import NS, render_frames
from .project import NF, camera_arrays


@dataclass
class EnvFrames:
    """Env outputs of N cameras (torch views of numpy buffers, float32 unless noted).

    rgb [N, H, W, 3] over the background; alpha [N, H, W]; depth [N, H, W] expected camera z
    (0 where empty); blends [N, H, W] int32 blended splats per pixel (None from FastBatch);
    stats [N, NS] float64
    (splats in view, tile instances, blends, covered pixels: env_frame.S_* columns)."""

    rgb: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor
    blends: Optional[torch.Tensor]
    stats: np.ndarray



def check_batch(caller: str, cameras: Sequence[Camera], scene_ids: Optional[Sequence[int]],
                n_scenes: int, settings: Optional[RasterSettings]) -> tuple[RasterSettings, np.ndarray]:
    """The settings (default: the first camera's size) and scene index per camera [N] int64
    (default all 0) of a batched render call; ValueError naming `caller` when a camera's size
    differs or an index is outside the batch's scenes."""
    c0 = cameras[0]
    st = settings or RasterSettings(c0.width, c0.height)
    W, H, N = st.width, st.height, len(cameras)
    if any((c.width, c.height) != (W, H) for c in cameras):
        raise ValueError(f"{caller}: every camera must be {W}x{H}")
    ids = np.zeros(N, np.int64) if scene_ids is None else np.asarray(scene_ids, np.int64)
    if ids.shape != (N,) or (N and (ids.min() < 0 or ids.max() >= n_scenes)):
        raise ValueError(f"scene_ids must be {N} indices into {n_scenes} scenes")
    return st, ids


class SceneBatch:
    """StaticScenes packed for `render_frames` (exact, non-LOD scenes only)."""

    def __init__(self, scenes: Sequence) -> None:
        if any(s.lod is not None for s in scenes):
            raise ValueError("SceneBatch: LOD scenes are not supported (use lod=False)")
        self.scenes = list(scenes)
        self.sh_degree = max(s.sh_degree for s in scenes)
        k = max(s.sh.shape[1] for s in scenes)
        row0 = np.cumsum([0] + [len(s.means) for s in scenes])  # [S+1] first Gaussian row
        self.cell_lo = np.cumsum([0] + [len(s.centers) for s in scenes]).astype(np.int64)
        cat = np.concatenate
        self.centers = cat([s.centers for s in scenes])  # [C, 3]
        self.r_means = cat([s.r_means for s in scenes])  # [C]
        self.rho = cat([s.rho for s in scenes])  # [C]
        self.cell_start = cat([s.cell_start[:-1] + row0[i] for i, s in enumerate(scenes)]
                              + [row0[-1:]]).astype(np.int64)  # [C+1] global rows
        self.means = cat([s.means for s in scenes])  # [G, 3]
        self.cov = cat([s.cov for s in scenes])  # [G, 6]
        self.opacity = cat([s.opacity for s in scenes])  # [G]
        self.cut = cat([s.cut for s in scenes])  # [G]
        self.normal = cat([s.normal for s in scenes])  # [G, 3]
        self.rgb = cat([s.rgb for s in scenes])  # [G, 3]
        self.sh = cat([np.pad(s.sh, ((0, 0), (0, k - s.sh.shape[1]), (0, 0)))
                       for s in scenes]).astype(np.float32)  # [G, K, 3]
        self.max_rows = max(1, max(len(s.means) for s in scenes))
        self._scratch: Optional[tuple] = None

    def _scratch_for(self, workers: int, H: int, W: int) -> tuple:
        key = (workers, H, W)
        if self._scratch is None or self._scratch[0] != key:
            G = self.max_rows
            self._scratch = (key, np.empty((workers, G), np.int64), np.empty((workers, G, NF), np.float32),
                             np.empty((workers, G, 4), np.int32), np.empty((workers, G), np.int32),
                             np.empty((workers, H, W, 3), np.float32))
        return self._scratch[1:]

    def render(self, cameras: Sequence[Camera], scene_ids: Optional[Sequence[int]] = None,
               settings: Optional[RasterSettings] = None,
               background: Sequence[float] = (0.0, 0.0, 0.0), blend_cap: int = 0,
               t_stop: float = 0.0, n_workers: Optional[int] = None) -> EnvFrames:
        """Render camera i of scene scene_ids[i] (default all 0); every camera has the
        settings' size. Approximations (off by default = exact): blend_cap > 0 stops a pixel
        after that many blends; t_stop > 0 once its transmittance is below t_stop."""
        st, ids = check_batch("SceneBatch.render", cameras, scene_ids, len(self.scenes), settings)
        W, H, N = st.width, st.height, len(cameras)
        arrs = [camera_arrays(c) for c in cameras]
        views = np.stack([a[0] for a in arrs]) if N else np.zeros((0, 4, 4))  # [N, 4, 4]
        campos = np.stack([a[1] for a in arrs]) if N else np.zeros((0, 3))  # [N, 3]
        cams = np.stack([a[2] for a in arrs]) if N else np.zeros((0, 4))  # [N, 4]
        workers = max(1, min(n_workers or numba.get_num_threads(), N))
        sel, fo, box, radii, color = self._scratch_for(workers, H, W)
        rgb = np.empty((N, H, W, 3), np.float32)
        alpha, depth = np.empty((N, H, W), np.float32), np.empty((N, H, W), np.float32)
        blends = np.empty((N, H, W), np.int32)
        stats = np.zeros((N, NS), np.float64)
        cov_alpha = -1.0 if st.cov_cull_alpha is None else float(st.cov_cull_alpha)
        bg = np.asarray(background, np.float32).reshape(3)
        render_frames(ids, self.cell_lo, self.centers, self.r_means, self.rho, self.cell_start,
                      self.means, self.cov, self.opacity, self.cut, self.normal, self.rgb,
                      self.sh, min(st.active_sh_degree, self.sh_degree), views, campos, cams,
                      W, H, kernel_tile(st.tile_size), float(st.near), float(st.far),
                      cov_alpha, int(blend_cap), float(t_stop), bg, sel, fo, box, radii, color, rgb, alpha,
                      depth, blends, stats, workers)
        t = torch.from_numpy
        return EnvFrames(rgb=t(rgb), alpha=t(alpha), depth=t(depth), blends=t(blends),
                         stats=stats)


def render_many(scenes: Sequence, cameras: Sequence[Camera],
                scene_ids: Optional[Sequence[int]] = None, **kw) -> EnvFrames:
    """Pack `scenes` and render camera i of scene scene_ids[i] in one call (see SceneBatch)."""
    return SceneBatch(scenes).render(cameras, scene_ids, **kw)
