"""metric: an SfM model -> a PosedClip in the metric gravity frame (z up, ground z = 0).

Reads: sfm/ (model, `quality.json`), decode/ `images/` (frame indices and timestamps).
Writes (metric/): a PosedClip (`cameras.parquet`, `points.npz`, `frame.json`), `sparse/`,
`transforms.json`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from vid2sim.factory.runtime.stage_cache import StageWork
from vid2sim.factory.runtime.steps import decode, sfm
from vid2sim.factory.runtime.steps.base import StepOutputs
from vid2sim.factory.sfm import metric as stage
from vid2sim.factory.sfm.metric import MetricConfig
from vid2sim.factory.sfm.posed import PosedClip

NAME = stage.STAGE
VERSION = stage.STAGE_VERSION


@dataclass(frozen=True)
class Inputs:
    sfm: sfm.Outputs
    decode: decode.Outputs


@dataclass(frozen=True)
class Outputs(StepOutputs):
    """A PosedClip folder (also the entry of a clip posed elsewhere, e.g. a synthetic street)."""

    @property
    def colmap(self) -> Path:
        return self.dir / stage.OUTPUTS.colmap

    def clip(self) -> PosedClip:
        return PosedClip.load(self.dir)


def configure(conf, job) -> MetricConfig:
    return replace(conf.resolved().metric, capture_height_m=job.spec.capture_height)


def work(conf: MetricConfig, inputs: Inputs) -> StageWork:
    return stage.work(conf, inputs.sfm.dir, inputs.decode.images)
