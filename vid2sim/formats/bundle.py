"""Scene bundle: the folder the factory writes and the envs read.

A bundle folder holds:
  scene.json       scene_id, source {uri, sha256, clip_start_s, clip_end_s, group},
                   world_frame {units "m", up "+z", ground_z 0, scale_source}, metrics,
                   pipeline {config, config_hash, code_version}, tags
  splats.ply       Gaussians in the standard 3DGS PLY layout (x y z nx ny nz f_dc_0..2
                   [f_rest_*] opacity scale_0..2 rot_0..3)
  collision.ply    triangle mesh for physics (ground removed), same world frame
  walkable.npz     grid uint8 [H, W] (1 = walkable), origin float64 [2] (world x, y of
                   cell [0, 0]), resolution float64 (metres per cell)
  cameras.parquet  one row per frame, schema `vid2sim.factory.sfm.posed.cameras_schema()`
  preview.png      a picture of the scene
  <extras>         optional further files or folders (visual mesh, COLMAP model, ...)

`validate_bundle` reads a folder and returns a `BundleInfo` or raises `BundleError` naming the
file and the reason. `write_bundle` assembles a bundle in a temporary sibling folder, validates
it, then renames it into place, so a failed write leaves nothing behind.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Union

import numpy as np

SCENE_JSON = "scene.json"
SPLATS_PLY = "splats.ply"
COLLISION_PLY = "collision.ply"
WALKABLE_NPZ = "walkable.npz"
CAMERAS_PARQUET = "cameras.parquet"
PREVIEW_PNG = "preview.png"
REQUIRED_FILES = (SCENE_JSON, SPLATS_PLY, COLLISION_PLY, WALKABLE_NPZ, CAMERAS_PARQUET, PREVIEW_PNG)

SCHEMA_VERSION = 1
SCENE_ID_RE = re.compile(r"[a-z0-9][a-z0-9._-]{0,63}")
TAG_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9._:=/+-]{0,63}")
SHA256_RE = re.compile(r"[0-9a-f]{64}")
SPLAT_PROPERTIES = ("x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
                    "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# Top-level files that are bookkeeping, not content (checkout marker, factory stage marker).
IGNORED_FILES = (".vid2sim-checkout.json", "stage.json")

# scene.json layout: required keys (and optional ones) per object.
TOP_REQUIRED = ("scene_id", "source", "world_frame", "metrics", "pipeline", "tags")
TOP_OPTIONAL = ("schema_version", "description", "extras")
SOURCE_REQUIRED = ("uri", "sha256", "clip_start_s", "clip_end_s", "group")
SOURCE_OPTIONAL = ("title", "license")
FRAME_REQUIRED = ("units", "up", "ground_z", "scale_source")
FRAME_OPTIONAL = ("notes", "extras")
PIPELINE_REQUIRED = ("config", "config_hash", "code_version")
PIPELINE_OPTIONAL = ("stages",)

PathLike = Union[str, os.PathLike]


class BundleError(ValueError):
    """A bundle (or a file in it) is invalid; the message names the file and the reason."""

    def __init__(self, path: PathLike, reason: str) -> None:
        self.path, self.reason = str(path), reason
        super().__init__(f"{self.path}: {reason}")


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


def is_valid_scene_id(scene_id: Any) -> bool:
    return isinstance(scene_id, str) and SCENE_ID_RE.fullmatch(scene_id) is not None


def check_scene_id(scene_id: Any, where: PathLike = "scene_id") -> str:
    """Return `scene_id` or raise BundleError (lowercase [a-z0-9][a-z0-9._-]{0,63})."""
    if not is_valid_scene_id(scene_id):
        raise BundleError(where, f"invalid scene_id {scene_id!r}: must match [a-z0-9][a-z0-9._-]{{0,63}}")
    return scene_id


# ----------------------------------------------------------------------------- scene.json

def _check_keys(obj: Any, required: tuple, optional: tuple, where: Path, label: str) -> dict:
    if not isinstance(obj, dict):
        raise BundleError(where, f"{label} must be an object, got {type(obj).__name__}")
    missing = [k for k in required if k not in obj]
    if missing:
        raise BundleError(where, f"missing required field(s) in {label}: {', '.join(missing)}")
    unknown = sorted(set(obj) - set(required) - set(optional))
    if unknown:
        raise BundleError(where, f"unknown field(s) in {label}: {', '.join(unknown)}")
    return obj


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def check_scene_json(scene: Any, where: PathLike = SCENE_JSON) -> dict:
    """Validate a parsed scene.json dict; return it or raise BundleError."""
    where = Path(where)
    _check_keys(scene, TOP_REQUIRED, TOP_OPTIONAL, where, "scene.json")
    check_scene_id(scene["scene_id"], where)
    src = _check_keys(scene["source"], SOURCE_REQUIRED, SOURCE_OPTIONAL, where, "source")
    if not isinstance(src["uri"], str) or not src["uri"]:
        raise BundleError(where, "source.uri must be a non-empty string")
    if not isinstance(src["sha256"], str) or not SHA256_RE.fullmatch(src["sha256"]):
        raise BundleError(where, "source.sha256 must be 64 lowercase hex characters")
    if not isinstance(src["group"], str) or not src["group"]:
        raise BundleError(where, "source.group must be a non-empty string")
    t0, t1 = src["clip_start_s"], src["clip_end_s"]
    if not (_is_number(t0) and _is_number(t1)) or t0 < 0 or t1 < t0:
        raise BundleError(where, f"source clip window must satisfy 0 <= clip_start_s <= clip_end_s, got {t0!r}, {t1!r}")
    wf = _check_keys(scene["world_frame"], FRAME_REQUIRED, FRAME_OPTIONAL, where, "world_frame")
    if wf["units"] != "m":
        raise BundleError(where, f"world_frame.units must be 'm', got {wf['units']!r}")
    if wf["up"] != "+z":
        raise BundleError(where, f"world_frame.up must be '+z', got {wf['up']!r}")
    if not _is_number(wf["ground_z"]) or wf["ground_z"] != 0:
        raise BundleError(where, f"world_frame.ground_z must be 0, got {wf['ground_z']!r}")
    if not isinstance(wf["scale_source"], str) or not wf["scale_source"]:
        raise BundleError(where, "world_frame.scale_source must be a non-empty string")
    if not isinstance(scene["metrics"], dict) or not all(isinstance(k, str) for k in scene["metrics"]):
        raise BundleError(where, "metrics must be an object with string keys")
    pipe = _check_keys(scene["pipeline"], PIPELINE_REQUIRED, PIPELINE_OPTIONAL, where, "pipeline")
    if not isinstance(pipe["config"], dict):
        raise BundleError(where, "pipeline.config must be an object")
    for k in ("config_hash", "code_version"):
        if not isinstance(pipe[k], str) or not pipe[k]:
            raise BundleError(where, f"pipeline.{k} must be a non-empty string")
    tags = scene["tags"]
    if not isinstance(tags, list) or not all(isinstance(t, str) and TAG_RE.fullmatch(t) for t in tags):
        raise BundleError(where, f"tags must be a list of tags matching {TAG_RE.pattern}, got {tags!r}")
    if "schema_version" in scene and scene["schema_version"] != SCHEMA_VERSION:
        raise BundleError(where, f"unsupported schema_version {scene['schema_version']!r} (expected {SCHEMA_VERSION})")
    return scene


def read_scene_json(path: Path) -> dict:
    if not path.is_file():
        raise BundleError(path, "missing scene.json")
    try:
        scene = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise BundleError(path, f"unreadable JSON ({e})") from None
    return check_scene_json(scene, path)


def make_scene_json(
    scene_id: str,
    *,
    source_uri: str,
    source_sha256: str,
    clip_start_s: float,
    clip_end_s: float,
    group: Optional[str] = None,
    scale_source: str,
    metrics: Optional[dict] = None,
    config: Any = None,
    config_hash: Optional[str] = None,
    code_version: Optional[str] = None,
    tags: tuple[str, ...] | list[str] = (),
    description: Optional[str] = None,
) -> dict:
    """Fill a valid scene.json dict. `group` defaults to the source video hash (clips of one
    video share a group, so splits never put them on both sides)."""
    from vid2sim.versioning import code_version as _code_version
    from vid2sim.versioning import config_hash as _config_hash
    from vid2sim.versioning import to_jsonable

    cfg = to_jsonable(config) if config is not None else {}
    if not isinstance(cfg, dict):
        cfg = {"value": cfg}
    scene = {
        "schema_version": SCHEMA_VERSION,
        "scene_id": scene_id,
        "source": {"uri": source_uri, "sha256": source_sha256, "clip_start_s": float(clip_start_s),
                   "clip_end_s": float(clip_end_s), "group": group or source_sha256},
        "world_frame": {"units": "m", "up": "+z", "ground_z": 0, "scale_source": scale_source},
        "metrics": dict(to_jsonable(metrics or {})),
        "pipeline": {"config": cfg, "config_hash": config_hash or _config_hash(cfg),
                     "code_version": code_version or _code_version()},
        "tags": list(tags),
    }
    if description:
        scene["description"] = description
    return check_scene_json(scene, "scene.json (make_scene_json)")


# ----------------------------------------------------------------------------- artifacts

def check_splats(path: Path) -> tuple[int, tuple[float, ...]]:
    """3DGS PLY -> (count, bounds [6]); raise BundleError when the layout is not 3DGS."""
    from plyfile import PlyData

    if not path.is_file():
        raise BundleError(path, "missing splats file")
    try:
        ply = PlyData.read(str(path))
        vertex = ply["vertex"]
    except KeyError:
        raise BundleError(path, "PLY has no 'vertex' element") from None
    except Exception as e:  # plyfile raises several types on malformed input
        raise BundleError(path, f"unreadable PLY ({type(e).__name__}: {e})") from None
    names = [p.name for p in vertex.properties]
    missing = [p for p in SPLAT_PROPERTIES if p not in names]
    if missing:
        raise BundleError(path, f"PLY lacks 3DGS properties: {', '.join(missing)}")
    rest = sorted(int(n[7:]) for n in names if n.startswith("f_rest_") and n[7:].isdigit())
    if rest != list(range(len(rest))) or len(rest) % 3:
        raise BundleError(path, "f_rest_* properties must be f_rest_0..f_rest_{3k-1}")
    n = int(vertex.count)
    if n == 0:
        raise BundleError(path, "PLY holds no Gaussians")
    xyz = np.stack([np.asarray(vertex[c], np.float64) for c in ("x", "y", "z")], 1)  # [N, 3]
    if not np.isfinite(xyz).all():
        raise BundleError(path, "non-finite splat positions")
    return n, tuple(float(v) for v in (*xyz.min(0), *xyz.max(0)))


def check_mesh(path: Path) -> tuple[int, tuple[float, ...]]:
    """Collision mesh -> (faces, bounds [6]); raise BundleError if unreadable or faceless."""
    import trimesh

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


def load_walkable(path: Path) -> tuple[np.ndarray, np.ndarray, float]:
    """walkable.npz -> (grid uint8 [H, W], origin float64 [2], resolution m/cell)."""
    if not Path(path).is_file():
        raise BundleError(path, "missing walkable grid")
    try:
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in ("grid", "origin", "resolution") if k not in z.files]
            if missing:
                raise BundleError(path, f"walkable npz lacks key(s): {', '.join(missing)}")
            grid, origin, res = z["grid"], z["origin"], z["resolution"]
    except BundleError:
        raise
    except Exception as e:
        raise BundleError(path, f"unreadable npz ({type(e).__name__}: {e})") from None
    if grid.ndim != 2 or grid.dtype != np.uint8 or grid.size == 0:
        raise BundleError(path, f"grid must be a non-empty uint8 [H, W] array, got {grid.dtype} {grid.shape}")
    if not np.isin(grid, (0, 1)).all():
        raise BundleError(path, "grid values must be 0 or 1")
    origin = np.asarray(origin, np.float64).reshape(-1)
    if origin.shape != (2,) or not np.isfinite(origin).all():
        raise BundleError(path, f"origin must be 2 finite numbers, got shape {origin.shape}")
    if np.asarray(res).size != 1 or not float(res) > 0 or not math.isfinite(float(res)):
        raise BundleError(path, f"resolution must be one positive number, got {res!r}")
    return grid, origin, float(res)


def load_cameras(path: Path):
    """cameras.parquet -> pyarrow.Table with exactly `cameras_schema()` columns and types."""
    import pyarrow.parquet as pq

    from vid2sim.factory.sfm.posed import cameras_schema

    if not Path(path).is_file():
        raise BundleError(path, "missing cameras table")
    try:
        table = pq.read_table(path)
    except Exception as e:
        raise BundleError(path, f"unreadable parquet ({type(e).__name__}: {e})") from None
    want = cameras_schema()
    got = {f.name: f.type for f in table.schema}
    missing = [f.name for f in want if f.name not in got]
    wrong = [f"{f.name} is {got[f.name]}, expected {f.type}" for f in want if f.name in got and got[f.name] != f.type]
    extra = sorted(set(got) - set(want.names))
    if missing or wrong or extra:
        parts = ([f"missing columns {missing}"] if missing else []) + wrong + ([f"unknown columns {extra}"] if extra else [])
        raise BundleError(path, "wrong cameras schema: " + "; ".join(parts))
    table = table.select(want.names)
    splits = set(table.column("split").to_pylist())
    if not splits <= {"train", "test"}:
        raise BundleError(path, f"split values must be 'train' or 'test', got {sorted(map(str, splits))}")
    if table.num_rows == 0:
        raise BundleError(path, "cameras table has no rows")
    return table


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
    grid, _, res = load_walkable(folder / WALKABLE_NPZ)
    cams = load_cameras(folder / CAMERAS_PARQUET)
    check_png(folder / PREVIEW_PNG)
    splits = cams.column("split").to_pylist()
    counts = {"all": len(splits), "train": splits.count("train"), "test": splits.count("test")}
    return BundleInfo(path=folder, scene_id=scene["scene_id"], scene=scene, num_splats=n, bounds=bounds,
                      mesh_bounds=mesh_bounds, num_faces=faces,
                      walkable_area_m2=float(grid.sum()) * res * res, frame_counts=counts,
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
    walkable: tuple[np.ndarray, Any, float],
    cameras,
    preview_png: PathLike,
    extras: Optional[dict[str, PathLike]] = None,
    overwrite: bool = False,
) -> Path:
    """Assemble a bundle at `out_dir` (atomically: temp sibling, validate, rename).

    walkable: (grid uint8 [H, W], origin [2], resolution); cameras: pyarrow.Table with
    `cameras_schema()`; extras: {relative name: file or folder} copied as-is.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

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
        grid, origin, res = walkable
        np.savez(tmp / WALKABLE_NPZ, grid=np.asarray(grid), origin=np.asarray(origin, np.float64),
                 resolution=np.float64(res))
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
