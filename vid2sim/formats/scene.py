"""scene.json: the bundle's metadata record (identity, source clip, world frame, metrics, pipeline).

Layout (schema_version 1):
  scene_id     [a-z0-9][a-z0-9._-]{0,63}
  source       {uri, sha256, clip_start_s, clip_end_s, group[, title, license]}
  world_frame  {units "m", up "+z", ground_z 0, scale_source[, notes, extras]}
  metrics      {str: value}
  pipeline     {config, config_hash, code_version[, stages]}
  tags         [tag, ...]; optional: schema_version, description, robot, extras
  robot        the robot the scene was made for (`formats/robot.py` RobotSpec.to_dict: footprint,
               clearance, bicycle model, walker body radius, camera mount and intrinsics)
Reads/writes nothing but the JSON file itself.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any, Optional

from vid2sim.formats.errors import BundleError, PathLike
from vid2sim.formats.robot import RobotSpec
from vid2sim.versioning import code_version as _code_version
from vid2sim.versioning import config_hash as _config_hash
from vid2sim.versioning import to_jsonable

SCENE_JSON = "scene.json"
SCHEMA_VERSION = 1
SCENE_ID_RE = re.compile(r"[a-z0-9][a-z0-9._-]{0,63}")
TAG_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9._:=/+-]{0,63}")
SHA256_RE = re.compile(r"[0-9a-f]{64}")

# scene.json layout: required keys (and optional ones) per object.
TOP_REQUIRED = ("scene_id", "source", "world_frame", "metrics", "pipeline", "tags")
TOP_OPTIONAL = ("schema_version", "description", "robot", "extras")
SOURCE_REQUIRED = ("uri", "sha256", "clip_start_s", "clip_end_s", "group")
SOURCE_OPTIONAL = ("title", "license")
FRAME_REQUIRED = ("units", "up", "ground_z", "scale_source")
FRAME_OPTIONAL = ("notes", "extras")
PIPELINE_REQUIRED = ("config", "config_hash", "code_version")
PIPELINE_OPTIONAL = ("stages",)


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
    if not _finite_json(scene["metrics"]):
        raise BundleError(where, "metrics must hold finite numbers (NaN/inf are not JSON)")
    pipe = _check_keys(scene["pipeline"], PIPELINE_REQUIRED, PIPELINE_OPTIONAL, where, "pipeline")
    if not isinstance(pipe["config"], dict):
        raise BundleError(where, "pipeline.config must be an object")
    for k in ("config_hash", "code_version"):
        if not isinstance(pipe[k], str) or not pipe[k]:
            raise BundleError(where, f"pipeline.{k} must be a non-empty string")
    tags = scene["tags"]
    if not isinstance(tags, list) or not all(isinstance(t, str) and TAG_RE.fullmatch(t) for t in tags):
        raise BundleError(where, f"tags must be a list of tags matching {TAG_RE.pattern}, got {tags!r}")
    if "robot" in scene:
        try:
            RobotSpec.from_dict(scene["robot"])
        except ValueError as e:
            raise BundleError(where, f"invalid robot: {e}") from None
    if "schema_version" in scene and scene["schema_version"] != SCHEMA_VERSION:
        raise BundleError(where, f"unsupported schema_version {scene['schema_version']!r} (expected {SCHEMA_VERSION})")
    return scene


def _no_constant(name: str) -> None:
    raise ValueError(f"non-finite number {name} in scene.json")


def _finite_json(obj: Any) -> bool:
    if isinstance(obj, float):
        return math.isfinite(obj)
    if isinstance(obj, dict):
        return all(_finite_json(v) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return all(_finite_json(v) for v in obj)
    return True


def read_scene_json(path: Path) -> dict:
    if not path.is_file():
        raise BundleError(path, "missing scene.json")
    try:
        scene = json.loads(path.read_text(), parse_constant=_no_constant)
    except ValueError as e:
        if str(e).startswith("non-finite"):
            raise BundleError(path, f"{e} (strict JSON has none; metrics must be finite numbers)") from None
        raise BundleError(path, f"unreadable JSON ({e})") from None
    except OSError as e:
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
    robot: Optional[RobotSpec] = None,
) -> dict:
    """Fill a valid scene.json dict. `group` defaults to the source video hash (clips of one
    video share a group, so splits never put them on both sides). `robot`: the robot the scene
    was made for, recorded under `robot` (None: not recorded)."""
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
    if robot is not None:
        scene["robot"] = robot.to_dict()
    return check_scene_json(scene, "scene.json (make_scene_json)")


