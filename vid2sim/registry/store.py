"""`Registry`: scene bundles in content-addressed blobs + a Delta Lake manifest.

Layout under the root (a local folder, `file://` URI, or object-store URI):
  blobs/ab/cdef...   artifact contents keyed by sha256 (blobs/tmp/ holds in-flight writes)
  manifests/         Delta table, one row per scene version (see manifest.MANIFEST_SCHEMA)

`add` stores every blob BEFORE committing the manifest row, so a row never points at a missing
blob; a writer killed mid-way leaves at most unreferenced blobs, which `gc` removes. `gc` is
safe beside running adds at any grace period, 0 included (see `Registry.gc`).

The manifest compacts itself (see `RegistryConfig.auto_compact_files` and manifest.py); nothing
is ever deleted from it without an explicit `compact(vacuum_hours=...)`, so time travel to any
version keeps working until then.

Roots: a plain path or `file://` URI (tested), or an object-store URI (s3://, gs://, az://...):
blobs then go through pyarrow/fsspec filesystems and the manifest through delta-rs with
`storage_options`. On S3, concurrent commits are made safe by delta-rs's conditional put
(`conditional_put=etag`, set by default; see manifest.safe_storage_options). `memory://` works
for the blob store but not for the manifest (delta-rs's in-memory store is private to one table
handle).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence
from urllib.parse import urlparse

import pyarrow as pa

from vid2sim.ranges import checked
from vid2sim.registry.blobs import (ArrowBlobStore, BlobStore, LocalBlobStore, arrow_filesystem,
                                    name_owner, owner, process_state, sha256_file, temp_in_use)
from vid2sim.formats.bundle import BundleInfo, validate_bundle
from vid2sim.formats.scene import SCENE_JSON, TAG_RE, check_scene_id
from vid2sim.registry.errors import BadGracePeriod, HistoryLost, RegistryError, RegistryNotFound, SceneNotFound
from vid2sim.registry.manifest import MIN_FULL_VACUUM_HOURS, AsOf, ManifestTable, now_utc
from vid2sim.registry.query import QueryError, QueryLimits, run_query
from vid2sim.registry.redact import redact_uri
from vid2sim.registry.records import (ACTIVE, DEPRECATED, Artifact, SceneRecord, content_hash, latest_rows,
                                      records)
from vid2sim.registry.split import Split, SplitConfig, make_split

DEFAULT_ROOT = "./vid2sim-registry"
CHECKOUT_MARKER = ".vid2sim-checkout.json"
GC_GRACE_S = 3600.0
# leftovers whose writer gc cannot check (another machine, or files that record no owner) are
# kept at least this long whatever the grace period: the writer may still be running
UNKNOWN_OWNER_GRACE_S = 3600.0
_IN_FLIGHT: set[str] = set()  # intents of adds running in this process (process_state "self")
_TRASHING: set[str] = set()  # trash files a gc running in this process has not decided on yet


@dataclass(frozen=True)
class AddResult:
    """What `add_result` did: the scene version, and whether the call committed nothing."""

    record: SceneRecord
    noop: bool


@checked
@dataclass(frozen=True)
class RegistryConfig:
    """Registry knobs (defaults suit thousands of scenes on a local disk or object store)."""

    # after a commit, merge the manifest's Parquet files + checkpoint when more than this many are
    # active (one file per commit: ~every 50 commits); 0 = only on explicit `compact`
    auto_compact_files: int = 50


MANIFEST_SCHEMES = ("s3", "s3a", "gs", "gcs", "az", "abfs", "abfss", "azure", "adl")  # object stores delta-rs opens


def default_root() -> str:
    return os.environ.get("VID2SIM_REGISTRY") or DEFAULT_ROOT


def parse_ref(ref: str) -> tuple[str, Optional[int]]:
    """'scene' or 'scene@3' -> (scene_id, version or None)."""
    scene, _, ver = ref.partition("@")
    if ver and not ver.isdigit():
        raise RegistryError(f"{ref}: version after '@' must be a number")
    return scene, int(ver) if ver else None


def _refs(table: pa.Table) -> set[str]:
    return {a["sha256"] for arts in table.column("artifacts").to_pylist() for a in arts}


def _check_grace(grace_s: float) -> float:
    try:
        g = float(grace_s)
    except (TypeError, ValueError):
        raise BadGracePeriod(f"gc grace period {grace_s!r}: not a number of seconds") from None
    if math.isnan(g) or g < 0:
        raise BadGracePeriod(f"gc grace period {grace_s!r}: must be a number of seconds >= 0")
    return g



def _checkout_marker(folder: Path) -> Optional[dict]:
    """What a checkout folder's marker says it holds: None without a marker, {} for an unreadable one."""
    marker = folder / CHECKOUT_MARKER
    if not marker.is_file():
        return None
    try:
        done = json.loads(marker.read_text())
    except (ValueError, UnicodeDecodeError, OSError):
        return {}
    return done if isinstance(done, dict) else {}


def _checkout_owner(done: Optional[dict], rec: SceneRecord, root: str) -> str:
    """What a checkout folder's marker says it holds, for the error refusing to overwrite it."""
    if not done:
        return ""
    return (f" ({done.get('ref', '?')} content {str(done.get('content_hash', '?'))[:12]} from registry "
            f"{done.get('registry', '?')}; wanted {rec.ref} content {rec.content_hash[:12]} from {root}:"
            " check it out under another folder)")


def _stale_checkout(done: Optional[dict], rec: SceneRecord, root: str) -> bool:
    """Whether a checkout folder holds what this registry root once checked out as the same
    scene version with other content: a version's content never changes within a registry, so
    the registry at that place was made anew (e.g. deleted and ingested again)."""
    return bool(done) and done.get("registry") == root and done.get("ref") == rec.ref \
        and done.get("content_hash") != rec.content_hash


def _set_aside(folder: Path) -> None:
    """Remove a stale checkout folder: renamed out of the way first (one rename, so the new
    checkout can take its place at once), then deleted."""
    if not folder.exists():
        return
    aside = folder.parent / f".{folder.name}.stale-{uuid.uuid4().hex}"
    os.replace(folder, aside)
    shutil.rmtree(aside, ignore_errors=True)


def _check_name(name: str) -> str:
    p = Path(name)
    if not name or p.is_absolute() or ".." in p.parts:
        raise RegistryError(f"unsafe artifact name {name!r}")
    return name


class Registry:
    """Versioned store of scene bundles (see module docstring)."""

    def __init__(self, root: str | os.PathLike | None = None, storage_options: Optional[dict] = None,
                 config: Optional[RegistryConfig] = None) -> None:
        self.config = config or RegistryConfig()
        root = str(root) if root is not None else default_root()
        parsed = urlparse(root)
        if parsed.scheme in ("", "file") or len(parsed.scheme) == 1:  # plain path / file:// / C:\
            local = Path(parsed.path if parsed.scheme == "file" else root).expanduser().resolve()
            self.root = str(local)
            self.blobs: BlobStore = LocalBlobStore(local / "blobs")
            table_uri = str(local / "manifests")
        else:
            self.root = root.rstrip("/")
            if parsed.scheme not in MANIFEST_SCHEMES:
                raise RegistryError(f"{root}: a registry cannot live on {parsed.scheme}:// (the manifest needs a "
                                    f"folder or one of {', '.join(s + '://' for s in MANIFEST_SCHEMES)})")
            try:
                fs, base = arrow_filesystem(self.root)
            except (ImportError, OSError, ValueError) as e:
                raise RegistryError(f"{root}: cannot open the registry's store ({e})") from None
            self.blobs = ArrowBlobStore(fs, f"{base.rstrip('/')}/blobs")
            table_uri = f"{self.root}/manifests"
        self.manifest = ManifestTable(table_uri, storage_options, auto_compact_files=self.config.auto_compact_files)
        self._latest_cache: Optional[tuple[int, list[SceneRecord]]] = None

    def __repr__(self) -> str:
        return f"Registry({self.root!r})"

    # ------------------------------------------------------------------ reads
    @property
    def version(self) -> int:
        """Registry version = Delta table version (one per commit)."""
        return self.manifest.version

    def _rows(self, as_of: AsOf = None, check: bool = True) -> tuple[int, pa.Table]:
        """(version, all rows); a mistyped root or a lost log raise instead of reading as empty."""
        self._check_root()
        if not self.manifest.exists():
            self._check_missing_log()
        return self.manifest.read(as_of, check)

    def _local_root(self) -> Optional[Path]:
        return Path(self.root) if isinstance(self.blobs, LocalBlobStore) else None

    def _check_root(self) -> None:
        local = self._local_root()
        if local is not None and local.exists() and not local.is_dir():
            raise RegistryError(f"{local}: is a file, not a registry folder")

    def _check_missing_log(self, write: bool = False) -> None:
        """No manifest log: fine for a new registry, an error beside stored blobs (or, for reads, at no path)."""
        local = self._local_root()
        if local is not None and not local.exists():
            if write:
                return
            raise RegistryNotFound(f"no registry at {local} (nothing there; `registry add` creates one)")
        orphans = self._unaccounted(set())
        if orphans:
            raise HistoryLost(f"{self.root}: the manifest log is missing but the blob store holds "
                              f"{len(orphans)} blob(s): the registry has lost its history "
                              f"(`gc` refuses to delete them without --force)")
        if not write:  # a registry is recognised by its manifest log, not by a folder existing
            raise RegistryNotFound(f"no registry at {self.root} (no manifest log under manifests/; "
                                   f"`registry add` creates one)")

    def require(self) -> "Registry":
        """This registry; RegistryNotFound / HistoryLost when the root holds none (creates nothing)."""
        self._require_registry()
        return self

    def _require_registry(self) -> None:
        """RegistryNotFound / HistoryLost unless the root holds a registry (never creates one)."""
        self._check_root()
        if not self.manifest.exists():
            self._check_missing_log()

    def _check_writable(self) -> None:
        """Refuse to commit on top of lost history (a missing or gapped log)."""
        self._check_root()
        if not self.manifest.exists():
            self._check_missing_log(write=True)
        else:
            self.manifest.refresh(check=True)

    def list(self, as_of: AsOf = None, include_deprecated: bool = False) -> list[SceneRecord]:
        """Latest version of every scene (optionally at an older registry version/time)."""
        recs = self._latest(as_of)
        return recs if include_deprecated else [r for r in recs if r.status == ACTIVE]

    def _latest(self, as_of: AsOf = None) -> list[SceneRecord]:
        """Latest record of every scene (cached per registry version for the live table)."""
        v, table = self._rows(as_of)
        if as_of is None and self._latest_cache is not None and self._latest_cache[0] == v:
            return list(self._latest_cache[1])
        recs = records(latest_rows(table))
        if as_of is None:
            self._latest_cache = (v, recs)
        return list(recs)

    def show(self, scene_id: str, version: Optional[int] = None, as_of: AsOf = None) -> SceneRecord:
        hist = self.history(scene_id, as_of=as_of)
        if version is None:
            return hist[-1]
        for r in hist:
            if r.version == version:
                return r
        raise SceneNotFound(f"{scene_id}@{version}: no such version (latest is {hist[-1].version})")

    def history(self, scene_id: Optional[str] = None, as_of: AsOf = None) -> list[SceneRecord]:
        """All versions (of one scene, by version; or of all, in commit-time order)."""
        import pyarrow.compute as pc

        _, table = self._rows(as_of)
        if scene_id is not None:
            table = table.filter(pc.equal(table["scene_id"], scene_id))
            if table.num_rows == 0:
                raise SceneNotFound(f"{scene_id}: no such scene in registry {self.root}")
            return records(table.sort_by("version"))
        return records(table.sort_by([("created_at", "ascending"), ("scene_id", "ascending"),
                                      ("version", "ascending")]))

    def query(self, sql: str, as_of: AsOf = None, limits: QueryLimits = QueryLimits()) -> pa.Table:
        """Read-only DuckDB SQL over `scenes` (all versions) and `latest`; errors past `max_rows`."""
        table, more = self.query_head(sql, as_of, limits)
        if more:
            raise QueryError(f"query returned more than {limits.max_rows} rows: add a LIMIT or aggregate")
        return table

    def query_head(self, sql: str, as_of: AsOf = None, limits: QueryLimits = QueryLimits()
                   ) -> tuple[pa.Table, bool]:
        """(first `limits.max_rows` rows, whether there were more); see `vid2sim.registry.query`."""
        return run_query(self._rows(as_of)[1], sql, limits)

    def split(self, seed: int = 0, test_fraction: float = 0.2, test_groups: Optional[Sequence[str]] = None,
              train_sizes: Sequence[int] = (), tags: Sequence[str] = (),
              min_metrics: Optional[dict[str, float]] = None, as_of: AsOf = None) -> Split:
        """Deterministic, leak-free (by source group) split of the latest active scenes."""
        conf = SplitConfig(seed=seed, test_fraction=test_fraction,
                           test_groups=tuple(test_groups) if test_groups is not None else None,
                           train_sizes=tuple(train_sizes), tags=tuple(tags), min_metrics=dict(min_metrics or {}))
        v = self._rows(as_of)[0]
        return make_split(self._latest(as_of), conf, v)

    # ------------------------------------------------------------------ add
    def _store_blobs(self, info: BundleInfo, intent: Optional[str] = None) -> tuple[list[Artifact], str]:
        """Write an intent naming the blobs (and this process), then store them (a bad stored
        copy is rewritten)."""
        arts = [Artifact(_check_name(name), *sha256_file(path)) for name, path in sorted(info.artifacts.items())]
        intent = intent or uuid.uuid4().hex
        self.blobs.write_intent(intent, {"scene_id": info.scene_id, "blobs": [a.sha256 for a in arts],
                                         "created": time.time(), "owner": owner()})
        for a in arts:
            self.blobs.put_file(info.artifacts[a.name], a.sha256)
        return arts, intent

    def add(self, bundle_dir: str | os.PathLike) -> SceneRecord:
        """Validate, store blobs, commit a new scene version (no-op for identical content)."""
        return self.add_result(bundle_dir).record

    def add_result(self, bundle_dir: str | os.PathLike) -> AddResult:
        """`add`, also saying whether this call committed (`noop` is False only if it did)."""
        info = validate_bundle(bundle_dir)
        uri = info.scene["source"]["uri"]
        if redact_uri(uri) != uri:  # scene.json is stored as it is: nothing that may be a credential
            raise RegistryError(f"{info.scene_id}: scene.json source.uri carries user info, a fragment or query "
                                f"parameters outside the allow-list (possible credentials); write its redacted "
                                f"form {redact_uri(uri)!r} (vid2sim.registry.redact)")
        self._check_writable()
        intent = uuid.uuid4().hex
        _IN_FLIGHT.add(intent)  # before the intent exists: a gc in this process honours it
        try:
            return self._add(info, intent)
        finally:
            _IN_FLIGHT.discard(intent)

    def _add(self, info: BundleInfo, intent: str) -> AddResult:
        arts, intent = self._store_blobs(info, intent)
        chash = content_hash(arts)
        scene, src = info.scene, info.scene["source"]
        result: dict = {}

        def build(v: int, table: pa.Table) -> Optional[list[dict]]:
            prev = self._latest_in(table, info.scene_id)
            if prev is not None and prev.content_hash == chash and prev.status == ACTIVE:
                result["rec"] = prev
                return None
            rec = SceneRecord(
                scene_id=info.scene_id, version=(prev.version + 1) if prev else 1, status=ACTIVE, event="add",
                message=None, created_at=now_utc(), source_uri=src["uri"], source_sha256=src["sha256"],
                clip_start_s=float(src["clip_start_s"]), clip_end_s=float(src["clip_end_s"]),
                source_group=src["group"], num_frames=info.frame_counts["all"],
                num_train_frames=info.frame_counts["train"], num_test_frames=info.frame_counts["test"],
                num_splats=info.num_splats, metrics=scene["metrics"], bounds=info.bounds,
                mesh_bounds=info.mesh_bounds, walkable_area_m2=info.walkable_area_m2,
                tags=tuple(sorted(set(scene["tags"]) | set(prev.tags if prev else ()))),
                pipeline_hash=scene["pipeline"]["config_hash"], code_version=scene["pipeline"]["code_version"],
                content_hash=chash, artifacts=tuple(arts))
            result["rec"] = rec
            return [rec.to_row()]

        committed, _ = self.manifest.commit(build, operation=f"add {info.scene_id}")
        self._repair_blobs(info, arts)
        self.blobs.delete_intent(intent)
        return AddResult(result["rec"], noop=committed is None)

    def _repair_blobs(self, info: BundleInfo, arts: list[Artifact]) -> None:
        """Re-store any blob a concurrent `gc` removed between our write and our commit."""
        for a in arts:
            if not self.blobs.exists(a.sha256):
                self.blobs.put_file(info.artifacts[a.name], a.sha256)

    @staticmethod
    def _latest_in(table: pa.Table, scene_id: str) -> Optional[SceneRecord]:
        import pyarrow.compute as pc

        rows = table.filter(pc.equal(table["scene_id"], scene_id))
        if rows.num_rows == 0:
            return None
        return SceneRecord.from_row(rows.sort_by([("version", "descending")]).slice(0, 1).to_pylist()[0])

    # ------------------------------------------------------------------ mutations (append a new version)
    def _mutate(self, scene_id: str, event: str, change) -> SceneRecord:
        self._require_registry()  # tag/untag/deprecate never create a registry (only add does)
        result: dict = {}

        def build(v: int, table: pa.Table) -> Optional[list[dict]]:
            prev = self._latest_in(table, scene_id)
            if prev is None:
                raise SceneNotFound(f"{scene_id}: no such scene in registry {self.root}")
            fields = change(prev)
            if fields is None:
                result["rec"] = prev
                return None
            rec = prev.evolve(version=prev.version + 1, event=event, created_at=now_utc(), **fields)
            result["rec"] = rec
            return [rec.to_row()]

        self.manifest.commit(build, operation=f"{event} {scene_id}", create=False)
        return result["rec"]

    def tag(self, scene_id: str, *tags: str) -> SceneRecord:
        bad = [t for t in tags if not TAG_RE.fullmatch(t)]
        if bad or not tags:
            raise RegistryError(f"invalid tag(s) {bad or list(tags)}: must match {TAG_RE.pattern}")

        def change(prev: SceneRecord):
            new = tuple(sorted(set(prev.tags) | set(tags)))
            return None if new == prev.tags else {"tags": new, "message": None}

        return self._mutate(scene_id, "tag", change)

    def untag(self, scene_id: str, *tags: str) -> SceneRecord:
        def change(prev: SceneRecord):
            new = tuple(t for t in prev.tags if t not in set(tags))
            return None if new == prev.tags else {"tags": new, "message": None}

        return self._mutate(scene_id, "untag", change)

    def deprecate(self, scene_id: str, reason: str) -> SceneRecord:
        if not reason or not reason.strip():
            raise RegistryError(f"{scene_id}: a deprecation reason is required")

        def change(prev: SceneRecord):
            return None if prev.status == DEPRECATED else {"status": DEPRECATED, "message": reason}

        return self._mutate(scene_id, "deprecate", change)

    # ------------------------------------------------------------------ integrity
    def verify(self) -> list[str]:
        """Problems: log gaps / damage, missing or corrupt referenced blobs, blobs nothing accounts for."""
        problems = self.manifest.log_problems(deep=True)
        try:
            _, table = self._rows(check=False)
        except HistoryLost as e:
            return list(dict.fromkeys(problems + [str(e)]))
        problems += [p for p, _ in self._blob_problems(table)]
        orphans = self._unaccounted(_refs(table))
        if orphans:
            problems.append(f"{len(orphans)} stored blob(s) referenced by no manifest row and no add in "
                            f"flight (lost history?): {', '.join(orphans[:3])}{' ...' if len(orphans) > 3 else ''}"
                            f"; `gc` keeps them unless --force")
        return list(dict.fromkeys(problems))

    def _blob_problems(self, table: pa.Table) -> list[tuple[str, str]]:
        """(problem, sha256) for every referenced blob that is missing or does not hash to its name."""
        users: dict[str, list[str]] = {}
        sizes: dict[str, int] = {}
        for r in table.select(["scene_id", "version", "artifacts"]).to_pylist():
            for a in r["artifacts"]:
                users.setdefault(a["sha256"], []).append(f"{r['scene_id']}@{r['version']}:{a['name']}")
                sizes[a["sha256"]] = a["size"]
        problems = []
        trashed: Optional[set[str]] = None
        for sha, who in sorted(users.items()):
            where = ", ".join(who[:3]) + (f" (+{len(who) - 3} more)" if len(who) > 3 else "")
            try:
                got, size = self.blobs.rehash(sha)
            except (FileNotFoundError, OSError):
                if trashed is None:
                    trashed = {t.sha256 for t in self.blobs.trashed()}
                hint = (" (a copy waits in blobs/trash/: a gc was interrupted or is running; the next "
                        "`vid2sim registry gc` puts it back)" if sha in trashed else "")
                problems.append((f"missing blob {sha} for {where}{hint}", sha))
                continue
            if got != sha or size != sizes[sha]:
                problems.append((f"corrupt blob {sha} (content hashes to {got}, {size} bytes) for {where}", sha))
        return problems

    def repair(self, sources: Sequence[str | os.PathLike]) -> list[str]:
        """Rewrite missing or corrupt referenced blobs from files under `sources` (bundle folders).

        A file is used only when its size and sha256 match the blob's. Returns what was repaired.
        """
        _, table = self._rows()
        sizes = {a["sha256"]: a["size"] for arts in table.column("artifacts").to_pylist() for a in arts}
        bad = {sha for _, sha in self._blob_problems(table)}
        by_size: dict[int, set[str]] = {}
        for sha in bad:
            by_size.setdefault(sizes[sha], set()).add(sha)
        done = []
        for src in sources:
            if not Path(src).is_dir():
                raise RegistryError(f"--from {src}: not a folder")
            for f in sorted(p for p in Path(src).rglob("*") if p.is_file()):
                if bad and f.stat().st_size in by_size:
                    sha = sha256_file(f)[0]
                    if sha in bad:
                        self.blobs.put_file(f, sha)
                        bad.discard(sha)
                        done.append(f"repaired blob {sha} from {f}")
        return done

    def referenced(self, check: bool = True) -> set[str]:
        return _refs(self._rows(check=check)[1])

    def _pending(self) -> tuple[dict[str, float], dict[str, float]]:
        """Intents of adds in flight: (sha -> newest intent mtime, intent name -> mtime)."""
        shas: dict[str, float] = {}
        names = {}
        for name, data, mtime in self.blobs.intents():
            names[name] = mtime
            for sha in data.get("blobs", []):
                shas[sha] = max(mtime, shas.get(sha, 0.0))
        return shas, names

    def _unaccounted(self, refs: set[str], cutoff: Optional[float] = None) -> list[str]:
        """Stored blobs (older than `cutoff`) that no row in `refs` and no add intent accounts for.

        Candidates are re-checked against fresh intents and rows: an add that started after the
        first look has written its intent before its blobs, and removes it only after its commit.
        """
        pending = self._pending()[0]
        cand = [b.sha256 for b in self.blobs.list() if not b.is_temp and b.sha256 not in refs
                and b.sha256 not in pending and (cutoff is None or b.mtime <= cutoff)]
        if not cand:
            return []
        pending = self._pending()[0]
        now_refs = _refs(self.manifest.read(check=False)[1]) if self.manifest.exists() else set()
        return sorted(c for c in cand if c not in pending and c not in now_refs)

    def gc(self, grace_s: float = GC_GRACE_S, dry_run: bool = False, force: bool = False) -> list[str]:
        """Delete blobs of adds that never committed, and stale temp files, older than `grace_s`.

        Safe beside running adds and other gcs at any grace period (0 included):
        - the adds' intents are read first, then the manifest rows, then the blob listing; a blob
          goes only when no row references it, no running add's intent names it (an add whose
          process is alive on this machine is protected whatever its age; one from another
          machine for at least UNKNOWN_OWNER_GRACE_S) and its mtime is older than the cutoff;
        - such a blob is first moved to the trash; then the intents and the rows are read again
          (an add that started after the first read, a commit after it) and the mtime compared
          (an add re-storing identical bytes touches it): anything that now needs it is restored;
        - a temp file goes only when its writer is known to be dead (or, recording no owner,
          after UNKNOWN_OWNER_GRACE_S); an add never loses its temp file.
        Refuses (HistoryLost) when the log has a gap or when blobs exist that neither a manifest
        row nor an add's intent accounts for, since that means lost history; `force` deletes
        every unreferenced blob anyway. Returns what it removed (or would remove).
        """
        grace_s = _check_grace(grace_s)
        if not force:
            bad = self.manifest.log_problems(deep=True)
            if bad:
                raise HistoryLost(f"gc refused: {bad[0]}; run `vid2sim registry verify` (--force deletes anyway)")
        start = time.time()
        cutoff = start - grace_s
        if not dry_run:
            self._recover_trash()
        intents = self.blobs.intents()  # (1) before the rows: an add not seen here stores after it
        guarded = self._guarded(intents, start, grace_s)
        try:
            refs = self.referenced(check=not force)  # (2)
        except HistoryLost:
            if not force:
                raise
            refs = set()
        orphans = self._unaccounted(refs, cutoff)
        if orphans and not force:
            raise HistoryLost(f"gc refused: {len(orphans)} blob(s) are referenced by no manifest row and no add "
                              f"in flight, so the manifest may have lost history; run `vid2sim registry verify` "
                              f"(--force deletes them)")
        listing = list(self.blobs.list())  # (3)
        cands = {b.sha256: b.mtime for b in listing
                 if not b.is_temp and b.sha256 not in refs and b.sha256 not in guarded and b.mtime <= cutoff}
        temps = [b for b in listing if b.is_temp and self._stale_temp(b.sha256, b.mtime, start, grace_s)]
        if dry_run:
            return sorted(cands) + [f"tmp/{b.sha256}" for b in temps]
        gone: set[str] = set()
        pending: list = []
        try:
            for sha in sorted(cands):
                t = self.blobs.trash(sha)
                if t is not None:
                    pending.append(t)
                    _TRASHING.add(t.name)
            if pending:  # (4) what started to need them after (1)-(3)
                guarded |= self._guarded(self.blobs.intents(), start, grace_s)
                refs |= _refs(self.manifest.read(check=False)[1]) if self.manifest.exists() else set()
            while pending:
                t = pending[0]
                touched = t.mtime is not None and t.mtime != cands[t.sha256]
                if touched or t.sha256 in guarded or t.sha256 in refs:
                    self.blobs.restore(t)
                else:
                    self.blobs.purge(t)
                    gone.add(t.sha256)
                pending.pop(0)
                _TRASHING.discard(t.name)
        finally:
            for t in pending:  # interrupted (an error, Ctrl-C): undecided blobs go back
                self.blobs.restore(t)
                _TRASHING.discard(t.name)
        for b in temps:
            if not temp_in_use(b.sha256):  # (re-checked: the writer may be this process)
                self.blobs.delete(b)
        left = {b.sha256 for b in listing if not b.is_temp} - gone - refs
        for name, data, mtime in intents:
            if not self._guards(name, data, mtime, start, grace_s) and not set(data.get("blobs", [])) & left:
                self.blobs.delete_intent(name)  # its writer is gone and so are its blobs
        return sorted(gone) + [f"tmp/{b.sha256}" for b in temps]

    @staticmethod
    def _guards(name: str, data: dict, mtime: float, start: float, grace_s: float) -> bool:
        """Whether an add's intent still protects its blobs (see `gc`)."""
        own = data.get("owner") or {}
        state = process_state(own.get("host"), own.get("pid"))
        if state == "alive":
            return True
        if state == "self":
            return name in _IN_FLIGHT
        if state == "dead":
            return mtime > start - grace_s
        return mtime > start - max(grace_s, UNKNOWN_OWNER_GRACE_S)

    def _guarded(self, intents: list[tuple[str, dict, float]], start: float, grace_s: float) -> set[str]:
        """Blobs named by intents that still protect them."""
        out: set[str] = set()
        for name, data, mtime in intents:
            if self._guards(name, data, mtime, start, grace_s):
                out.update(data.get("blobs", []))
        return out

    @staticmethod
    def _stale_temp(name: str, mtime: float, start: float, grace_s: float) -> bool:
        """A temp file gc may delete: its writer is dead (or unknown and long silent)."""
        state = process_state(*name_owner(name))
        if state in ("alive", "self"):
            return state == "self" and not temp_in_use(name) and mtime <= start - grace_s
        if state == "dead":
            return mtime <= start - grace_s
        return mtime <= start - max(grace_s, UNKNOWN_OWNER_GRACE_S)

    def _recover_trash(self) -> None:
        """Put back blobs a gc that is no longer running left in the trash (it was killed mid-way)."""
        for t in self.blobs.trashed():
            state = process_state(*name_owner(t.name[65:]))
            if state != "alive" and not (state == "self" and t.name in _TRASHING):
                self.blobs.restore(t)

    def compact(self, vacuum_hours: Optional[int] = None, dry_run: bool = False) -> dict:
        """Merge the manifest's small Parquet files + checkpoint; rows and history unchanged.

        With `vacuum_hours`, also delete manifest files that compactions replaced more than that
        many hours ago (and, when >= 1 h, untracked files from killed writers): time travel to
        versions older than that window fails afterwards. Metrics gain "vacuumed": [file names]
        (with `dry_run`: what vacuum would delete; nothing is deleted).
        """
        self._require_registry()
        metrics = self._compact_retrying()  # non-destructive: always runs
        if vacuum_hours is not None:
            metrics["vacuumed"] = self.manifest.vacuum(vacuum_hours, dry_run=dry_run,
                                                       full=vacuum_hours >= MIN_FULL_VACUUM_HOURS)
        return metrics

    def _compact_retrying(self, attempts: int = 20) -> dict:
        import random
        import time

        from deltalake.exceptions import CommitFailedError

        for i in range(attempts):
            try:
                return self.manifest.compact()
            except CommitFailedError:  # a concurrent writer committed first: re-read and retry
                time.sleep(random.uniform(0, min(1.0, 0.01 * 2 ** i)))
        raise RegistryError(f"{self.root}: compaction lost to concurrent commits {attempts} times; retry later")

    # ------------------------------------------------------------------ checkout
    def checkout(self, scene_id: str, version: Optional[int] = None, dest: str | os.PathLike | None = None,
                 as_of: AsOf = None) -> Path:
        """Materialise a bundle folder (hash-verified) for the envs; reuses a finished checkout.

        A finished checkout of the same content is verified before it is handed back: every
        artifact file's size and sha256 against the manifest; a file that is missing or differs
        (edited, truncated, bit rot) is rewritten from its verified blob. Other files in the
        folder are left alone. A checkout that this registry root made of the same scene version
        with other content (the registry was made anew at the same place) is replaced whole; any
        other folder with something in it is refused. dest defaults to
        ./vid2sim-checkouts/<scene_id>@<version>.
        """
        rec = self.show(check_scene_id(scene_id), version, as_of=as_of)
        out = Path(dest) if dest is not None else Path("vid2sim-checkouts") / rec.ref
        if out.exists() and not out.is_dir():
            raise RegistryError(f"{out}: checkout destination is a file, not a folder")
        done = _checkout_marker(out)  # what the folder's marker says it holds
        if done and done.get("content_hash") == rec.content_hash:
            self.refresh_checkout(rec, out)
            return out
        stale = _stale_checkout(done, rec, self.root)
        if out.exists() and any(out.iterdir()) and not stale:
            raise RegistryError(f"{out}: checkout destination exists and holds something else"
                                f"{_checkout_owner(done, rec, self.root)}")
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
        try:
            for a in rec.artifacts:
                target = tmp / _check_name(a.name)
                target.parent.mkdir(parents=True, exist_ok=True)
                try:
                    got, size = self.blobs.copy_to(a.sha256, target)
                except (FileNotFoundError, OSError) as e:
                    raise RegistryError(f"{rec.ref}: artifact {a.name} blob {a.sha256} is missing ({e})") from None
                if got != a.sha256 or size != a.size:
                    raise RegistryError(f"{rec.ref}: artifact {a.name} blob {a.sha256} is corrupt (hashes to {got})")
            (tmp / CHECKOUT_MARKER).write_text(json.dumps({"ref": rec.ref, "content_hash": rec.content_hash,
                                                           "registry": self.root}))
            try:
                if stale:
                    _set_aside(out)
                elif out.exists():
                    out.rmdir()  # an empty folder the caller made
                os.replace(tmp, out)
            except OSError:  # `out` filled meanwhile: another process finished the same checkout?
                done = _checkout_marker(out)
                if not (done and done.get("content_hash") == rec.content_hash):
                    raise RegistryError(f"{out}: checkout destination filled while checking out "
                                        f"{rec.ref}{_checkout_owner(done, rec, self.root)}") from None
                shutil.rmtree(tmp, ignore_errors=True)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return out

    def refresh_checkout(self, rec: SceneRecord, out: Path) -> list[str]:
        """Check each artifact file of checkout `out` (size, then sha256) and rewrite the ones
        that differ from `rec` from their blobs (written beside, then renamed). Returns their names."""
        fixed = []
        for a in rec.artifacts:
            target = out / _check_name(a.name)
            try:
                ok = target.is_file() and target.stat().st_size == a.size and sha256_file(target)[0] == a.sha256
            except OSError:
                ok = False
            if ok:
                continue
            if target.is_dir() and not target.is_symlink():
                shutil.rmtree(target)
            target.parent.mkdir(parents=True, exist_ok=True)
            tmp = target.parent / f".{target.name}.tmp-{uuid.uuid4().hex}"
            try:
                try:
                    got, size = self.blobs.copy_to(a.sha256, tmp)
                except (FileNotFoundError, OSError) as e:
                    raise RegistryError(f"{rec.ref}: artifact {a.name} blob {a.sha256} is missing ({e})") from None
                if got != a.sha256 or size != a.size:
                    raise RegistryError(f"{rec.ref}: artifact {a.name} blob {a.sha256} is corrupt (hashes to {got})")
                os.replace(tmp, target)
            finally:
                tmp.unlink(missing_ok=True)
            fixed.append(a.name)
        return fixed

    def scene_json(self, scene_id: str, version: Optional[int] = None) -> dict:
        """The stored scene.json of a scene version (read from its blob)."""
        rec = self.show(scene_id, version)
        with self.blobs.open(rec.artifact(SCENE_JSON).sha256) as f:
            return json.loads(f.read())
