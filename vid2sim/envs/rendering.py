"""What the robot sees: splats (rgb / depth variants) or the coloured visual mesh (mesh-rgb).

`SceneView.draw(world_to_cam)` returns (rgb [H, W, 3] uint8, depth [H, W] float32, +inf where
nothing was drawn). Splats are rendered with `vid2sim.splats` StaticScene (cpu backend, forward
only) with the paper's screen-space covariance culling on; pixels whose splat coverage is below
0.5 read as empty (+inf depth). `FastSplatView` is the approximate fast path (fidelity "fast"):
the scene's sim-ready set (`envs/simready.py`) through `splats.cpu.FastBatch`'s kernels, drawn
by `splats.cpu.env_fast_view.FastView` (one numba call from the pose to the uint8 image), same outputs.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
import torch

from vid2sim.envs.camera import intrinsics, splat_camera
from vid2sim.envs.config import CameraConfig, FastRenderConfig
from vid2sim.envs.raster import rasterize
from vid2sim.envs.scenes import MeshData, SceneAssets
from vid2sim.envs.simready import SimReadySet, sim_ready_set
from vid2sim.splats import GaussianModel, RasterSettings
from vid2sim.splats.cpu import StaticScene, StaticSceneConfig
from vid2sim.splats.cpu.env_batch import SceneBatch
from vid2sim.splats.cpu.env_fast_view import FastView

EMPTY_ALPHA = 0.5



def view_outputs(rgb: torch.Tensor, depth: torch.Tensor, alpha: torch.Tensor
                 ) -> tuple[np.ndarray, np.ndarray]:
    """A splat render as the envs use it: (rgb [H, W, 3] uint8, depth [H, W] float32, +inf
    where the coverage is below EMPTY_ALPHA)."""
    rgb_u8 = (rgb.numpy().clip(0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)  # [H, W, 3]
    d = depth.numpy().astype(np.float32)  # [H, W], a copy when not float32 already
    d[alpha.numpy() < EMPTY_ALPHA] = np.inf
    return rgb_u8, d


class SplatView:
    """Exact splat renderer for one scene (not thread-safe: one StaticScene per env). Without LOD
    it draws through the whole-frame kernel (`SceneBatch`: the same pixels as
    `StaticScene.render`, bit for bit, in one numba call); with LOD through `StaticScene.render`."""

    def __init__(self, model: GaussianModel, conf: CameraConfig, lod: bool = False) -> None:
        self.conf = conf
        self.K = intrinsics(conf)
        self.scene = StaticScene(model, StaticSceneConfig(lod=lod, per_splat_outputs=False))
        self.batch = None if lod else SceneBatch([self.scene])
        self.settings = RasterSettings(conf.width, conf.height, near=conf.near, far=conf.far,
                                       cov_cull_alpha=conf.cov_cull_alpha,
                                       active_sh_degree=model.sh_degree)

    def draw(self, world_to_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        camera = splat_camera(self.conf, world_to_cam)
        if self.batch is None:
            out = self.scene.render(camera, self.settings)
            return view_outputs(out.rgb, out.depth, out.alpha)
        frames = self.batch.render([camera], settings=self.settings, n_workers=1)
        return view_outputs(frames.rgb[0], frames.depth[0], frames.alpha[0])


class FastSplatView:
    """Fast approximate splat renderer: the scene's sim-ready set, built once per process on
    first use (the first reset; an env that never draws, e.g. a privileged one, never builds it)."""

    def __init__(self, assets: SceneAssets, conf: CameraConfig, fast: FastRenderConfig) -> None:
        self.conf, self.fast, self.assets = conf, fast, assets
        self.K = intrinsics(conf)
        self._sim: Optional[SimReadySet] = None
        self._view: Optional[FastView] = None
        self.settings = RasterSettings(conf.width, conf.height, near=conf.near, far=conf.far,
                                       cov_cull_alpha=conf.cov_cull_alpha, active_sh_degree=0)

    @property
    def sim(self) -> SimReadySet:
        if self._sim is None:
            a = self.assets
            self._sim = sim_ready_set(a.content_key(), a.splats, a.walkable, self.conf, self.fast,
                                      cache_dir=a.bundle_dir.parent / "simready")
        return self._sim

    def draw(self, world_to_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The pixels of `sim.batch.render` + `view_outputs` (tests/test_splats_fastview.py)."""
        if self._view is None:  # its own scratch: the batch is shared by the envs of a process
            c = self.conf
            self._view = FastView(self.sim.batch, c.width, c.height, c.near, c.far,
                                  c.cov_cull_alpha, self.fast.t_stop, EMPTY_ALPHA)
        K, views = self.K, self.sim.views
        mask = None if views is None else views.mask(world_to_cam)
        return self._view.draw(world_to_cam, K[0, 0], K[1, 1], K[0, 2], K[1, 2], mask)


class MeshView:
    """The paper's traditional-simulator baseline: the bundle's coloured visual mesh, rasterised."""

    def __init__(self, mesh: MeshData, conf: CameraConfig) -> None:
        self.conf = conf
        self.K = intrinsics(conf)
        self.mesh = mesh

    def draw(self, world_to_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m, c = self.mesh, self.conf
        return rasterize(m.vertices, m.faces, m.face_colors, self.K, world_to_cam, c.width, c.height)


def depth_to_u8(depth: np.ndarray, depth_max: float) -> np.ndarray:
    """Metric depth [H, W] -> uint8 [H, W] (0 m -> 0, >= depth_max or empty -> 255)."""
    d = np.where(np.isfinite(depth), depth, depth_max)
    return (np.clip(d / depth_max, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)

