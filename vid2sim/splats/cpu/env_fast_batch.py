"""Approximate batched env rendering at RL rates: `FastBatch(scenes).render(cameras, ids)`.

The approximate counterpart of `env_batch.SceneBatch` (same call, same `EnvFrames`; what is traded
is listed in `env_fast_frame.py`). Scenes are StaticScenes, normally of sim-ready models
(`env_simready.sim_ready`: pruned, colours baked); each is packed once into float32 field
planes in its culling-cell (Morton) order. One call renders every camera: workers draw whole
frames from a shared counter (`env_fast_frame.render_fast_frames`).
"""

from __future__ import annotations

from typing import Optional, Sequence

import numba
import numpy as np
import torch

from ..camera import Camera
from ..types import RasterSettings
from .env_batch import EnvFrames, check_batch
from .env_fast_frame import ALL_BITS, NQ, NS, pack_splats, render_fast_frames
from .project import camera_arrays

TILE_SHIFT = 5  # fast composite tiles are 2^5 = 32 px, the most it takes (128x72: 4 x 3 tiles)
T_STOP = 0.02  # default opaque-stop transmittance (benchmarks/env_render.py measures others)


class FastBatch:
    """StaticScenes packed for `render_fast_frames` (non-LOD scenes)."""

    def __init__(self, scenes: Sequence) -> None:
        if any(s.lod is not None for s in scenes):
            raise ValueError("FastBatch: LOD scenes are not supported (use lod=False)")
        self.scenes = list(scenes)
        row0 = np.cumsum([0] + [len(s.means) for s in scenes])  # [S+1] first splat row
        cat = np.concatenate
        self.cell_lo = np.cumsum([0] + [len(s.centers) for s in scenes]).astype(np.int64)
        self.centers = cat([s.centers for s in scenes])  # [C, 3]
        self.r_means = cat([s.r_means for s in scenes])  # [C]
        self.rho = cat([s.rho for s in scenes])  # [C]
        self.cell_start = cat([s.cell_start[:-1] + row0[i] for i, s in enumerate(scenes)]
                              + [row0[-1:]]).astype(np.int64)  # [C+1] global rows
        self.packed = pack_splats(cat([s.means for s in scenes]), cat([s.cov for s in scenes]),
                                  cat([s.opacity for s in scenes]),
                                  cat([s.rgb for s in scenes]))  # [NP, G] float32 planes
        self.max_rows = max(1, max(len(s.means) for s in scenes))
        self.all_cells = np.full(len(self.centers), ALL_BITS, np.uint64)  # [C] every row of every cell
        self._scratch: Optional[tuple] = None

    def _scratch_for(self, workers: int, H: int, W: int) -> tuple:
        key = (workers, H, W)
        if self._scratch is None or self._scratch[0] != key:
            G = self.max_rows
            self._scratch = (key, np.empty((workers, 2, G, NQ), np.float32),
                             np.empty((workers, 2, G, 4), np.int32),
                             np.empty((workers, 2, G), np.uint32),
                             np.empty((workers, 2, G), np.int32),
                             np.empty((workers, H, W, 3), np.float32))
        return self._scratch[1:]

    def render(self, cameras: Sequence[Camera], scene_ids: Optional[Sequence[int]] = None,
               settings: Optional[RasterSettings] = None,
               background: Sequence[float] = (0.0, 0.0, 0.0), t_stop: float = T_STOP, fill_alpha: float = 1.0,
               tile_shift: int = TILE_SHIFT, n_workers: Optional[int] = None) -> EnvFrames:
        """Render camera i of scene scene_ids[i] (default all 0), every camera of the
        settings' size (SH degree ignored: one colour per splat). A pixel stops once its
        transmittance is below t_stop (>= 1e-4) and is renormalised (env_fast_frame.py), as is
        every pixel whose alpha reaches fill_alpha (1.0: only the stopped ones).
        `blends` is None (only the per-frame total in stats)."""
        if not 0 <= tile_shift <= 5:
            raise ValueError("FastBatch.render: tiles are 1 to 32 px (tile_shift 0 to 5)")
        st, ids = check_batch("FastBatch.render", cameras, scene_ids, len(self.scenes), settings)
        W, H, N = st.width, st.height, len(cameras)
        views = np.empty((N, 4, 4))
        cams = np.empty((N, 4))
        for i, c in enumerate(cameras):
            views[i], _, cams[i] = camera_arrays(c)
        workers = max(1, min(n_workers or numba.get_num_threads(), N))
        q, box, keys, rows, color = self._scratch_for(workers, H, W)
        rgb = np.empty((N, H, W, 3), np.float32)
        alpha, depth = np.empty((N, H, W), np.float32), np.empty((N, H, W), np.float32)
        stats = np.zeros((N, NS), np.float64)
        cov_alpha = -1.0 if st.cov_cull_alpha is None else float(st.cov_cull_alpha)
        ts = max(float(t_stop), 1e-4)
        t_fill = max(ts, 1.0 - float(fill_alpha))
        render_fast_frames(ids, self.cell_lo, self.centers, self.r_means, self.rho,
                           self.cell_start, self.packed, self.all_cells, views, cams, W, H,
                           int(tile_shift),
                           float(st.near), float(st.far), cov_alpha, ts, t_fill,
                           np.asarray(background, np.float32).reshape(3), q, box, keys, rows,
                           color, rgb, alpha, depth, stats, workers)
        t = torch.from_numpy
        return EnvFrames(rgb=t(rgb), alpha=t(alpha), depth=t(depth), blends=None, stats=stats)
