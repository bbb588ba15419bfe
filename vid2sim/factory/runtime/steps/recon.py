"""recon: a PosedClip -> geometry-consistent Gaussian splats.

Reads: metric/ (PosedClip and the frames it points at).
Writes (recon/): `splats.ply`, `metrics.json`, `config.json`, `train_log.json` (a checkpoint
while it runs).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from vid2sim.factory.recon import data, trainer
from vid2sim.factory.recon.config import ReconConfig
from vid2sim.factory.runtime.stage_cache import StageWork
from vid2sim.factory.runtime.steps import metric
from vid2sim.factory.runtime.steps.base import StepOutputs

NAME = data.STAGE
VERSION = data.STAGE_VERSION


@dataclass(frozen=True)
class Inputs:
    metric: metric.Outputs


@dataclass(frozen=True)
class Outputs(StepOutputs):
    @property
    def splats(self) -> Path:
        return self.dir / data.OUTPUTS.splats

    @property
    def metrics(self) -> Path:
        return self.dir / data.OUTPUTS.metrics


def configure(conf, job) -> ReconConfig:
    return conf.recon


def work(conf: ReconConfig, inputs: Inputs) -> StageWork:
    return trainer.work(conf, inputs.metric.dir)
