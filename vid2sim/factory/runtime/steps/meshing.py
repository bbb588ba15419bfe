"""meshing: splats + PosedClip -> rendered depth views fused into collision / visual meshes.

Reads: recon/ `splats.ply`, metric/ (the training cameras).
Writes (meshing/): `collision.ply`, `visual_mesh.ply`, `ground_points.npy`,
`carved_points.npy`, `meshing.json`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from vid2sim.factory.geometry import meshing as stage
from vid2sim.factory.geometry.meshing import MeshingConfig
from vid2sim.factory.geometry.splat_views import SplatViewConfig, render_views
from vid2sim.factory.runtime.steps import metric, recon
from vid2sim.factory.runtime.steps.base import StepOutputs
from vid2sim.splats.ply import read_ply
from vid2sim.versioning import config_hash

NAME = stage.STAGE
VERSION = stage.STAGE_VERSION


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


def main(conf: Config, inputs: Inputs, out_dir: Path) -> Outputs:
    """Views are rendered lazily: only when the stage is not cached for this key."""
    views_key = config_hash(inputs.recon.key, conf.views)
    views = render_views(read_ply(inputs.recon.splats), inputs.metric.clip(), conf.views)
    return Outputs(stage.main(conf.meshing, views, out_dir, input_key=views_key))
