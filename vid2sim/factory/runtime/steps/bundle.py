"""bundle: a clip's step outputs -> a validated scene bundle.

Reads: metric/ (PosedClip: cameras, frame facts, `sparse/`), recon/ (`splats.ply`,
`metrics.json`), meshing/ (`visual_mesh.ply`, `meshing.json`), walkable/ (`walkable.npz`, the
physical `collision.ply`, `walkable.json`, `corridor.json`), sfm/ (`quality.json`; absent for
a clip posed elsewhere).
Writes (bundle/): `scene/`, a bundle (scene.json, with the robot the scene was made for under
`robot`; splats.ply, collision.ply, walkable.npz, cameras.parquet, preview.png, extras:
visual_mesh.ply, colmap/) via `write_bundle`.
"""

from __future__ import annotations

import json
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import cv2
import numpy as np
import torch

from vid2sim.factory.runtime.config import ClipJob, PipelineConfig
from vid2sim.factory.runtime.stage_cache import StageError, StageWork
from vid2sim.factory.runtime.steps import meshing, metric, recon, sfm, walkable
from vid2sim.factory.runtime.steps.base import StepOutputs
from vid2sim.factory.sfm.posed import PosedClip
from vid2sim.formats.bundle import VISUAL_MESH_PLY, write_bundle
from vid2sim.formats.errors import BundleError
from vid2sim.formats.robot import ROBOT
from vid2sim.formats.scene import make_scene_json
from vid2sim.formats.walkable import load_walkable
from vid2sim.ranges import checked
from vid2sim.splats.camera import Camera
from vid2sim.splats.ply import read_ply
from vid2sim.splats.render import render
from vid2sim.splats.types import RasterSettings

NAME = "bundle"
VERSION = 3  # bump when this stage's outputs change for the same inputs
SCENE = "scene"


@checked
@dataclass(frozen=True)
class Config:
    job: ClipJob  # scene id, licence, source facts and tags of the clip
    pipeline: PipelineConfig  # recorded in scene.json


@dataclass(frozen=True)
class Inputs:
    metric: metric.Outputs
    recon: recon.Outputs
    meshing: meshing.Outputs
    walkable: walkable.Outputs
    sfm: Optional[sfm.Outputs] = None  # absent for a clip posed elsewhere


@dataclass(frozen=True)
class Outputs(StepOutputs):
    @property
    def scene(self) -> Path:
        """The bundle folder (the marker sits beside it, outside the bundle)."""
        return self.dir / SCENE


def configure(conf: PipelineConfig, job: ClipJob) -> Config:
    return Config(job, conf)


def work(conf: Config, inputs: Inputs) -> StageWork:
    """Keyed by the scene id, licence and tags and the keys of metric, recon, meshing, walkable."""
    job = conf.job
    return StageWork(NAME, VERSION, {"scene_id": job.scene_id, "licence": job.licence, "tags": job.spec.tags},
                     tuple(i.key for i in (inputs.metric, inputs.recon, inputs.meshing, inputs.walkable)),
                     lambda out_dir: build(conf, inputs, out_dir))


def build(conf: Config, inputs: Inputs, out_dir: Path) -> dict:
    """Assemble and validate the bundle; an invalid one is a verdict on the clip (StageError)."""
    try:
        _assemble(conf, inputs, Outputs(Path(out_dir)))
    except BundleError as e:  # the clip's outputs do not make a valid bundle: a verdict, not a bug
        raise StageError(NAME, "invalid_bundle", str(e)) from e
    return {"scene_id": conf.job.scene_id}


def tag(key: str, value: object) -> str:
    """`key:value` made a valid registry tag (spaces and other characters become '-')."""
    return re.sub(r"[^A-Za-z0-9._:=/+-]+", "-", f"{key}:{value}").strip("-")[:64]


def _read_json(path: Path) -> dict:
    return json.loads(path.read_text()) if path.is_file() else {}


def _scalars(d: dict, prefix: str = "") -> dict:
    """Flatten the numeric/str leaves of a metrics dict (for scene.json metrics)."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_scalars(v, f"{prefix}{k}."))
        elif isinstance(v, (int, float, str, bool)) or v is None:
            out[f"{prefix}{k}"] = v
    return out


def render_preview(splats_ply: Path, clip: PosedClip, walkable: np.ndarray, out_png: Path,
                   width: int = 480) -> Path:
    """Preview: the splats rendered from the middle training frame, beside the walkable map."""
    model = read_ply(splats_ply)
    train = clip.split("train") or clip.frames
    frame = train[len(train) // 2]
    cam = Camera.from_cam_to_world(frame.K, frame.cam_to_world, frame.width, frame.height)
    cam = cam.scaled(width / frame.width)
    with torch.no_grad():
        out = render(model, cam, RasterSettings(cam.width, cam.height, active_sh_degree=model.sh_degree),
                     background=(1.0, 1.0, 1.0))
    rgb = (out.rgb.clamp(0, 1).numpy() * 255).astype(np.uint8)[..., ::-1]  # BGR
    grid = np.flipud(walkable) if walkable.size else np.zeros((1, 1), np.uint8)  # rows = y: show y up
    gmap = cv2.cvtColor((grid * 200 + 30).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    scale = rgb.shape[0] / max(1, gmap.shape[0])
    gmap = cv2.resize(gmap, (max(1, int(gmap.shape[1] * scale)), rgb.shape[0]),
                      interpolation=cv2.INTER_NEAREST)
    cv2.imwrite(str(out_png), np.concatenate([rgb, gmap], axis=1))
    return out_png


def _metrics(inputs: Inputs) -> dict:
    """The upstream steps' figures recorded in scene.json (flattened by `_scalars`)."""
    return {"recon": _read_json(inputs.recon.metrics),
            "sfm": _read_json(inputs.sfm.quality) if inputs.sfm else {},
            "meshing": _read_json(inputs.meshing.summary).get("summary", {}),
            "walkable": _read_json(inputs.walkable.summary).get("summary", {}),
            "corridor": _read_json(inputs.walkable.corridor)}


def _assemble(conf: Config, inputs: Inputs, out: Outputs) -> None:
    job = conf.job
    clip = inputs.metric.clip()
    walk = load_walkable(inputs.walkable.grid)
    spec = job.spec
    start, end = spec.window if spec.window else (0.0, float(max(f.timestamp for f in clip.frames)))
    scene = make_scene_json(
        job.scene_id, source_uri=spec.source.uri, source_sha256=spec.source.sha256,
        clip_start_s=start, clip_end_s=end, group=spec.group,
        scale_source=str(clip.frame_info.get("scale_source", "capture_height")),
        metrics=_scalars(_metrics(inputs)), config=conf.pipeline, robot=ROBOT,
        tags=sorted({tag(k, v) for k, v in spec.tags.items()} | {tag("licence", job.licence)}))
    with tempfile.TemporaryDirectory() as tmp:
        preview = render_preview(inputs.recon.splats, clip, walk.grid, Path(tmp) / "p.png")
        extras = {VISUAL_MESH_PLY: inputs.meshing.visual}
        if inputs.metric.colmap.is_dir():
            extras["colmap"] = inputs.metric.colmap
        write_bundle(out.scene, scene_json=scene, splats_ply=inputs.recon.splats,
                     collision_ply=inputs.walkable.collision,  # the physical layer
                     walkable=walk,
                     cameras=clip.cameras_table(), preview_png=preview, extras=extras,
                     overwrite=True)
