"""Code version and config hashing shared by every stage that records provenance."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import subprocess
import types
import typing
from functools import lru_cache
from pathlib import Path
from typing import Any

from vid2sim import __version__


@lru_cache(maxsize=1)
def code_version() -> str:
    """Package version plus the git commit (and '+dirty') when run from a checkout."""
    root = Path(__file__).resolve().parent.parent
    try:
        sha = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "--short=12", "HEAD"],
            capture_output=True, text=True, timeout=5, check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True, text=True, timeout=5, check=True,
        ).stdout.strip()
        return f"{__version__}+g{sha}{'.dirty' if dirty else ''}"
    except (OSError, subprocess.SubprocessError):
        return __version__


def to_jsonable(obj: Any) -> Any:
    """Dataclasses, paths and tuples -> plain JSON types (for saving configs with results)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    return obj


def from_jsonable(cls: Any, data: Any) -> Any:
    """Inverse of `to_jsonable` for a config dataclass: rebuild `cls` from plain JSON, following
    the field type hints (nested dataclasses, Optional, tuples, Paths). Unknown keys raise."""
    if not dataclasses.is_dataclass(cls):
        return _coerce(cls, data)
    if not isinstance(data, dict):
        raise TypeError(f"{cls.__name__}: expected an object, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names)
    if unknown:
        raise TypeError(f"{cls.__name__}: unknown field(s) {unknown}")
    return cls(**{k: _coerce(hints[k], v) for k, v in data.items()})


def _coerce(tp: Any, value: Any) -> Any:
    """One JSON value -> the annotated type `tp` (best effort for unions and containers)."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if value is None or tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        return _coerce(inner[0], value) if len(inner) == 1 else value
    if dataclasses.is_dataclass(tp):
        return from_jsonable(tp, value)
    if origin is tuple or tp is tuple:
        if args and args[-1] is not Ellipsis:
            return tuple(_coerce(a, v) for a, v in zip(args, value))
        return tuple(_coerce(args[0], v) if args else v for v in value)
    if origin is list:
        return [_coerce(args[0], v) if args else v for v in value]
    if origin is dict:
        return {k: _coerce(args[1], v) if args else v for k, v in value.items()}
    if tp is Path:
        return Path(value)
    if tp is float and isinstance(value, int):
        return float(value)
    return value


def config_hash(*parts: Any) -> str:
    """Stable sha256 (hex, 16 chars) of configs/inputs, for cache keys and pipeline hashes."""
    payload = json.dumps([to_jsonable(p) for p in parts], sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(payload.encode()).hexdigest()[:16]
