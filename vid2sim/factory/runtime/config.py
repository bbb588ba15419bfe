"""What the factory runs: the pipeline config (every step's config, named presets) and a clip job.

`PipelineConfig` is saved with each scene (pipeline hash = hash of it); each step picks its own
part (`runtime/steps/*.configure`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Optional

from vid2sim.factory.evaluation.corridor import CorridorConfig
from vid2sim.factory.geometry.meshing import MeshingConfig
from vid2sim.factory.geometry.splat_views import SplatViewConfig
from vid2sim.factory.geometry.walkable import WalkableConfig
from vid2sim.factory.ingest.clips import ClipsConfig, ClipSpec
from vid2sim.factory.ingest.decode import DecodeConfig
from vid2sim.factory.ingest.decode import preset as decode_preset
from vid2sim.factory.ingest.masks import MasksConfig
from vid2sim.factory.recon.config import ReconConfig
from vid2sim.factory.recon.config import preset as recon_preset
from vid2sim.factory.sfm.metric import MetricConfig
from vid2sim.factory.sfm.sfm import SfMConfig
from vid2sim.factory.sfm.sfm import preset as sfm_preset
from vid2sim.ranges import checked
from vid2sim.versioning import from_jsonable, to_jsonable


def _sfm_config(preset: str) -> SfMConfig:
    return sfm_preset("fast" if preset == "fast" else "accurate")


@checked
@dataclass
class PipelineConfig:
    """Every stage's config; saved with each scene (pipeline hash = hash of this)."""

    preset: str = "fast"  # name of the preset this config started from ("fast" | "paper"); a label, read by `resolved`
    clips: ClipsConfig = field(default_factory=ClipsConfig)  # cutting long sources into clips
    decode: DecodeConfig = field(default_factory=DecodeConfig)  # frame sampling, quality filters, face blurring
    masks: MasksConfig = field(default_factory=MasksConfig)  # dynamic-object masks (people, vehicles)
    sfm: Optional[SfMConfig] = None  # camera poses (COLMAP / GLOMAP); None: from the preset (see resolved)
    metric: Optional[MetricConfig] = None  # metric scale and ground plane; None: the defaults
    recon: ReconConfig = field(default_factory=lambda: recon_preset("fast"))  # Gaussian-splat training
    views: SplatViewConfig = field(default_factory=SplatViewConfig)  # splat depth views rendered for meshing
    meshing: MeshingConfig = field(default_factory=MeshingConfig)  # TSDF fusion into collision / visual meshes
    walkable: WalkableConfig = field(default_factory=WalkableConfig)  # walkable map and the physical collision mesh
    corridor: CorridorConfig = field(default_factory=CorridorConfig)  # walked-corridor check and quality gate

    def resolved(self) -> "PipelineConfig":
        """Fill the SfM/metric configs from the preset when left unset."""
        return replace(self, sfm=self.sfm or _sfm_config(self.preset),
                       metric=self.metric or MetricConfig())

    @classmethod
    def from_dict(cls, data: dict) -> "PipelineConfig":
        """Rebuild from `to_jsonable(conf)`, e.g. scene.json's pipeline.config."""
        return from_jsonable(cls, data)

    def save(self, path: Path) -> Path:
        """Write the config as JSON (the same object scene.json keeps under pipeline.config)."""
        Path(path).write_text(json.dumps(to_jsonable(self), indent=2))
        return Path(path)

    @classmethod
    def load(cls, path: Path) -> "PipelineConfig":
        """Read a config JSON written by `save` (or copied from a scene.json)."""
        return cls.from_dict(json.loads(Path(path).read_text()))


def preset(name: str) -> PipelineConfig:
    """Named pipeline presets: `fast` (minutes on 2 CPU cores, 10 fps) and `paper` (30 fps, 30k iterations)."""
    if name not in ("fast", "paper"):
        raise ValueError(f"unknown preset {name!r} (fast | paper)")
    views = SplatViewConfig() if name == "fast" else SplatViewConfig(scale=1.0, every=1)
    sampling = decode_preset("default" if name == "fast" else "paper")
    return PipelineConfig(preset=name, decode=sampling, recon=recon_preset(name), views=views).resolved()


@dataclass(frozen=True)
class ClipJob:
    """One clip to make into a scene: its spec (source, window, facts), registry id and licence."""

    spec: ClipSpec
    scene_id: str
    licence: str
