"""The manifest: an append-only Delta Lake table with one row per scene version.

Commits are optimistic: a writer reads snapshot V, builds its rows from it and commits with
`max_commit_retries=0`, so the commit lands as exactly V+1 or fails with CommitFailedError when
another writer got there first; then it re-reads and rebuilds. Rows are never rewritten, so a
scene's versions are contiguous and unique even with many concurrent writers.
"""

from __future__ import annotations

import random
import time
from datetime import datetime, timezone
from typing import Callable, Optional, Union

import pyarrow as pa

ARTIFACT_TYPE = pa.struct([("name", pa.string()), ("sha256", pa.string()), ("size", pa.int64())])

MANIFEST_SCHEMA = pa.schema([
    ("scene_id", pa.string()),
    ("version", pa.int64()),
    ("status", pa.string()),  # active | deprecated
    ("event", pa.string()),  # add | tag | untag | deprecate
    ("message", pa.string()),  # deprecation reason etc.
    ("created_at", pa.timestamp("us", tz="UTC")),
    ("source_uri", pa.string()),
    ("source_sha256", pa.string()),
    ("clip_start_s", pa.float64()),
    ("clip_end_s", pa.float64()),
    ("source_group", pa.string()),
    ("num_frames", pa.int64()),
    ("num_train_frames", pa.int64()),
    ("num_test_frames", pa.int64()),
    ("num_splats", pa.int64()),
    ("metrics", pa.string()),  # JSON object
    ("bounds", pa.list_(pa.float64())),  # [6] splat centres xmin ymin zmin xmax ymax zmax
    ("mesh_bounds", pa.list_(pa.float64())),  # [6] collision mesh AABB
    ("walkable_area_m2", pa.float64()),
    ("tags", pa.list_(pa.string())),
    ("pipeline_hash", pa.string()),
    ("code_version", pa.string()),
    ("content_hash", pa.string()),  # sha256 over the sorted (name, sha256) artifact list
    ("artifacts", pa.list_(ARTIFACT_TYPE)),
])

TABLE_CONFIG = {
    "delta.enableExpiredLogCleanup": "false",  # keep the whole log: time travel to any version
    "delta.checkpointInterval": "100",
}

AsOf = Union[None, int, str, datetime]


class CommitConflict(RuntimeError):
    """Gave up after too many concurrent-commit conflicts."""


def parse_as_of(as_of: AsOf) -> Union[None, int, datetime]:
    """None | registry version (int or digits) | timestamp (datetime or ISO 8601; naive = UTC)."""
    if as_of is None or isinstance(as_of, int):
        return as_of
    if isinstance(as_of, datetime):
        ts = as_of
    else:
        s = str(as_of).strip()
        if s.lstrip("v").isdigit():
            return int(s.lstrip("v"))
        try:
            ts = datetime.fromisoformat(s.replace("Z", "+00:00"))
        except ValueError:
            raise ValueError(f"--as-of {as_of!r}: expected a registry version number or an ISO timestamp") from None
    return ts if ts.tzinfo else ts.replace(tzinfo=timezone.utc)


class ManifestTable:
    """Delta table wrapper: create-if-missing, snapshot reads (with time travel), safe appends."""

    def __init__(self, uri: str, storage_options: Optional[dict] = None) -> None:
        self.uri, self.storage_options = uri, storage_options
        self._dt = None
        self._cache: tuple[int, pa.Table] | None = None

    # -- table handle
    def _open(self):
        from deltalake import DeltaTable

        if self._dt is None:
            if not DeltaTable.is_deltatable(self.uri, storage_options=self.storage_options):
                self._create()
            self._dt = DeltaTable(self.uri, storage_options=self.storage_options)
        return self._dt

    def _create(self) -> None:
        from deltalake import DeltaTable

        try:
            DeltaTable.create(self.uri, MANIFEST_SCHEMA, mode="ignore", name="vid2sim_scenes",
                              configuration=TABLE_CONFIG, storage_options=self.storage_options)
        except Exception:  # another process created it first
            if not DeltaTable.is_deltatable(self.uri, storage_options=self.storage_options):
                raise

    def exists(self) -> bool:
        from deltalake import DeltaTable

        return DeltaTable.is_deltatable(self.uri, storage_options=self.storage_options)

    def refresh(self) -> int:
        dt = self._open()
        dt.update_incremental()
        return dt.version()

    @property
    def version(self) -> int:
        return self.refresh()

    # -- reads
    def read(self, as_of: AsOf = None) -> tuple[int, pa.Table]:
        """(registry version, all rows) at the latest version or `as_of`."""
        from deltalake import DeltaTable

        as_of = parse_as_of(as_of)
        if as_of is None:
            v = self.refresh()
            if self._cache is None or self._cache[0] != v:
                self._cache = (v, self._to_arrow(self._dt))
            return self._cache
        dt = DeltaTable(self.uri, storage_options=self.storage_options)
        try:
            dt.load_as_version(as_of)
        except Exception as e:
            raise ValueError(f"as-of {as_of!s}: no such registry version or time ({e})") from None
        return dt.version(), self._to_arrow(dt)

    @staticmethod
    def _to_arrow(dt) -> pa.Table:
        t = dt.to_pyarrow_table()
        return t.select(MANIFEST_SCHEMA.names).cast(MANIFEST_SCHEMA)

    def history(self) -> list[dict]:
        return self._open().history()

    # -- writes
    def commit(self, build: Callable[[int, pa.Table], Optional[list[dict]]], *, max_attempts: int = 400,
               operation: str = "append") -> tuple[Optional[int], Optional[list[dict]]]:
        """Append the rows `build(version, rows)` returns, rebuilding on conflict.

        Returns (committed registry version, rows) or (None, None) when `build` returned None
        (nothing to do at that snapshot).
        """
        from deltalake import CommitProperties, write_deltalake
        from deltalake.exceptions import CommitFailedError

        for attempt in range(max_attempts):
            v, table = self.read()
            rows = build(v, table)
            if not rows:
                return None, None
            data = pa.Table.from_pylist(rows, schema=MANIFEST_SCHEMA)
            try:
                write_deltalake(self._dt, data, mode="append", storage_options=self.storage_options,
                                commit_properties=CommitProperties(
                                    max_commit_retries=0, custom_metadata={"vid2sim.operation": operation}))
                return v + 1, rows
            except CommitFailedError:
                time.sleep(random.uniform(0, min(0.5, 0.005 * 2 ** min(attempt, 7))))
        raise CommitConflict(f"{self.uri}: gave up after {max_attempts} conflicting commits")

    def append_bulk(self, rows: list[dict]) -> int:
        """Blind append (no conflict check): for benchmarks and imports of pre-built rows."""
        from deltalake import write_deltalake

        self._open()
        write_deltalake(self._dt, pa.Table.from_pylist(rows, schema=MANIFEST_SCHEMA), mode="append",
                        storage_options=self.storage_options)
        return self.refresh()

    def compact(self) -> dict:
        """Merge small Parquet files and write a checkpoint (rows and time travel unchanged)."""
        dt = self._open()
        metrics = dt.optimize.compact()
        dt.update_incremental()
        dt.create_checkpoint()
        return metrics


def now_utc() -> datetime:
    return datetime.now(timezone.utc)
