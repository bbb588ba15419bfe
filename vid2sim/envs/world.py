"""One loaded scene ready for episodes: planner, physics world, camera view, geodesic range."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Union

import numpy as np

from vid2sim.envs.config import EnvConfig
from vid2sim.envs.episodes import end_cells, geodesic_range
from vid2sim.envs.physics import PhysicsWorld
from vid2sim.envs.planning import GridPlanner
from vid2sim.envs.rendering import FastSplatView, MeshView, SplatView
from vid2sim.envs.scenes import SceneAssets, load_scene, read_visual_mesh
from vid2sim.registry import Registry


@dataclass
class SceneWorld:
    assets: SceneAssets
    walkable: GridPlanner  # raw map: the "left the walkable area" test
    planner: GridPlanner  # inflated by EpisodeConfig.clearance: episodes, obstacles, expert
    physics: PhysicsWorld
    view: Union[SplatView, FastSplatView, MeshView]
    span: tuple[float, float]  # geodesic start-goal range (m)
    ends: np.ndarray  # [H, W] bool: cells starts and goals are sampled on (episodes.end_cells)

    def close(self) -> None:
        self.physics.close()


def build_world(registry: Registry, scene_id: str, conf: EnvConfig,
                checkout_root: Optional[Path] = None) -> SceneWorld:
    """Check out and load a scene; refuse it (SceneError) when it cannot host episodes."""
    assets = load_scene(registry, scene_id, checkout_root)
    walkable = GridPlanner(assets.walkable)
    clearance = max(0.0, conf.episode.clearance - assets.walkable_inflation)
    planner = GridPlanner(assets.walkable, clearance=clearance)
    span = geodesic_range(planner, conf.episode, scene_id)
    ends = end_cells(planner, max(0.0, conf.episode.end_clearance - assets.walkable_inflation))
    if conf.variant == "mesh-rgb":
        view: Union[SplatView, FastSplatView, MeshView] = MeshView(
            read_visual_mesh(assets.visual_mesh_path, scene_id), conf.camera)
    elif conf.render_fidelity == "fast":
        view = FastSplatView(assets, conf.camera, conf.fast)
    else:
        view = SplatView(assets.splats, conf.camera, lod=conf.lod)
    physics = PhysicsWorld(assets.collision, conf.robot)
    return SceneWorld(assets, walkable, planner, physics, view, span, ends)
