"""sfm: masked frames -> camera poses and a sparse model (COLMAP / GLOMAP), quality-gated.

Reads: decode/ `images/`, masks/ `masks/`.
Writes (sfm/): `sparse/0/`, `undistorted/{images,masks,sparse}/`, `transforms.json`, `quality.json`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from vid2sim.factory.runtime.stage_cache import StageWork
from vid2sim.factory.runtime.steps import decode, masks
from vid2sim.factory.runtime.steps.base import StepOutputs
from vid2sim.factory.sfm import sfm as stage
from vid2sim.factory.sfm.sfm import SfMConfig

NAME = stage.STAGE
VERSION = stage.STAGE_VERSION


@dataclass(frozen=True)
class Inputs:
    decode: decode.Outputs
    masks: masks.Outputs


@dataclass(frozen=True)
class Outputs(StepOutputs):
    @property
    def quality(self) -> Path:
        return self.dir / stage.OUTPUTS.quality


def configure(conf, job) -> SfMConfig:
    return conf.resolved().sfm


def work(conf: SfMConfig, inputs: Inputs) -> StageWork:
    return stage.work(conf, inputs.decode.images, inputs.masks.masks)
