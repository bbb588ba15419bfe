"""Typed views of manifest rows: `SceneRecord` (one scene version) and `Artifact`."""

from __future__ import annotations

import hashlib
import json
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
    """Keep the highest version of each scene_id."""
    if table.num_rows == 0:
        return table
    import numpy as np

    order = pc.sort_indices(table, [("scene_id", "ascending"), ("version", "descending")])
    sids = table["scene_id"].take(order).to_numpy(zero_copy_only=False)
    first = np.ones(len(sids), bool)
    first[1:] = sids[1:] != sids[:-1]
    return table.take(order.to_numpy()[first])


def _artifact_lists(col: pa.ChunkedArray) -> list[tuple[Artifact, ...]]:
    """list<struct<name, sha256, size>> column -> per-row artifact tuples (column-wise, fast)."""
    out: list[tuple[Artifact, ...]] = []
    for chunk in col.chunks:
        offsets = chunk.offsets.to_numpy()
        values = chunk.values
        arts = [_fast_new(Artifact, {"name": n, "sha256": h, "size": z}) for n, h, z in zip(
            values.field("name").to_pylist(), values.field("sha256").to_pylist(), values.field("size").to_pylist())]
        out.extend(tuple(arts[offsets[i]:offsets[i + 1]]) for i in range(len(chunk)))
    return out


def _fast_new(cls, fields: dict):
    """Build a frozen dataclass from already-typed fields without per-field __setattr__."""
    obj = object.__new__(cls)
    obj.__dict__.update(fields)
    return obj


def records(table: pa.Table) -> list[SceneRecord]:
    """Manifest rows -> SceneRecords, converting column by column (10k rows in well under a second)."""
    from datetime import timedelta, timezone

    if table.num_rows == 0:
        return []
    cols = {c: table.column(c).to_pylist() for c in table.column_names
            if c not in ("created_at", "artifacts", "metrics", "bounds", "mesh_bounds", "tags")}
    epoch = datetime(1970, 1, 1, tzinfo=timezone.utc)
    cols["created_at"] = [epoch + timedelta(microseconds=us) for us in
                          table.column("created_at").cast(pa.int64()).to_pylist()]
    cols["metrics"] = [json.loads(m or "{}") for m in table.column("metrics").to_pylist()]
    for c in ("bounds", "mesh_bounds", "tags"):
        cols[c] = [tuple(v or ()) for v in table.column(c).to_pylist()]
    cols["artifacts"] = _artifact_lists(table.column("artifacts"))
    names = [f for f in SceneRecord.__dataclass_fields__]
    return [_fast_new(SceneRecord, dict(zip(names, vals))) for vals in zip(*(cols[n] for n in names))]
