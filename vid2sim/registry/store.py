"""`Registry`: scene bundles in content-addressed blobs + a Delta Lake manifest.

Layout under the root (a local folder, `file://` URI, or object-store URI):
  blobs/ab/cdef...   artifact contents keyed by sha256 (blobs/tmp/ holds in-flight writes)
  manifests/         Delta table, one row per scene version (see manifest.MANIFEST_SCHEMA)

`add` stores every blob BEFORE committing the manifest row, so a row never points at a missing
blob; a writer killed mid-way leaves at most unreferenced blobs, which `gc` removes.

The manifest compacts itself (see `RegistryConfig.auto_compact_files` and manifest.py); nothing
is ever deleted from it without an explicit `compact(vacuum_hours=...)`, so time travel to any
version keeps working until then.

Roots: a plain path or `file://` URI (tested), or an object-store URI (s3://, gs://, az://...):
blobs then go through pyarrow/fsspec filesystems and the manifest through delta-rs with
`storage_options`. On S3, safe concurrent commits need delta-rs's conditional-put or locking
options. `memory://` works for the blob store but not for the manifest (delta-rs's in-memory
store is private to one table handle).
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence
from urllib.parse import urlparse

import pyarrow as pa

from vid2sim.registry.blobs import ArrowBlobStore, BlobStore, LocalBlobStore, arrow_filesystem, sha256_file
from vid2sim.formats.bundle import BundleInfo, validate_bundle
from vid2sim.formats.scene import SCENE_JSON, TAG_RE, check_scene_id
from vid2sim.registry.manifest import MIN_FULL_VACUUM_HOURS, AsOf, ManifestTable, now_utc
from vid2sim.registry.records import (ACTIVE, DEPRECATED, Artifact, SceneRecord, content_hash, latest_rows,
                                      records)
from vid2sim.registry.split import Split, SplitConfig, make_split

DEFAULT_ROOT = "./vid2sim-registry"
CHECKOUT_MARKER = ".vid2sim-checkout.json"
GC_GRACE_S = 3600.0


@dataclass(frozen=True)
class RegistryConfig:
    """Registry knobs (defaults suit thousands of scenes on a local disk or object store)."""

    # after a commit, merge the manifest's Parquet files + checkpoint when more than this many are
    # active (one file per commit: ~every 50 commits); 0 = only on explicit `compact`
    auto_compact_files: int = 50


class RegistryError(RuntimeError):
    """A registry operation failed; the message names the scene/file and the reason."""


class SceneNotFound(RegistryError, KeyError):
    def __str__(self) -> str:  # KeyError would add quotes
        return str(self.args[0])


def default_root() -> str:
    return os.environ.get("VID2SIM_REGISTRY") or DEFAULT_ROOT


def parse_ref(ref: str) -> tuple[str, Optional[int]]:
    """'scene' or 'scene@3' -> (scene_id, version or None)."""
    scene, _, ver = ref.partition("@")
    if ver and not ver.isdigit():
        raise RegistryError(f"{ref}: version after '@' must be a number")
    return scene, int(ver) if ver else None


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
            fs, base = arrow_filesystem(self.root)
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

    def _rows(self, as_of: AsOf = None) -> tuple[int, pa.Table]:
        return self.manifest.read(as_of)

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

    def query(self, sql: str, as_of: AsOf = None) -> pa.Table:
        """Run DuckDB SQL over the manifest: table `scenes` (all versions) and view `latest`."""
        import duckdb

        _, scenes = self._rows(as_of)
        con = duckdb.connect()
        try:
            con.register("scenes", scenes)
            con.execute("CREATE VIEW latest AS SELECT * FROM scenes "
                        "QUALIFY row_number() OVER (PARTITION BY scene_id ORDER BY version DESC) = 1")
            try:
                rel = con.sql(sql)
                if rel is None:  # a statement without a result
                    return pa.table({})
                fetch = getattr(rel, "to_arrow_table", None) or rel.arrow  # duckdb 2.x / 1.x
                return fetch()
            except duckdb.Error as e:
                raise RegistryError(f"query failed: {e}") from None
        finally:
            con.close()

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
    def _store_blobs(self, info: BundleInfo) -> list[Artifact]:
        arts = []
        for name, path in sorted(info.artifacts.items()):
            sha, size = sha256_file(path)
            self.blobs.put_file(path, sha)
            arts.append(Artifact(_check_name(name), sha, size))
        return arts

    def add(self, bundle_dir: str | os.PathLike) -> SceneRecord:
        """Validate, store blobs, commit a new scene version (no-op for identical content)."""
        info = validate_bundle(bundle_dir)
        arts = self._store_blobs(info)
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

        self.manifest.commit(build, operation=f"add {info.scene_id}")
        self._repair_blobs(info, arts)
        return result["rec"]

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

        self.manifest.commit(build, operation=f"{event} {scene_id}")
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
        """Re-hash every referenced blob; return problems ('missing'/'corrupt', naming the artifact)."""
        _, table = self._rows()
        users: dict[str, list[str]] = {}
        sizes: dict[str, int] = {}
        for r in table.select(["scene_id", "version", "artifacts"]).to_pylist():
            for a in r["artifacts"]:
                users.setdefault(a["sha256"], []).append(f"{r['scene_id']}@{r['version']}:{a['name']}")
                sizes[a["sha256"]] = a["size"]
        problems = []
        for sha, who in sorted(users.items()):
            where = ", ".join(who[:3]) + (f" (+{len(who) - 3} more)" if len(who) > 3 else "")
            try:
                got, size = self.blobs.rehash(sha)
            except (FileNotFoundError, OSError):
                problems.append(f"missing blob {sha} for {where}")
                continue
            if got != sha or size != sizes[sha]:
                problems.append(f"corrupt blob {sha} (content hashes to {got}, {size} bytes) for {where}")
        return problems

    def referenced(self) -> set[str]:
        _, table = self._rows()
        return {a["sha256"] for arts in table.column("artifacts").to_pylist() for a in arts}

    def gc(self, grace_s: float = GC_GRACE_S, dry_run: bool = False) -> list[str]:
        """Delete blobs no manifest row (any version) references, and stale temp files, older
        than `grace_s` seconds (protects blobs of an add still in flight). Returns what it removed."""
        import time

        refs = self.referenced()
        cutoff = time.time() - grace_s
        removed = []
        for b in list(self.blobs.list()):
            if (b.is_temp or b.sha256 not in refs) and b.mtime <= cutoff:
                if not dry_run:
                    self.blobs.delete(b)
                removed.append(("tmp/" if b.is_temp else "") + b.sha256)
        return removed

    def compact(self, vacuum_hours: Optional[int] = None, dry_run: bool = False) -> dict:
        """Merge the manifest's small Parquet files + checkpoint; rows and history unchanged.

        With `vacuum_hours`, also delete manifest files that compactions replaced more than that
        many hours ago (and, when >= 1 h, untracked files from killed writers): time travel to
        versions older than that window fails afterwards. Metrics gain "vacuumed": [file names]
        (with `dry_run`: what vacuum would delete; nothing is deleted).
        """
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

        dest defaults to ./vid2sim-checkouts/<scene_id>@<version>.
        """
        rec = self.show(check_scene_id(scene_id), version, as_of=as_of)
        out = Path(dest) if dest is not None else Path("vid2sim-checkouts") / rec.ref
        marker = out / CHECKOUT_MARKER
        if marker.is_file():
            done = json.loads(marker.read_text())
            if done.get("content_hash") == rec.content_hash:
                return out
        if out.exists() and any(out.iterdir()):
            raise RegistryError(f"{out}: checkout destination exists and holds something else")
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
            if out.exists():
                out.rmdir()
            os.replace(tmp, out)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        return out

    def scene_json(self, scene_id: str, version: Optional[int] = None) -> dict:
        """The stored scene.json of a scene version (read from its blob)."""
        rec = self.show(scene_id, version)
        with self.blobs.open(rec.artifact(SCENE_JSON).sha256) as f:
            return json.loads(f.read())
