"""Sim-ready splats: the scene as the robot's 128x72 camera needs it, made once at load.

Choice: made when a scene is loaded for simulation, not stored in the bundle; the
bundle keeps the full splats for viewing. The envs pass robot cameras sampled over the
walkable map (their own cameras; `robot_cameras` makes the same ones from robot poses: the
robot spec's mount and intrinsics, `vid2sim.formats.robot.ROBOT`), and `sim_ready` keeps the
splats that carry the image there:

1. Global significance (LightGaussian-style, but measured rather than estimated from
   opacity x volume): each splat's summed blend weight alpha * T over every pixel of every
   given view, at the env resolution. Sub-pixel splats that never win a pixel, splats hidden
   behind others and splats never in view score ~0.
2. Keep the most significant splats that together carry `keep_mass` of the total measured
   weight; drop the rest (no merging: merged splats changed colours more than dropping the
   least significant ones on the scenes measured).
3. Optionally (`bake_colour`) replace each kept splat's view-dependent SH colour by its
   blend-weighted mean colour over the same views (SH degree 0): what the approximate
   `env_fast_batch.FastBatch` renders.
4. Optionally (`fit_iterations` > 0) fit the kept splats to exact renders of the full scene
   from the same views (`env_simfit.fit_to_views`): recovers most of what harder pruning loses.
5. A per-pixel blend cap / early stop is a render-time setting (`SceneBatch.render`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from vid2sim.formats.robot import ROBOT
from vid2sim.ranges import checked

from ..camera import Camera, look_at
from ..model import GaussianModel
from ..sh import C0
from ..types import RasterSettings
from .env_batch import SceneBatch
from .env_frame import NS, render_frame
from .project import camera_arrays
from .project import F_BL, F_R, NF
from .composite import kernel_tile
from .env_simfit import FitConfig, fit_to_views
from .env_scene import StaticScene

# The robot camera (vid2sim.formats.robot.ROBOT, which the envs' CameraConfig also reads): 128x72,
# Unity's default 60 deg vertical fov (the paper gives only the 1280x720 sensor), centred
# principal point; mounted 0.65 m above the ground, 0.45 m ahead of the robot centre, level.
ENV_WIDTH, ENV_HEIGHT = ROBOT.camera_width_px, ROBOT.camera_height_px
ENV_VFOV_DEG = ROBOT.camera_vfov_deg
ROBOT_CAMERA_HEIGHT_M = ROBOT.camera_height_m
ROBOT_CAMERA_FORWARD_M = ROBOT.camera_forward_m


@checked
@dataclass(frozen=True)
class SimReadyConfig:
    """keep_mass: fraction of the total measured blend weight the kept splats carry.
    width/height: resolution the significance is measured at (the env's). bake_colour: the
    result has SH degree 0 with each splat's blend-weighted mean colour over the views.
    fit_iterations: Adam steps fitting the kept splats to exact renders (0 = no fit)."""

    keep_mass: float = 0.995
    bake_colour: bool = False
    fit_iterations: int = 0
    view_keep_mass: float = 0.0  # > 0: also each view's own set (`sim_ready_views`)
    width: int = ENV_WIDTH
    height: int = ENV_HEIGHT


def robot_cameras(xy: np.ndarray, yaw: np.ndarray, height_m: float = ROBOT_CAMERA_HEIGHT_M,
                  width: int = ENV_WIDTH, height: int = ENV_HEIGHT,
                  vfov_deg: float = ENV_VFOV_DEG, ground_z: float = 0.0,
                  forward_m: float = ROBOT_CAMERA_FORWARD_M) -> list[Camera]:
    """The level forward cameras of robots at xy [P, 2] (z-up metric frame, ground at
    ground_z) heading yaw [P] radians (0 = +x): each camera height_m above the ground and
    forward_m ahead of the robot centre along the heading, square pixels, vertical fov
    vfov_deg. The defaults are the envs' camera (the robot spec)."""
    f = 0.5 * height / np.tan(np.deg2rad(vfov_deg) / 2)
    out = []
    for (x, y), a in zip(np.asarray(xy, np.float64), np.asarray(yaw, np.float64)):
        eye = np.array([x + forward_m * np.cos(a), y + forward_m * np.sin(a), ground_z + height_m])
        target = eye + np.array([np.cos(a), np.sin(a), 0.0])
        out.append(Camera(f, f, width / 2, height / 2, width, height,
                          look_at(eye, target, (0.0, 0.0, 1.0))))
    return out


def significance(scene: StaticScene, cameras: Sequence[Camera],
                 settings: RasterSettings) -> np.ndarray:
    """Summed blend weight alpha * T of each model splat over all pixels of all cameras:
    [N] float64 in model order (splats the scene dropped at load score 0)."""
    return significance_colour(scene, cameras, settings)[0]


def significance_colour(scene: StaticScene, cameras: Sequence[Camera], settings: RasterSettings,
                        view_keep_mass: float = 0.0
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(significance [N] as `significance`, blend-weighted mean colour [N, 3] of each splat
    over the cameras (its SH colour seen from each camera, weighted by its blend weight
    there; the DC colour where it never blends)), both float64 in model order, and, when
    view_keep_mass > 0, per camera the splats that carry that fraction of the camera's own
    blend weight (`keep_by_mass`): [V, ceil(N / 8)] uint8, np.packbits of a bool [V, N] in
    model order ([0, ceil(N / 8)] when view_keep_mass is 0)."""
    if scene.lod is not None:
        raise ValueError("significance: needs an exact (non-LOD) StaticScene")
    W, H = settings.width, settings.height
    G = max(len(scene.means), 1)
    sel, fo = np.empty(G, np.int64), np.empty((G, NF), np.float32)
    box, radii = np.empty((G, 4), np.int32), np.empty(G, np.int32)
    color, rgb = np.empty((H, W, 3), np.float32), np.empty((H, W, 3), np.float32)
    alpha, depth, blends = (np.empty((H, W), np.float32), np.empty((H, W), np.float32),
                            np.empty((H, W), np.int32))
    contrib, stats = np.zeros(G, np.float64), np.zeros(NS, np.float64)
    sig = np.zeros(len(scene.means), np.float64)  # [G] cached-row order
    col = np.zeros((len(scene.means), 3), np.float64)  # [G, 3] weighted colour sums
    cov_alpha = -1.0 if settings.cov_cull_alpha is None else float(settings.cov_cull_alpha)
    deg = min(settings.active_sh_degree, scene.sh_degree)
    bg = np.zeros(3, np.float32)
    view_sets = np.zeros((len(cameras) if view_keep_mass > 0.0 else 0, (scene.num + 7) // 8),
                         np.uint8)  # [V, ceil(N / 8)] packed bits, model order
    mine = np.zeros(scene.num, bool)
    for v, cam in enumerate(cameras):
        view, campos, k = camera_arrays(cam)
        contrib[:] = 0.0
        n = render_frame(0, len(scene.centers), scene.centers, scene.r_means, scene.rho,
                         scene.cell_start, scene.means, scene.cov, scene.opacity, scene.cut,
                         scene.normal, scene.rgb, scene.sh, deg, view, campos, k, W, H,
                         kernel_tile(settings.tile_size), float(settings.near),
                         float(settings.far), cov_alpha, 0, 0.0, bg, sel, fo, box, radii, color, rgb,
                         alpha, depth, blends, contrib, stats)
        hit = np.nonzero(contrib[:n] > 0.0)[0]  # fo rows of culled splats are not written
        rows = sel[hit]  # distinct within one camera
        sig[rows] += contrib[hit]
        col[rows] += contrib[hit, None] * fo[hit, F_R:F_BL + 1]
        if view_keep_mass > 0.0:
            own = rows[keep_by_mass(contrib[hit], view_keep_mass)]
            mine[:] = False
            mine[scene.index[own[own < len(scene.index)]]] = True
            view_sets[v] = np.packbits(mine)
    K = len(scene.index)
    seen = sig[:K] > 0.0
    mean_col = scene.rgb[:K].astype(np.float64).copy()
    mean_col[seen] = col[:K][seen] / sig[:K][seen, None]
    out, out_col = np.zeros(scene.num, np.float64), np.zeros((scene.num, 3), np.float64)
    out[scene.index] = sig[:K]
    out_col[scene.index] = mean_col
    return out, out_col, view_sets


def bake_colour(model: GaussianModel, rgb: np.ndarray) -> GaussianModel:
    """Copy of model with SH degree 0 whose DC colour is rgb [N, 3] (C0 * dc + 0.5 = rgb)."""
    out = model.with_sh_degree(0)
    out.sh[:, 0] = torch.from_numpy((rgb - 0.5) / C0).to(out.sh.dtype)
    return out


def keep_by_mass(sig: np.ndarray, keep_mass: float) -> np.ndarray:
    """Boolean mask [N] of the most significant entries of sig [N] whose sum reaches
    keep_mass of the total (zero-significance entries are never kept)."""
    order = np.argsort(-sig, kind="stable")
    total = float(sig.sum())
    keep = np.zeros(len(sig), bool)
    if total <= 0.0:
        return keep
    csum = np.cumsum(sig[order])
    k = int(np.searchsorted(csum, keep_mass * total, side="left")) + 1
    keep[order[:min(k, len(sig))]] = True
    return keep & (sig > 0.0)


def sim_ready(model: GaussianModel, cameras: Sequence[Camera],
              config: SimReadyConfig = SimReadyConfig(),
              settings: RasterSettings | None = None) -> tuple[GaussianModel, np.ndarray]:
    """The splats of `model` that carry keep_mass of the image over `cameras` (robot views
    at the env resolution; colours baked when config.bake_colour), and the significance [N]
    they were chosen by."""
    small, sig, _ = sim_ready_views(model, cameras, config, settings)
    return small, sig


def sim_ready_views(model: GaussianModel, cameras: Sequence[Camera],
                    config: SimReadyConfig = SimReadyConfig(), settings: RasterSettings | None = None
                    ) -> tuple[GaussianModel, np.ndarray, np.ndarray]:
    """`sim_ready`'s (splats, significance), and per camera which of those splats carry
    config.view_keep_mass of that camera's blend weight (measured on the full model in the
    same pass): [V, ceil(K / 8)] uint8 packed bits over the K kept splats ([0, ...] when
    view_keep_mass is 0), the view sets of `env_view_sets.ViewSets`."""
    deg = model.sh_degree if config.bake_colour else 0
    st = settings or RasterSettings(config.width, config.height, active_sh_degree=deg)
    sig, col, full_sets = significance_colour(StaticScene(model), cameras, st, config.view_keep_mass)
    keep = keep_by_mass(sig, config.keep_mass)
    view_sets = np.zeros((len(full_sets), (int(keep.sum()) + 7) // 8), np.uint8)
    for v, bits in enumerate(full_sets):  # model order -> kept-splat order, one view at a time
        view_sets[v] = np.packbits(np.unpackbits(bits, count=len(keep)).astype(bool)[keep])
    small = (bake_colour(model, col) if config.bake_colour else model).index(torch.from_numpy(keep))
    if config.fit_iterations > 0:
        full = RasterSettings(config.width, config.height, active_sh_degree=model.sh_degree)
        targets = SceneBatch([StaticScene(model)]).render(cameras, settings=full).rgb
        fit_st = RasterSettings(config.width, config.height, active_sh_degree=small.sh_degree)
        small = fit_to_views(small, cameras, targets, fit_st,
                             FitConfig(iterations=config.fit_iterations))
    return small, sig, view_sets
