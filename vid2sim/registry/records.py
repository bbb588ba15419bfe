"""Typed views of manifest rows: `SceneRecord` (one scene version) and `Artifact`."""

from __future__ import annotations

import gc
import hashlib
import json
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, replace
from datetime import datetime
from typing import Any, Optional

import pyarrow as pa
import pyarrow.compute as pc

ACTIVE, DEPRECATED = "active", "deprecated"


@dataclass(frozen=True)
class Artifact:
    name: str  # relative posix path inside the bundle
    sha256: str
    size: int


@dataclass(frozen=True)
class SceneRecord:
    """One version of one scene, as stored in the manifest."""

    scene_id: str
    version: int
    status: str
    event: str
    message: Optional[str]
    created_at: datetime
    source_uri: str
    source_sha256: str
    clip_start_s: float
    clip_end_s: float
    source_group: str
    num_frames: int
    num_train_frames: int
    num_test_frames: int
    num_splats: int
    metrics: dict[str, Any]
    bounds: tuple[float, ...]  # [6]
    mesh_bounds: tuple[float, ...]  # [6]
    walkable_area_m2: float
    tags: tuple[str, ...]
    pipeline_hash: str
    code_version: str
    content_hash: str
    artifacts: tuple[Artifact, ...] = field(default_factory=tuple)

    @property
    def ref(self) -> str:
        return f"{self.scene_id}@{self.version}"

    def artifact(self, name: str) -> Artifact:
        for a in self.artifacts:
            if a.name == name:
                return a
        raise KeyError(f"{self.ref} has no artifact {name!r}")

    @classmethod
    def from_row(cls, row: dict) -> "SceneRecord":
        r = dict(row)
        r["metrics"] = json.loads(r["metrics"] or "{}")
        r["bounds"] = tuple(r["bounds"] or ())
        r["mesh_bounds"] = tuple(r["mesh_bounds"] or ())
        r["tags"] = tuple(r["tags"] or ())
        r["artifacts"] = tuple(Artifact(**a) for a in r["artifacts"] or ())
        return cls(**r)

    def to_row(self) -> dict:
        r = asdict(self)
        r["metrics"] = json.dumps(self.metrics, sort_keys=True)
        r["bounds"], r["mesh_bounds"], r["tags"] = list(self.bounds), list(self.mesh_bounds), list(self.tags)
        r["artifacts"] = [asdict(a) for a in self.artifacts]
        return r

    def to_dict(self) -> dict:
        """JSON-ready dict (timestamps as ISO strings)."""
        d = self.to_row()
        d["metrics"] = self.metrics
        d["created_at"] = self.created_at.isoformat()
        return d

    def evolve(self, **changes: Any) -> "SceneRecord":
        return replace(self, **changes)


def content_hash(artifacts: list[Artifact] | tuple[Artifact, ...]) -> str:
    payload = json.dumps(sorted((a.name, a.sha256) for a in artifacts), separators=(",", ":"))
    return hashlib.sha256(payload.encode()).hexdigest()


def latest_rows(table: pa.Table) -> pa.Table:
    """The latest-version view (group by scene_id, max version), in Arrow, ordered by scene_id.

    One sort over (scene_id asc, version desc) and the first row of each scene_id run, so only
    these rows are ever materialised as SceneRecords.
    """
    if table.num_rows == 0:
        return table
    import numpy as np

    keys = table.select(["scene_id", "version"])
    order = pc.sort_indices(keys, [("scene_id", "ascending"), ("version", "descending")])
    sids = keys["scene_id"].take(order).to_numpy(zero_copy_only=False)
    first = np.ones(len(sids), bool)
    first[1:] = sids[1:] != sids[:-1]
    return table.take(order.to_numpy()[first])


def _list_tuples(col: pa.ChunkedArray) -> list[tuple]:
    """list<T> column -> per-row tuples (null -> ()), slicing one flat Python list per chunk."""
    out: list[tuple] = []
    for chunk in col.chunks:
        offs = chunk.offsets.to_pylist()  # absolute into chunk.values, also for a sliced chunk
        flat = chunk.values.to_pylist()
        rows = [tuple(flat[a:b]) for a, b in zip(offs[:-1], offs[1:])]
        if chunk.null_count:
            rows = [r if ok else () for r, ok in zip(rows, chunk.is_valid().to_pylist())]
        out.extend(rows)
    return out


def _artifact_lists(col: pa.ChunkedArray) -> list[tuple[Artifact, ...]]:
    """list<struct<name, sha256, size>> column -> per-row artifact tuples (column-wise, fast)."""
    out: list[tuple[Artifact, ...]] = []
    new = object.__new__
    for chunk in col.chunks:
        offs = chunk.offsets.to_pylist()
        names, shas, sizes = (f.to_pylist() for f in chunk.values.flatten())  # flatten honours offsets
        arts = []
        for n, h, z in zip(names, shas, sizes):
            a = new(Artifact)
            a.__dict__.update(name=n, sha256=h, size=z)
            arts.append(a)
        rows = [tuple(arts[a:b]) for a, b in zip(offs[:-1], offs[1:])]
        if chunk.null_count:
            rows = [r if ok else () for r, ok in zip(rows, chunk.is_valid().to_pylist())]
        out.extend(rows)
    return out


def _fast_new(cls, fields: dict):
    """Build a frozen dataclass from already-typed fields without per-field __setattr__."""
    obj = object.__new__(cls)
    obj.__dict__.update(fields)
    return obj


@contextmanager
def _no_cyclic_gc():
    """Pause the cyclic GC while building many acyclic objects (its passes dominate otherwise)."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def records(table: pa.Table) -> list[SceneRecord]:
    """Manifest rows -> SceneRecords, converting column by column (equal to `SceneRecord.from_row`)."""
    if table.num_rows == 0:
        return []
    with _no_cyclic_gc():
        return _records(table)


def _records(table: pa.Table) -> list[SceneRecord]:
    from datetime import timedelta, timezone

    nested = ("created_at", "artifacts", "metrics", "bounds", "mesh_bounds", "tags")
    cols = {c: table.column(c).to_pylist() for c in table.column_names if c not in nested}
    epoch = datetime(1970, 1, 1, tzinfo=timezone.utc)
    cols["created_at"] = [epoch + timedelta(microseconds=us) for us in
                          table.column("created_at").cast(pa.int64()).to_pylist()]
    loads = json.loads
    cols["metrics"] = [loads(m) if m else {} for m in table.column("metrics").to_pylist()]
    for c in ("bounds", "mesh_bounds", "tags"):
        cols[c] = _list_tuples(table.column(c))
    cols["artifacts"] = _artifact_lists(table.column("artifacts"))
    names = list(SceneRecord.__dataclass_fields__)
    new, out = object.__new__, []
    for vals in zip(*(cols[n] for n in names)):
        rec = new(SceneRecord)
        rec.__dict__.update(zip(names, vals))
        out.append(rec)
    return out
