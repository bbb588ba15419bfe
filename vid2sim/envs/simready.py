"""The envs' sim-ready splat set (fast render path): made once per scene, cached per process.

`fidelity="fast"` (EnvConfig) renders a pruned copy of the scene's splats with one baked colour
per splat through `vid2sim.splats.cpu.FastBatch` (see `splats/cpu/env_simready.py` and
`splats/cpu/env_fast_frame.py` for what is traded). The set is measured on `FastRenderConfig.views`
robot views at the env's camera (random walkable cells, random headings, fixed seed: the same
set in every process), never on the episode's own views. Envs of one process that load the
same bundle with the same settings share one set (`_CACHE`), and the set is written as a PLY
(named by a hash of the bundle's splats and the settings) to `$VID2SIM_SIMREADY_CACHE`, else to
`simready/` beside the env's bundle checkouts, and read back by later processes: measuring the
default 1024 views costs about 15 s of one core per scene (a colour fit, when asked for, about
a minute per 600 steps), paid once. With view sets (`FastRenderConfig.view_keep_mass` > 0,
`splats/cpu/env_view_sets.py`) the same pass records each view's own set, written beside the PLY
as `simready-<key>.views.npz`, and a frame draws only what the measured views near its camera
needed.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import uuid
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from vid2sim.envs.camera import splat_camera, world_to_camera
from vid2sim.envs.config import CameraConfig, FastRenderConfig
from vid2sim.formats.walkable import WalkableGrid
from vid2sim.splats import Camera, GaussianModel, RasterSettings, read_ply, write_ply
from vid2sim.splats.cpu import StaticScene, StaticSceneConfig
from vid2sim.splats.cpu.env_fast_batch import FastBatch
from vid2sim.splats.cpu.env_simready import SimReadyConfig, sim_ready_views
from vid2sim.splats.cpu.env_view_sets import CellMasks, ViewSets

CACHE_ENV = "VID2SIM_SIMREADY_CACHE"
_CACHE: dict[str, "SimReadySet"] = {}


@dataclass
class SimReadySet:
    model: GaussianModel  # the kept splats, SH 0 (baked colours)
    batch: FastBatch  # packed for the fast kernels (not thread-safe: scratch buffers)
    full_splats: int
    views: Optional[CellMasks] = None  # the view sets as cell masks of `batch` (None: off)


def measured_views(grid: WalkableGrid, fast: FastRenderConfig) -> int:
    """How many robot views the set is measured on: `fast.views`; with view sets
    `fast.views_per_m2` per square metre of walkable map where that is more (a frame needs
    measured views near it everywhere)."""
    if fast.view_keep_mass <= 0:
        return fast.views
    area = float(np.count_nonzero(grid.grid)) * grid.resolution ** 2
    return max(fast.views, math.ceil(fast.views_per_m2 * area))


def view_cameras(grid: WalkableGrid, conf: CameraConfig, n: int, seed: int) -> list[Camera]:
    """n env cameras at random walkable cells with random headings (no jitter)."""
    rng = np.random.default_rng(seed)
    rows, cols = np.nonzero(grid.grid)
    pick = rng.integers(0, len(rows), n)
    xs, ys = grid.cell_center(rows[pick], cols[pick])
    yaws = rng.uniform(-np.pi, np.pi, n)
    return [splat_camera(conf, world_to_camera(float(x), float(y), float(a), conf))
            for x, y, a in zip(xs, ys, yaws)]


def cache_key(bundle_key: str, conf: CameraConfig, fast: FastRenderConfig) -> str:
    sets = [fast.views_per_m2, fast.view_keep_mass] if fast.view_keep_mass > 0 else []
    text = json.dumps([bundle_key, asdict(conf), fast.keep_mass, fast.fit_iterations, fast.views,
                       fast.seed, *sets], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def sim_ready_set(bundle_key: str, model: GaussianModel, grid: WalkableGrid, conf: CameraConfig,
                  fast: FastRenderConfig, cache_dir: Optional[Path] = None) -> SimReadySet:
    """The scene's sim-ready set for the fast path (memory cache, then the disk cache in
    $VID2SIM_SIMREADY_CACHE or cache_dir (None: none), then made and written there)."""
    key = cache_key(bundle_key, conf, fast)  # names the files: what measuring depends on
    held = f"{key}-{fast.cell_size}-{fast.view_radius}-{fast.view_heading_deg}"  # + how it is drawn
    if held in _CACHE:
        return _CACHE[held]
    folder = os.environ.get(CACHE_ENV) or cache_dir
    path: Optional[Path] = Path(folder) / f"simready-{key}.ply" if folder else None
    views_path = None if path is None else path.with_name(f"simready-{key}.views.npz")
    with_views = fast.view_keep_mass > 0
    if path is not None and path.is_file() and (not with_views or views_path.is_file()):
        small = read_ply(path)
        views = ViewSets.load(views_path) if with_views else None
    else:
        small, views = _measure(model, grid, conf, fast)
        if path is not None:  # unique temporary names: several processes may make them at once
            tmp = f"-{os.getpid()}-{uuid.uuid4().hex}.tmp"
            if views is not None:
                os.replace(views.save(views_path.with_name(views_path.name + tmp)), views_path)
            os.replace(write_ply(small, path.with_name(path.stem + tmp)), path)
    scene = StaticScene(small, StaticSceneConfig(cell_size=fast.cell_size, per_splat_outputs=False))
    masks = None if views is None else CellMasks(views, scene, fast.view_radius, fast.view_heading_deg)
    _CACHE[held] = SimReadySet(small, FastBatch([scene]), model.num, masks)
    return _CACHE[held]


def _measure(model: GaussianModel, grid: WalkableGrid, conf: CameraConfig,
             fast: FastRenderConfig) -> tuple[GaussianModel, Optional[ViewSets]]:
    """The sim-ready splats and (when fast.view_keep_mass > 0) their view sets."""
    cams = view_cameras(grid, conf, measured_views(grid, fast), fast.seed)
    st = RasterSettings(conf.width, conf.height, near=conf.near, far=conf.far,
                        cov_cull_alpha=conf.cov_cull_alpha, active_sh_degree=model.sh_degree)
    small, _, sets = sim_ready_views(model, cams, SimReadyConfig(
        keep_mass=fast.keep_mass, bake_colour=True, fit_iterations=fast.fit_iterations,
        view_keep_mass=fast.view_keep_mass, width=conf.width, height=conf.height), st)
    if fast.view_keep_mass <= 0:
        return small, None
    return small, ViewSets.from_cameras(cams, sets, small.num)
