"""decode: a clip of a source -> sampled, filtered, face-blurred frames.

Reads: the clip spec (source: video, image folder or URI; time window).
Writes (decode/): `images/NNNNNN.jpg`, `frames.parquet`, `clip.json`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from vid2sim.factory.ingest import decode as stage
from vid2sim.factory.ingest.clips import ClipSpec
from vid2sim.factory.ingest.decode import DecodeConfig
from vid2sim.factory.runtime.stage_cache import StageWork
from vid2sim.factory.runtime.steps.base import StepOutputs
from vid2sim.factory.runtime.threads import assigned_threads

NAME = stage.STAGE
VERSION = stage.STAGE_VERSION


@dataclass(frozen=True)
class Inputs:
    clip: ClipSpec


@dataclass(frozen=True)
class Outputs(StepOutputs):
    @property
    def images(self) -> Path:
        return self.dir / stage.OUTPUTS.images

    @property
    def frames(self) -> Path:
        return self.dir / stage.OUTPUTS.frames


def configure(conf, job) -> DecodeConfig:
    return conf.decode


def work(conf: DecodeConfig, inputs: Inputs) -> StageWork:
    """Decode the clip's window of its source with the task's threads as workers."""
    clip = inputs.clip
    return stage.work(replace(conf, workers=assigned_threads()), clip.source, clip.window)
