"""masks: decoded frames -> dynamic-object masks (0 = dynamic).

Reads: decode/ (`images/`, its marker).
Writes (masks/): `masks/<image>.png`, `masks.parquet`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from vid2sim.factory.ingest import masks as stage
from vid2sim.factory.ingest.masks import MasksConfig
from vid2sim.factory.runtime.stage_cache import StageWork
from vid2sim.factory.runtime.steps import decode
from vid2sim.factory.runtime.steps.base import StepOutputs

NAME = stage.STAGE
VERSION = stage.STAGE_VERSION


@dataclass(frozen=True)
class Inputs:
    decode: decode.Outputs


@dataclass(frozen=True)
class Outputs(StepOutputs):
    @property
    def masks(self) -> Path:
        return self.dir / stage.OUTPUTS.masks


def configure(conf, job) -> MasksConfig:
    return conf.masks


def work(conf: MasksConfig, inputs: Inputs) -> StageWork:
    return stage.work(conf, inputs.decode.dir)
