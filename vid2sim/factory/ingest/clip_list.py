"""Ingestion manifests: which sources to process, with windows, tags and groups.

Formats: YAML (a list of rows, or `{sources: [...]}`), CSV, Parquet. One row:

  source          path or URI (video file, image folder, http(s)/s3/gs URI)   REQUIRED
  licence         licence of the footage (e.g. "CC-BY-4.0")                   REQUIRED
  start, end      clip window in seconds (both or neither; default: cut into N-s clips)
  group           source-video group id (clips of one walk share it, so splits never
                  leak between train and test); default: the source's file stem
  capture_height  camera height above the ground in metres (default 1.5, hand-held)
  city, weather   free-text tags (also accepted nested under `tags:` in YAML)
  sha256          expected content hash of the source (checked when given)

Relative source paths are resolved against the manifest's folder. A bad row raises
`StageError("manifest", reason)`: `missing_fields`, `bad_window`, `bad_value`, `bad_yaml`,
`unknown_field` (a column that looks like a misspelled field; other extra columns are tags),
`unknown_format`, `empty_manifest`, `missing_manifest`.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

from vid2sim.factory.ingest.sources import is_uri, uri_name
from vid2sim.factory.runtime.stage_cache import StageError

STAGE = "manifest"
REQUIRED = ("source", "licence")
TAG_FIELDS = ("city", "weather", "licence")
DEFAULT_CAPTURE_HEIGHT = 1.5


@dataclass(frozen=True)
class ManifestRow:
    source: str
    licence: str
    group: str
    start: Optional[float] = None
    end: Optional[float] = None
    capture_height: float = DEFAULT_CAPTURE_HEIGHT
    tags: dict = field(default_factory=dict)  # city, weather, licence, extra columns
    sha256: Optional[str] = None

    @property
    def window(self) -> Optional[tuple[float, float]]:
        return None if self.start is None else (self.start, self.end)


def load_manifest(path: Path) -> list[ManifestRow]:
    """Read and validate a manifest file; raises StageError on the first bad row."""
    path = Path(path)
    if not path.is_file():
        raise StageError(STAGE, "missing_manifest", str(path))
    records = _read_records(path)
    if not records:
        raise StageError(STAGE, "empty_manifest", f"{path}: no rows")
    return [parse_row(r, i, path.parent, str(path)) for i, r in enumerate(records)]


def _read_records(path: Path) -> list[dict]:
    suffix = path.suffix.lower()
    if suffix in (".yaml", ".yml"):
        import yaml

        try:
            data = yaml.safe_load(path.read_text()) or []
        except yaml.YAMLError as e:
            mark = getattr(e, "problem_mark", None)
            at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
            raise StageError(STAGE, "bad_yaml", f"{path}: not valid YAML{at} ({getattr(e, 'problem', e)})") from None
        if isinstance(data, dict):
            data = data.get("sources", [])
        if not isinstance(data, list) or not all(isinstance(r, dict) for r in data):
            raise StageError(STAGE, "bad_value", f"{path}: expected a list of rows")
        return data
    if suffix == ".csv":
        with open(path, newline="") as f:
            return [dict(r) for r in csv.DictReader(f)]
    if suffix == ".parquet":
        import pyarrow.parquet as pq

        return pq.read_table(path).to_pylist()
    raise StageError(STAGE, "unknown_format", f"{path}: use .yaml, .csv or .parquet")


def _empty(v: Any) -> bool:
    return v is None or (isinstance(v, str) and not v.strip()) or (isinstance(v, float) and math.isnan(v))


def _float(v: Any, name: str, where: str) -> Optional[float]:
    if _empty(v):
        return None
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise StageError(STAGE, "bad_value", f"{where}: {name}={v!r} is not a number") from None
    if not math.isfinite(x):
        raise StageError(STAGE, "bad_value", f"{where}: {name}={v!r} is not a finite number")
    return x


def parse_row(rec: dict, index: int, base: Path = Path("."), origin: str = "manifest") -> ManifestRow:
    """Validate one record (a dict) into a ManifestRow."""
    rec = dict(rec)
    tags = dict(rec.pop("tags", None) or {})
    for k in TAG_FIELDS:  # nested tags count as the top-level field
        if _empty(rec.get(k)) and not _empty(tags.get(k)):
            rec[k] = tags[k]
    where = f"{origin} row {index}"
    missing = [k for k in REQUIRED if _empty(rec.get(k))]
    if missing:
        raise StageError(STAGE, "missing_fields", f"{where}: missing {', '.join(missing)}")
    _check_spelling(rec, where)
    start, end = _float(rec.get("start"), "start", where), _float(rec.get("end"), "end", where)
    if (start is None) != (end is None) or (start is not None and (start < 0 or end <= start)):
        raise StageError(STAGE, "bad_window", f"{where}: start={start} end={end} (need 0 <= start < end)")
    height = _float(rec.get("capture_height"), "capture_height", where)
    height = DEFAULT_CAPTURE_HEIGHT if height is None else height
    if height <= 0:
        raise StageError(STAGE, "bad_value", f"{where}: capture_height={height} must be > 0")
    source = str(rec["source"]).strip()
    if not is_uri(source) and not Path(source).is_absolute():
        source = str((Path(base) / source).resolve())
    group = str(rec.get("group")).strip() if not _empty(rec.get("group")) else _stem(source)
    tags.update({k: rec[k] for k in TAG_FIELDS if not _empty(rec.get(k))})
    tags.update({k: v for k, v in rec.items() if k not in KNOWN and not _empty(v)})
    sha = None if _empty(rec.get("sha256")) else str(rec["sha256"]).strip().lower()
    return ManifestRow(source=source, licence=str(rec["licence"]), group=group, start=start, end=end,
                       capture_height=height, tags=tags, sha256=sha)


KNOWN = ("source", "licence", "start", "end", "group", "capture_height", "sha256", "city", "weather")


def _check_spelling(rec: dict, where: str) -> None:
    """Extra columns are tags, but one that looks like a misspelled field is an error."""
    import difflib

    for k in rec:
        if k in KNOWN:
            continue
        close = difflib.get_close_matches(str(k).lower(), KNOWN, n=1, cutoff=0.75)
        if close:
            raise StageError(STAGE, "unknown_field", f"{where}: unknown field {k!r} (did you mean {close[0]!r}?)")


def _stem(source: str) -> str:
    name = uri_name(source)  # never the query, fragment or user info of a URI (secrets)
    return name.rsplit(".", 1)[0] if "." in name else name
