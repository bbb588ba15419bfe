"""Scene bundle: the folder the factory writes and the envs read.

A bundle folder holds:
  scene.json       metadata (`vid2sim.formats.scene`)
  splats.ply       Gaussians in the standard 3DGS PLY layout (`vid2sim.formats.splat_ply`)
  collision.ply    triangle mesh for physics (ground removed), same world frame
  walkable.npz     walkable grid (`vid2sim.formats.walkable`)
  cameras.parquet  one row per frame, schema `vid2sim.formats.cameras.cameras_schema()`
  preview.png      a picture of the scene
  <extras>         optional further files or folders (visual mesh, COLMAP model, ...)

`validate_bundle` reads a folder and returns a `BundleInfo` or raises `BundleError` naming the
file and the reason. `write_bundle` assembles a bundle in a temporary sibling folder, validates
it, then renames it into place, so a failed write leaves nothing behind.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import trimesh

from vid2sim.formats.cameras import CAMERAS_PARQUET, load_cameras
from vid2sim.formats.errors import BundleError, PathLike
from vid2sim.formats.scene import SCENE_JSON, check_scene_json, read_scene_json
from vid2sim.formats.splat_ply import SPLATS_PLY, check_splats
from vid2sim.formats.walkable import WALKABLE_NPZ, WalkableGrid, load_walkable

PREVIEW_PNG = "preview.png"
COLLISION_PLY = "collision.ply"
VISUAL_MESH_PLY = "visual_mesh.ply"  # an optional extra: the visual mesh with the ground
REQUIRED_FILES = (SCENE_JSON, SPLATS_PLY, COLLISION_PLY, WALKABLE_NPZ, CAMERAS_PARQUET, PREVIEW_PNG)
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# Top-level files that are bookkeeping, not content (checkout marker, factory stage marker).
IGNORED_FILES = (".vid2sim-checkout.json", "stage.json")


@dataclass
class BundleInfo:
    """What `validate_bundle` learned about a bundle folder."""

    path: Path
    scene_id: str
    scene: dict
    num_splats: int
    bounds: tuple[float, ...]  # [6] splat centres: xmin ymin zmin xmax ymax zmax
    mesh_bounds: tuple[float, ...]  # [6] collision mesh AABB
    num_faces: int
    walkable_area_m2: float
    frame_counts: dict[str, int]  # split name -> frames; "all" -> total
    artifacts: dict[str, Path] = field(default_factory=dict)  # relative name -> file


# ----------------------------------------------------------------------------- artifacts

def check_mesh(path: Path) -> tuple[int, tuple[float, ...]]:
    """Collision mesh -> (faces, bounds [6]); raise BundleError if unreadable or faceless."""
    if not path.is_file():
        raise BundleError(path, "missing collision mesh")
    try:
        mesh = trimesh.load(str(path), force="mesh", process=False)
    except Exception as e:
        raise BundleError(path, f"unreadable mesh ({type(e).__name__}: {e})") from None
    faces = getattr(mesh, "faces", None)
    if faces is None or len(faces) == 0:
        raise BundleError(path, "mesh has no triangle faces")
    b = np.asarray(mesh.bounds, np.float64).reshape(-1)
    if not np.isfinite(b).all():
        raise BundleError(path, "non-finite mesh vertices")
    return int(len(faces)), tuple(float(v) for v in b)


def check_png(path: Path) -> None:
    if not path.is_file():
        raise BundleError(path, "missing preview image")
    with open(path, "rb") as f:
        if f.read(8) != PNG_SIGNATURE:
            raise BundleError(path, "not a PNG file")


def list_artifacts(folder: Path) -> dict[str, Path]:
    """All regular files under `folder` as {relative posix name: path} (minus IGNORED_FILES);
    rejects symlinks."""
    out: dict[str, Path] = {}
    for p in sorted(folder.rglob("*")):
        rel = p.relative_to(folder).as_posix()
        if rel in IGNORED_FILES:
            continue
        if p.is_symlink():
            raise BundleError(p, "symlinks are not allowed in a bundle")
        if p.is_file():
            out[rel] = p
    return out


# ----------------------------------------------------------------------------- validate / write

def validate_bundle(path: PathLike) -> BundleInfo:
    """Read-only check of a bundle folder -> BundleInfo; raises BundleError (file + reason)."""
    folder = Path(path)
    if not folder.is_dir():
        raise BundleError(folder, "bundle folder does not exist")
    scene = read_scene_json(folder / SCENE_JSON)
    n, bounds = check_splats(folder / SPLATS_PLY)
    faces, mesh_bounds = check_mesh(folder / COLLISION_PLY)
    walk = load_walkable(folder / WALKABLE_NPZ)
    cams = load_cameras(folder / CAMERAS_PARQUET)
    check_png(folder / PREVIEW_PNG)
    splits = cams.column("split").to_pylist()
    counts = {"all": len(splits), "train": splits.count("train"), "test": splits.count("test")}
    return BundleInfo(path=folder, scene_id=scene["scene_id"], scene=scene, num_splats=n, bounds=bounds,
                      mesh_bounds=mesh_bounds, num_faces=faces,
                      walkable_area_m2=walk.area_m2(), frame_counts=counts,
                      artifacts=list_artifacts(folder))


def _copy_in(src: PathLike, dst: Path) -> None:
    src = Path(src)
    if not src.exists():
        raise BundleError(src, "input file does not exist")
    dst.parent.mkdir(parents=True, exist_ok=True)
    if src.is_dir():
        shutil.copytree(src, dst, symlinks=False)
    else:
        shutil.copyfile(src, dst)


def _check_extra_name(name: str) -> str:
    parts = Path(name).parts
    if (not name or Path(name).is_absolute() or ".." in parts or parts[0] in REQUIRED_FILES
            or name.startswith(".")):
        raise BundleError(name, "invalid extra name (must be a relative path, no '..', not a required file)")
    return name


def write_bundle(
    out_dir: PathLike,
    *,
    scene_json: dict,
    splats_ply: PathLike,
    collision_ply: PathLike,
    walkable: WalkableGrid | tuple[np.ndarray, Any, float],
    cameras,
    preview_png: PathLike,
    extras: Optional[dict[str, PathLike]] = None,
    overwrite: bool = False,
) -> Path:
    """Assemble a bundle at `out_dir` (atomically: temp sibling, validate, rename).

    walkable: WalkableGrid or (grid uint8 [H, W], origin [2], resolution); cameras: pyarrow.Table with
    `cameras_schema()`; extras: {relative name: file or folder} copied as-is.
    """
    out = Path(out_dir)
    if out.exists() and any(out.iterdir()) and not overwrite:
        raise BundleError(out, "output folder exists and is not empty (pass overwrite=True)")
    check_scene_json(scene_json, out / SCENE_JSON)
    if not isinstance(cameras, pa.Table):
        raise BundleError(out / CAMERAS_PARQUET, f"cameras must be a pyarrow.Table, got {type(cameras).__name__}")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    try:
        (tmp / SCENE_JSON).write_text(json.dumps(scene_json, indent=2, sort_keys=True))
        _copy_in(splats_ply, tmp / SPLATS_PLY)
        _copy_in(collision_ply, tmp / COLLISION_PLY)
        (walkable if isinstance(walkable, WalkableGrid) else WalkableGrid(*walkable)).save(tmp / WALKABLE_NPZ)
        pq.write_table(cameras, tmp / CAMERAS_PARQUET)
        _copy_in(preview_png, tmp / PREVIEW_PNG)
        for name, src in (extras or {}).items():
            _copy_in(src, tmp / _check_extra_name(name))
        try:
            validate_bundle(tmp)
        except BundleError as e:  # report the destination name, not the temp folder
            raise BundleError(str(e.path).replace(str(tmp), str(out)), e.reason) from None
        if out.exists():
            shutil.rmtree(out)
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out
