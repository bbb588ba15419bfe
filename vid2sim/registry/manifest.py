"""The manifest: an append-only Delta Lake table with one row per scene version.

Commits are optimistic: a writer reads snapshot V, builds its rows from it and commits with
`max_commit_retries=0`, so the commit lands as exactly V+1 or fails with CommitFailedError when
another writer got there first; then it re-reads and rebuilds. Rows are never rewritten, so a
scene's versions are contiguous and unique even with many concurrent writers.

Maintenance: every commit adds one small Parquet file, and reads/commits slow down as they pile
up. After a successful commit that leaves more than `auto_compact_files` active files, the writer
rewrites the rows into one file (see `compact`) and writes a checkpoint. That is best effort:
losing a race with a concurrent commit is logged and the commit that triggered it still succeeds.
Compaction only tombstones the old files; they stay on disk so time travel to any earlier version
keeps working. Only an explicit `vacuum` (`vid2sim registry compact --vacuum-hours H`) deletes
files tombstoned more than H hours ago, after which versions older than that can no longer be read.
"""

from __future__ import annotations

import json
import logging
import random
import re
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable, Optional, Union

import pyarrow as pa
import pyarrow.fs as pafs

from vid2sim.registry.blobs import arrow_filesystem
from vid2sim.registry.errors import HistoryLost, RegistryNotFound

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

log = logging.getLogger(__name__)
LOG_DIR = "_delta_log"
COMMIT_RE = re.compile(r"(\d{20})\.json")
MIN_FULL_VACUUM_HOURS = 1  # untracked files younger than this may belong to a commit in flight


S3_SCHEMES = ("s3", "s3a")
UNSAFE_RENAME = "aws_s3_allow_unsafe_rename"


def safe_storage_options(uri: str, options: Optional[dict] = None) -> Optional[dict]:
    """delta-rs storage options that keep concurrent commits safe on `uri`'s store.

    S3 and S3-compatible stores (MinIO, Ceph, moto) have no atomic rename, so a commit must be a
    conditional put of `_delta_log/<version>.json` (If-None-Match): two committers of the same
    version cannot both win. We ask for `conditional_put=etag` explicitly (delta-rs 1.6 also
    defaults to it) unless a DynamoDB lock (`AWS_S3_LOCKING_PROVIDER`) is configured, and refuse
    `AWS_S3_ALLOW_UNSAFE_RENAME`, which lets two writers overwrite the same log entry.
    """
    scheme = uri.split("://", 1)[0].lower() if "://" in uri else ""
    if scheme not in S3_SCHEMES:
        return options
    opts = dict(options or {})
    keys = {k.lower(): k for k in opts}
    if str(opts.get(keys.get(UNSAFE_RENAME, ""), "")).lower() == "true":
        raise ValueError(f"{uri}: AWS_S3_ALLOW_UNSAFE_RENAME loses concurrent commits; "
                         "use conditional_put=etag (default) or a DynamoDB lock")
    if "aws_s3_locking_provider" not in keys and "conditional_put" not in keys \
            and "aws_conditional_put" not in keys:
        opts["conditional_put"] = "etag"
    return opts


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

    def __init__(self, uri: str, storage_options: Optional[dict] = None, auto_compact_files: int = 0) -> None:
        self.uri, self.storage_options = uri, safe_storage_options(uri, storage_options)
        self.auto_compact_files = auto_compact_files  # 0 = never compact automatically
        self._dt = None
        self._cache: tuple[int, pa.Table] | None = None
        self._checked = -1  # log files 0.._checked were seen present and non-empty
        self.local = "://" not in uri
        self._fs: Optional[tuple[pafs.FileSystem, str]] = None  # the store's filesystem (not local)

    # -- table handle
    def _open(self, create: bool = True):
        """The Delta table handle; a missing table is created only when `create` (writes)."""
        from deltalake import DeltaTable

        if self._dt is None:
            if not self.exists():
                if not create:
                    return None
                self._create()
            self._dt = self._guard(lambda: DeltaTable(self.uri, storage_options=self.storage_options))
        return self._dt

    def _guard(self, fn):
        """Run a delta-rs call; its errors on a damaged log become one named HistoryLost line."""
        from deltalake.exceptions import DeltaError

        try:
            return fn()
        except (DeltaError, OSError) as e:
            try:  # name the gap rather than delta-rs's words
                found = self.log_problems()
            except OSError:  # the store itself does not answer: delta-rs's words it is
                found = []
            first = str(e).splitlines()[0][:300] if str(e) else type(e).__name__
            raise HistoryLost(f"{self.uri}: {found[0] if found else f'manifest log unreadable ({first})'}; "
                              f"run `vid2sim registry verify`") from None

    def _create(self) -> None:
        from deltalake import DeltaTable

        try:
            DeltaTable.create(self.uri, MANIFEST_SCHEMA, mode="ignore", name="vid2sim_scenes",
                              configuration=TABLE_CONFIG, storage_options=self.storage_options)
        except Exception:  # another process created it first
            if not DeltaTable.is_deltatable(self.uri, storage_options=self.storage_options):
                raise

    def exists(self) -> bool:
        """True when the table has a log (a local log folder holding any commit file counts)."""
        from deltalake import DeltaTable

        if self.local:
            log_dir = Path(self.uri) / LOG_DIR
            return log_dir.is_dir() and any(COMMIT_RE.fullmatch(p.name) for p in log_dir.iterdir())
        return DeltaTable.is_deltatable(self.uri, storage_options=self.storage_options)

    def refresh(self, check: bool = True) -> int:
        """Latest version (-1 when there is no table yet); `check` raises HistoryLost on a log gap."""
        dt = self._open(create=False)
        if dt is None:
            return -1
        self._guard(dt.update_incremental)
        v = dt.version()
        if check and v > self._checked:
            problems = self.log_problems(upto=v, start=self._checked + 1)
            if problems:
                raise HistoryLost(f"{self.uri}: {problems[0]}; run `vid2sim registry verify`")
            self._checked = v
        return v

    @property
    def version(self) -> int:
        return self.refresh()

    def log_problems(self, upto: Optional[int] = None, start: int = 0, deep: bool = False) -> list[str]:
        """Gaps, empty or (with `deep`) unparsable commit files in the log, and missing data files.

        Local tables and object stores alike (on a store: one listing of the log, plus, with `deep`,
        a read of each commit file and a lookup of each data file). `upto` defaults to the newest file.
        """
        fs, log_dir = self._log_fs()
        listing = fs.get_file_info(pafs.FileSelector(log_dir, allow_not_found=True))
        found = {int(m.group(1)): info for info in listing
                 if info.type == pafs.FileType.File and (m := COMMIT_RE.fullmatch(info.base_name))}
        last = max(found, default=-1) if upto is None else upto
        problems = [f"manifest log version {v} is missing (history has a gap)"
                    for v in range(start, last + 1) if v not in found]
        for v in range(start, last + 1):
            info = found.get(v)
            if info is not None and (info.size == 0 or (deep and not _parses(fs, info.path))):
                kind = "empty (0 bytes)" if info.size == 0 else "not valid JSON lines"
                problems.append(f"manifest log version {v} is {kind}: the commit it held is lost")
        if not problems and self._dt is not None and (self.local or deep):
            problems += [f"manifest data file {u} is missing" for u in self._dt.file_uris()
                         if not self._data_file_exists(fs, u)]
        return problems

    def _log_fs(self) -> tuple[pafs.FileSystem, str]:
        """(filesystem, path of the `_delta_log` folder): the local disk, or the table's store."""
        if self.local:
            return pafs.LocalFileSystem(), str(Path(self.uri).resolve() / LOG_DIR)
        if self._fs is None:
            self._fs = arrow_filesystem(self.uri)
        fs, base = self._fs
        return fs, f"{base.rstrip('/')}/{LOG_DIR}"

    def _data_file_exists(self, fs: pafs.FileSystem, uri: str) -> bool:
        if self.local:
            return Path(uri.removeprefix("file://")).is_file()
        path = uri.split("://", 1)[1] if "://" in uri else uri
        return fs.get_file_info(path).type == pafs.FileType.File

    # -- reads
    def read(self, as_of: AsOf = None, check: bool = True) -> tuple[int, pa.Table]:
        """(registry version, all rows) at the latest version or `as_of`."""
        from deltalake import DeltaTable

        as_of = parse_as_of(as_of)
        if as_of is None:
            v = self.refresh(check)
            if v < 0:
                return v, MANIFEST_SCHEMA.empty_table()
            if self._cache is None or self._cache[0] != v:
                self._cache = (v, self._guard(lambda: self._to_arrow(self._dt)))
            return self._cache
        # time travel runs the latest read's checks first: a gap or an emptied entry anywhere in
        # the log is lost history (HistoryLost), never a silently shorter past
        latest = self.refresh(check)
        if latest < 0:
            raise ValueError(f"as-of {as_of!s}: the registry has no versions yet")
        if isinstance(as_of, int) and not 0 <= as_of <= latest:
            raise ValueError(f"as-of {as_of}: no such registry version (latest is {latest})")
        dt = self._guard(lambda: DeltaTable(self.uri, storage_options=self.storage_options))
        try:
            dt.load_as_version(as_of)
        except Exception as e:
            raise ValueError(f"as-of {as_of!s}: no such registry version or time ({e})") from None
        try:
            return dt.version(), self._to_arrow(dt)
        except (OSError, HistoryLost) as e:  # its data files were vacuumed
            raise ValueError(f"as-of {as_of!s}: registry version {dt.version()} is no longer readable "
                             f"(files removed by vacuum: {e})") from None

    def _to_arrow(self, dt) -> pa.Table:
        if self.local:  # a missing data file aborts the process inside delta-rs: check first
            gone = [u for u in dt.file_uris() if not Path(u.removeprefix("file://")).is_file()]
            if gone:
                raise HistoryLost(f"{self.uri}: manifest data file {gone[0]} is missing "
                                  f"({len(gone)} in all); run `vid2sim registry verify`")
        t = dt.to_pyarrow_table()
        return t.select(MANIFEST_SCHEMA.names).cast(MANIFEST_SCHEMA)

    def history(self) -> list[dict]:
        return self._open().history()

    # -- writes
    def commit(self, build: Callable[[int, pa.Table], Optional[list[dict]]], *, max_attempts: int = 400,
               operation: str = "append", create: bool = True) -> tuple[Optional[int], Optional[list[dict]]]:
        """Append the rows `build(version, rows)` returns, rebuilding on conflict.

        Returns (committed registry version, rows) or (None, None) when `build` returned None
        (nothing to do at that snapshot). Without `create`, a missing table is RegistryNotFound.
        """
        from deltalake import CommitProperties, write_deltalake
        from deltalake.exceptions import CommitFailedError

        if self._open(create=create) is None:
            raise RegistryNotFound(f"no registry at {self.uri.removesuffix('/manifests')} (no manifest log; "
                                   f"`registry add` creates one)")
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
            except CommitFailedError:
                time.sleep(random.uniform(0, min(0.5, 0.005 * 2 ** min(attempt, 7))))
                continue
            self.maybe_compact()
            return v + 1, rows
        raise CommitConflict(f"{self.uri}: gave up after {max_attempts} conflicting commits")

    def append_bulk(self, rows: list[dict]) -> int:
        """Blind append (no conflict check): for benchmarks and imports of pre-built rows."""
        from deltalake import write_deltalake

        self._open()
        write_deltalake(self._dt, pa.Table.from_pylist(rows, schema=MANIFEST_SCHEMA), mode="append",
                        storage_options=self.storage_options)
        self.maybe_compact()
        return self.refresh()

    # -- maintenance
    def num_files(self) -> int:
        """Active Parquet files in the snapshot this handle holds."""
        return len(self._open().file_uris())

    def maybe_compact(self) -> Optional[dict]:
        """Compact + checkpoint when more than `auto_compact_files` files are active; never raises.

        Returns the compaction metrics, or None when under the threshold or when it failed (e.g. a
        concurrent compactor won the race: logged, the next commit over the threshold tries again).
        """
        if self.auto_compact_files <= 0 or self.num_files() <= self.auto_compact_files:
            return None
        from deltalake.exceptions import CommitFailedError

        t = time.perf_counter()
        try:
            metrics = self.compact()
        except CommitFailedError as e:  # a concurrent commit won: fine, the next commit retries
            log.info("%s: automatic compaction lost a race, skipped (%s)", self.uri, e)
            return None
        except Exception as e:  # maintenance must never fail the commit that already landed
            log.warning("%s: automatic compaction failed, skipped (%s: %s)", self.uri, type(e).__name__, e)
            self._dt = None
            return None
        if metrics["numFilesRemoved"]:
            log.info("%s: auto-compacted %d files -> %d in %.2f s", self.uri, metrics["numFilesRemoved"],
                     metrics["numFilesAdded"], time.perf_counter() - t)
        return metrics

    def compact(self) -> dict:
        """Rewrite the snapshot's rows into one file + checkpoint (rows and time travel unchanged).

        Committed like our appends (exactly V+1, `max_commit_retries=0`): an overwrite of the rows
        read at V, so a concurrent commit makes it fail with CommitFailedError rather than rebase.
        Not delta-rs `optimize.compact()`: 1.6 rebases a compaction over a concurrent compaction of
        the same files (dataChange=false removes are not treated as conflicts, whatever
        max_commit_retries says), which leaves both outputs active and duplicates every row.
        The replaced files are only tombstoned, never deleted here (see `vacuum`).
        """
        from deltalake import CommitProperties, write_deltalake

        v, table = self.read()
        before = len(self._dt.file_uris())
        if before <= 1:
            return {"numFilesRemoved": 0, "numFilesAdded": 0, "version": v}
        write_deltalake(self._dt, table, mode="overwrite", storage_options=self.storage_options,
                        commit_properties=CommitProperties(
                            max_commit_retries=0, custom_metadata={"vid2sim.operation": "compact"}))
        if self._dt.version() == v + 1:
            self._cache = (v + 1, table)  # same rows
        self._dt.create_checkpoint()
        return {"numFilesRemoved": before, "numFilesAdded": len(self._dt.file_uris()), "version": v + 1}

    def vacuum(self, retention_hours: int, dry_run: bool = False, full: bool = False) -> list[str]:
        """Delete data files tombstoned (by compaction) more than `retention_hours` ago.

        Explicit only: afterwards, time travel to versions older than the retention window fails.
        `full` also deletes untracked files (left by killed writers/compactors) older than the window;
        it needs >= MIN_FULL_VACUUM_HOURS so an in-flight writer's not-yet-committed file survives.
        Returns the removed (or, with dry_run, removable) file names.
        """
        if retention_hours < 0 or (full and retention_hours < MIN_FULL_VACUUM_HOURS):
            raise ValueError(f"vacuum retention_hours={retention_hours}: must be >= "
                             f"{MIN_FULL_VACUUM_HOURS if full else 0}{' with full' if full else ''}")
        return self._open().vacuum(retention_hours=int(retention_hours), dry_run=dry_run,
                                   enforce_retention_duration=False, full=full)


def _parses(fs: pafs.FileSystem, path: str) -> bool:
    try:
        with fs.open_input_stream(path) as f:
            text = f.read().decode()
        return all(json.loads(line) is not None for line in text.splitlines() if line.strip())
    except (ValueError, UnicodeDecodeError):
        return False


def now_utc() -> datetime:
    return datetime.now(timezone.utc)
