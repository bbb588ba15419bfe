"""meshing: splats + PosedClip -> rendered depth views fused into collision / visual meshes.

Reads: recon/ `splats.ply`, metric/ (the training cameras).
Writes (meshing/): `collision.ply`, `visual_mesh.ply`, `ground_points.npy`,
`carved_points.npy`, `meshing.json`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from vid2sim.factory.geometry import meshing as stage
from vid2sim.factory.geometry.meshing import DepthView, MeshingConfig
from vid2sim.factory.geometry.splat_views import SplatViewConfig, render_views
from vid2sim.factory.runtime.stage_cache import StageWork
from vid2sim.factory.runtime.steps import metric, recon
from vid2sim.factory.runtime.steps.base import StepOutputs
from vid2sim.ranges import checked
from vid2sim.splats.ply import read_ply
from vid2sim.versioning import config_hash

NAME = stage.STAGE
VERSION = stage.STAGE_VERSION


@checked
@dataclass(frozen=True)
class Config:
    views: SplatViewConfig  # the splat depth views rendered for fusion
    meshing: MeshingConfig  # TSDF fusion and mesh cleaning


@dataclass(frozen=True)
class Inputs:
    metric: metric.Outputs
    recon: recon.Outputs


@dataclass(frozen=True)
class Outputs(StepOutputs):
    @property
    def collision(self) -> Path:
        return self.dir / stage.OUTPUTS.collision

    @property
    def visual(self) -> Path:
        return self.dir / stage.OUTPUTS.visual

    @property
    def ground_points(self) -> Path:
        return self.dir / stage.OUTPUTS.ground_points

    @property
    def carved_points(self) -> Path:
        return self.dir / stage.OUTPUTS.carved_points

    @property
    def summary(self) -> Path:
        return self.dir / stage.OUTPUTS.summary


def configure(conf, job) -> Config:
    return Config(conf.views, conf.meshing)


def work(conf: Config, inputs: Inputs) -> StageWork:
    """Keyed by the meshing config and the views (the recon key and the view config)."""
    return stage.work(conf.meshing, _views(conf.views, inputs), input_key=config_hash(inputs.recon.key, conf.views))


def _views(conf: SplatViewConfig, inputs: Inputs) -> Iterator[DepthView]:
    """The splat depth views, rendered lazily: only when the stage is not cached for its key."""
    yield from render_views(read_ply(inputs.recon.splats), inputs.metric.clip(), conf)
