"""The `bundle` stage: gather a clip's stage outputs into a validated scene bundle.

Reads: metric/ (PosedClip: cameras, frame facts), recon/ (splats.ply, metrics.json),
meshing/ (collision.ply, visual_mesh.ply), walkable/ (walkable.npz, corridor.json), sfm/
(quality.json).
Writes: a bundle folder (scene.json, with the robot the scene was made for under `robot`;
splats.ply, collision.ply, walkable.npz, cameras.parquet, preview.png, extras: visual_mesh.ply,
colmap/) via `write_bundle`.
"""

from __future__ import annotations

import json
import re
import tempfile
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch

from vid2sim.factory.geometry.meshing import OUTPUTS as MESHING
from vid2sim.factory.geometry.walkable import OUTPUTS as WALKABLE
from vid2sim.factory.sfm.posed import PosedClip
from vid2sim.factory.runtime.stage_cache import Timer, input_key, is_done, mark_done, stage_key
from vid2sim.factory.runtime.stage_cache import StageError
from vid2sim.formats.bundle import write_bundle
from vid2sim.formats.errors import BundleError
from vid2sim.formats.robot import ROBOT
from vid2sim.formats.scene import make_scene_json
from vid2sim.formats.walkable import load_walkable
from vid2sim.splats.camera import Camera
from vid2sim.splats.ply import read_ply
from vid2sim.splats.render import render
from vid2sim.splats.types import RasterSettings

STAGE = "bundle"
STAGE_VERSION = 3  # bump when this stage's outputs change for the same inputs


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


def assemble_bundle(ctx: dict, out_dir: Path) -> Path:
    """Stage entry (called by the pipeline with the clip's context); returns the bundle folder
    `out_dir/scene` (the stage marker sits in `out_dir`, outside the bundle)."""
    try:
        return _assemble(ctx, out_dir)
    except BundleError as e:  # the clip's outputs do not make a valid bundle: a verdict, not a bug
        raise StageError(STAGE, "invalid_bundle", str(e)) from e


def _assemble(ctx: dict, out_dir: Path) -> Path:
    job, conf = ctx["job"], ctx["conf"]
    dirs = {k: Path(ctx[f"{k}_dir"]) for k in ("recon", "meshing", "walkable")}
    sfm_dir = Path(ctx["sfm_dir"]) if ctx.get("sfm_dir") else None  # absent for posed inputs
    posed_dir = Path(ctx["posed_dir"])
    inputs = [input_key(d) for d in (posed_dir, *dirs.values())]
    key = stage_key(STAGE, STAGE_VERSION, {"scene_id": job.scene_id, "licence": job.licence, "tags": job.spec.tags},
                    *inputs)
    bundle_dir = Path(out_dir) / "scene"
    if is_done(out_dir, key):
        return bundle_dir
    with Timer() as t:
        clip = PosedClip.load(posed_dir)
        walk = load_walkable(dirs["walkable"] / WALKABLE.grid)
        metrics = {"recon": _read_json(dirs["recon"] / "metrics.json"),
                   "sfm": _read_json(sfm_dir / "quality.json") if sfm_dir else {},
                   "meshing": _read_json(dirs["meshing"] / MESHING.summary).get("summary", {}),
                   "walkable": _read_json(dirs["walkable"] / WALKABLE.summary).get("summary", {}),
                   "corridor": _read_json(dirs["walkable"] / "corridor.json")}
        spec = job.spec
        start, end = spec.window if spec.window else (0.0, float(max(f.timestamp for f in clip.frames)))
        scene = make_scene_json(
            job.scene_id, source_uri=spec.source.uri, source_sha256=spec.source.sha256,
            clip_start_s=start, clip_end_s=end, group=spec.group,
            scale_source=str(clip.frame_info.get("scale_source", "capture_height")),
            metrics=_scalars(metrics), config=conf, robot=ROBOT,
            tags=sorted({tag(k, v) for k, v in spec.tags.items()} | {tag("licence", job.licence)}))
        with tempfile.TemporaryDirectory() as tmp:
            preview = render_preview(dirs["recon"] / "splats.ply", clip, walk.grid, Path(tmp) / "p.png")
            extras = {"visual_mesh.ply": dirs["meshing"] / MESHING.visual}
            colmap = posed_dir / "sparse"
            if colmap.is_dir():
                extras["colmap"] = colmap
            write_bundle(bundle_dir, scene_json=scene, splats_ply=dirs["recon"] / "splats.ply",
                         collision_ply=dirs["walkable"] / WALKABLE.collision,  # the physical layer
                         walkable=walk,
                         cameras=clip.cameras_table(), preview_png=preview, extras=extras,
                         overwrite=True)
    mark_done(out_dir, STAGE, key, {"scene_id": job.scene_id}, t.seconds)
    return bundle_dir
