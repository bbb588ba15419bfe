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


def records(table: pa.Table) -> list[SceneRecord]:
    return [SceneRecord.from_row(r) for r in table.to_pylist()]
