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
a minute per 600 steps), paid once.
"""

from __future__ import annotations

import hashlib
import json
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
from vid2sim.splats.cpu.env_simready import SimReadyConfig, sim_ready

CACHE_ENV = "VID2SIM_SIMREADY_CACHE"
_CACHE: dict[str, "SimReadySet"] = {}


@dataclass
class SimReadySet:
    model: GaussianModel  # the kept splats, SH 0 (baked colours)
    batch: FastBatch  # packed for the fast kernels (not thread-safe: scratch buffers)
    full_splats: int


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
    text = json.dumps([bundle_key, asdict(conf), fast.keep_mass, fast.fit_iterations, fast.views,
                       fast.seed], sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def sim_ready_set(bundle_key: str, model: GaussianModel, grid: WalkableGrid, conf: CameraConfig,
                  fast: FastRenderConfig, cache_dir: Optional[Path] = None) -> SimReadySet:
    """The scene's sim-ready set for the fast path (memory cache, then the disk cache in
    $VID2SIM_SIMREADY_CACHE or cache_dir (None: none), then made and written there)."""
    key = cache_key(bundle_key, conf, fast)
    if key in _CACHE:
        return _CACHE[key]
    folder = os.environ.get(CACHE_ENV) or cache_dir
    path: Optional[Path] = Path(folder) / f"simready-{key}.ply" if folder else None
    if path is not None and path.is_file():
        small = read_ply(path)
    else:
        cams = view_cameras(grid, conf, fast.views, fast.seed)
        st = RasterSettings(conf.width, conf.height, near=conf.near, far=conf.far,
                            cov_cull_alpha=conf.cov_cull_alpha, active_sh_degree=model.sh_degree)
        small, _ = sim_ready(model, cams, SimReadyConfig(
            keep_mass=fast.keep_mass, bake_colour=True, fit_iterations=fast.fit_iterations,
            width=conf.width, height=conf.height), st)
        if path is not None:  # a unique temporary name: several processes may make it at once
            tmp = write_ply(small, path.with_name(f"{path.stem}-{os.getpid()}-{uuid.uuid4().hex}.tmp"))
            os.replace(tmp, path)
    scene = StaticScene(small, StaticSceneConfig(cell_size=fast.cell_size, per_splat_outputs=False))
    _CACHE[key] = SimReadySet(small, FastBatch([scene]), model.num)
    return _CACHE[key]
