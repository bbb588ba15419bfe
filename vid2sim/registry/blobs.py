"""Content-addressed blob store: `<root>/blobs/ab/cdef...` keyed by sha256.

Writes go to `<root>/blobs/tmp/<random>` and are renamed into place, so a blob path either
holds the full content or does not exist. Before an add stores blobs it writes an intent
(`<root>/blobs/intents/<id>.json`: the scene and the blob hashes) and removes it after its
commit, so a blob that no manifest row and no intent accounts for means lost history. Identical
content is stored once. Two backends share one small interface: `LocalBlobStore` (a folder;
os.replace + fsync) and `ArrowBlobStore` (any pyarrow FileSystem, including fsspec filesystems
wrapped by `pyarrow.fs.FSSpecHandler`).

Owners: temp files are named `<random>.<pid>.<host>` and intents record `owner` {host, pid}, so
`gc` can tell a writer that is still running on this machine (its files are never touched) from
one that died (its leftovers go after the grace period); see `process_state`. `gc` deletes a blob
in two steps: it moves it to `<root>/blobs/trash/` (`trash`), re-checks that nothing started to
reference it meanwhile, then `restore`s or `purge`s it; a gc killed in between leaves trash that
the next gc restores.
"""

from __future__ import annotations

import hashlib
import json
import os
import socket
import time
import uuid
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, Iterator

CHUNK = 1 << 20
TMP_DIR = "tmp"
INTENT_DIR = "intents"  # one JSON per add in flight: the blobs it stores before its commit
TRASH_DIR = "trash"  # blobs a running gc took out, until it has re-checked them
HOST = socket.gethostname()
_WRITING: set[str] = set()  # temp file names this process is writing right now


def temp_name(pid: int | None = None, host: str | None = None) -> str:
    """A fresh temp/trash file name that names its owner: `<random>.<pid>.<host>`."""
    return f"{uuid.uuid4().hex}.{os.getpid() if pid is None else pid}.{host or HOST}"


def name_owner(name: str) -> tuple[str | None, int | None]:
    """(host, pid) of a `temp_name`; (None, None) for a name that records no owner."""
    parts = name.split(".", 2)
    if len(parts) == 3 and parts[1].isdigit() and parts[2]:
        return parts[2], int(parts[1])
    return None, None


def owner() -> dict:
    """What an intent records about the process writing it."""
    return {"host": HOST, "pid": os.getpid()}


def process_state(host: str | None, pid: int | None) -> str:
    """'self' (this process), 'alive', 'dead', or 'unknown' (another machine / nothing recorded).

    A zombie or a reused pid reads as alive: that only keeps leftovers longer, never less."""
    if not host or not pid or host != HOST:
        return "unknown"
    if pid == os.getpid():
        return "self"
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return "dead"
    except PermissionError:  # exists, owned by another user
        return "alive"
    except OSError:
        return "unknown"
    return "alive"


def temp_in_use(name: str) -> bool:
    """True while the process that names itself in temp file `name` may still be writing it."""
    state = process_state(*name_owner(name))
    return state == "alive" or (state == "self" and name in _WRITING)


@dataclass(frozen=True)
class Trashed:
    """A blob `gc` moved aside: its trash file name and the mtime it had (None: not reliable)."""

    sha256: str
    name: str
    mtime: float | None


def sha256_file(path: Path) -> tuple[str, int]:
    """(hex sha256, size in bytes) of a local file."""
    h, n = hashlib.sha256(), 0
    with open(path, "rb") as f:
        while chunk := f.read(CHUNK):
            h.update(chunk)
            n += len(chunk)
    return h.hexdigest(), n


def sha256_stream(stream: BinaryIO) -> tuple[str, int]:
    h, n = hashlib.sha256(), 0
    while chunk := stream.read(CHUNK):
        h.update(chunk)
        n += len(chunk)
    return h.hexdigest(), n


@dataclass(frozen=True)
class BlobInfo:
    sha256: str  # or the temp file name for leftovers in tmp/
    mtime: float  # seconds since epoch
    is_temp: bool = False


def blob_relpath(sha: str) -> str:
    if len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
        raise ValueError(f"not a sha256 hex digest: {sha!r}")
    return f"{sha[:2]}/{sha[2:]}"


class BlobStore(ABC):
    """What the registry needs from a blob store."""

    @abstractmethod
    def exists(self, sha: str) -> bool: ...

    @abstractmethod
    def put_file(self, path: Path, sha: str) -> bool:
        """Store `path` under `sha` (its precomputed hash); False if an intact copy is present.

        A stored copy with the wrong size or hash (bit rot, a tampered file) is rewritten."""

    def intact(self, sha: str, size: int) -> bool:
        """The stored blob exists, has `size` bytes and hashes to `sha`."""
        try:
            got, n = self.rehash(sha)
        except (FileNotFoundError, OSError):
            return False
        return got == sha and n == size

    @abstractmethod
    def open(self, sha: str) -> BinaryIO: ...

    @abstractmethod
    def list(self) -> Iterator[BlobInfo]: ...

    @abstractmethod
    def delete(self, info: BlobInfo) -> None: ...

    @abstractmethod
    def write_intent(self, name: str, data: dict) -> None:
        """Atomically write intent `name` (JSON)."""

    @abstractmethod
    def intents(self) -> list[tuple[str, dict, float]]:
        """(name, content, mtime) of every readable intent."""

    @abstractmethod
    def delete_intent(self, name: str) -> None: ...

    @abstractmethod
    def trash(self, sha: str) -> Trashed | None:
        """Move blob `sha` aside (None when it is not there); see `restore` and `purge`."""

    @abstractmethod
    def trashed(self) -> list[Trashed]:
        """Everything in the trash (mtime: the trash file's)."""

    @abstractmethod
    def restore(self, t: Trashed) -> None:
        """Put a trashed blob back (just drop the trash copy when the blob was stored again)."""

    @abstractmethod
    def purge(self, t: Trashed) -> None:
        """Delete a trashed blob for good."""

    def rehash(self, sha: str) -> tuple[str, int]:
        with self.open(sha) as f:
            return sha256_stream(f)

    def copy_to(self, sha: str, dest: Path) -> tuple[str, int]:
        """Write blob `sha` to a local file; return the (hash, size) of what was written."""
        h, n = hashlib.sha256(), 0
        with self.open(sha) as src, open(dest, "wb") as out:
            while chunk := src.read(CHUNK):
                h.update(chunk)
                n += len(chunk)
                out.write(chunk)
        return h.hexdigest(), n


def _check_copy(sha: str, got: str, path: Path) -> None:
    if got != sha:
        raise IOError(f"{path}: content changed while storing (expected sha256 {sha}, read {got})")


class LocalBlobStore(BlobStore):
    """Blobs in a local folder."""

    def __init__(self, root: Path) -> None:
        self.root = Path(root)

    def path(self, sha: str) -> Path:
        return self.root / blob_relpath(sha)

    def exists(self, sha: str) -> bool:
        return self.path(sha).is_file()

    def put_file(self, path: Path, sha: str) -> bool:
        final = self.path(sha)
        try:
            if final.is_file() and final.stat().st_size == os.path.getsize(path) \
                    and self.intact(sha, final.stat().st_size):
                os.utime(final)  # refresh mtime: gc sees a blob about to be referenced (see Registry.gc)
                return False
        except FileNotFoundError:  # a gc moved it aside meanwhile: store it again
            pass
        tmp_dir = self.root / TMP_DIR
        tmp_dir.mkdir(parents=True, exist_ok=True)
        tmp = tmp_dir / temp_name()
        _WRITING.add(tmp.name)  # gc leaves a live writer's temp file alone (temp_in_use)
        try:
            h = hashlib.sha256()
            with open(path, "rb") as src, open(tmp, "wb") as out:
                while chunk := src.read(CHUNK):
                    h.update(chunk)
                    out.write(chunk)
                out.flush()
                os.fsync(out.fileno())
            _check_copy(sha, h.hexdigest(), Path(path))
            final.parent.mkdir(parents=True, exist_ok=True)
            os.replace(tmp, final)
        finally:
            tmp.unlink(missing_ok=True)
            _WRITING.discard(tmp.name)
        return True

    def open(self, sha: str) -> BinaryIO:
        return open(self.path(sha), "rb")

    def list(self) -> Iterator[BlobInfo]:
        if not self.root.is_dir():
            return
        for d in sorted(self.root.iterdir()):
            if not d.is_dir():
                continue
            for f in sorted(d.iterdir()):
                try:
                    mtime = f.stat().st_mtime
                except FileNotFoundError:
                    continue
                if d.name == TMP_DIR:
                    yield BlobInfo(f.name, mtime, is_temp=True)
                elif len(d.name) == 2:
                    yield BlobInfo(d.name + f.name, mtime)

    def delete(self, info: BlobInfo) -> None:
        p = self.root / TMP_DIR / info.sha256 if info.is_temp else self.path(info.sha256)
        p.unlink(missing_ok=True)

    def write_intent(self, name: str, data: dict) -> None:
        d = self.root / INTENT_DIR
        d.mkdir(parents=True, exist_ok=True)
        tmp = d / f".{name}.tmp"
        tmp.write_text(json.dumps(data))
        os.replace(tmp, d / f"{name}.json")

    def intents(self) -> list[tuple[str, dict, float]]:
        d = self.root / INTENT_DIR
        out = []
        for p in sorted(d.glob("*.json")) if d.is_dir() else []:
            try:
                out.append((p.stem, json.loads(p.read_text()), p.stat().st_mtime))
            except (FileNotFoundError, ValueError):  # removed meanwhile / torn by a crash
                continue
        return out

    def delete_intent(self, name: str) -> None:
        (self.root / INTENT_DIR / f"{name}.json").unlink(missing_ok=True)

    def trash(self, sha: str) -> Trashed | None:
        d = self.root / TRASH_DIR
        d.mkdir(parents=True, exist_ok=True)
        name = f"{sha}.{temp_name()}"
        try:
            os.rename(self.path(sha), d / name)  # atomic: a later os.utime / read of the blob fails
        except FileNotFoundError:
            return None
        try:
            return Trashed(sha, name, (d / name).stat().st_mtime)  # rename keeps the mtime
        except FileNotFoundError:  # another gc restored it already
            return None

    def trashed(self) -> list[Trashed]:
        d = self.root / TRASH_DIR
        out = []
        for p in sorted(d.iterdir()) if d.is_dir() else []:
            try:
                out.append(Trashed(p.name[:64], p.name, p.stat().st_mtime))
            except FileNotFoundError:
                continue
        return out

    def restore(self, t: Trashed) -> None:
        src, final = self.root / TRASH_DIR / t.name, self.path(t.sha256)
        if final.is_file():
            src.unlink(missing_ok=True)
            return
        final.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.replace(src, final)
        except FileNotFoundError:
            pass

    def purge(self, t: Trashed) -> None:
        (self.root / TRASH_DIR / t.name).unlink(missing_ok=True)


class ArrowBlobStore(BlobStore):
    """Blobs on any `pyarrow.fs.FileSystem` (S3, GCS, HDFS, local, or fsspec via FSSpecHandler)."""

    def __init__(self, fs, base: str) -> None:
        self.fs, self.base = fs, base.rstrip("/")

    def path(self, sha: str) -> str:
        return f"{self.base}/{blob_relpath(sha)}"

    def exists(self, sha: str) -> bool:
        import pyarrow.fs as pafs

        return self.fs.get_file_info(self.path(sha)).type == pafs.FileType.File

    def put_file(self, path: Path, sha: str) -> bool:
        if self.exists(sha) and self.intact(sha, os.path.getsize(path)):
            return False
        name = temp_name()
        tmp = f"{self.base}/{TMP_DIR}/{name}"
        final = self.path(sha)
        self.fs.create_dir(f"{self.base}/{TMP_DIR}", recursive=True)
        self.fs.create_dir(final.rsplit("/", 1)[0], recursive=True)
        h = hashlib.sha256()
        _WRITING.add(name)
        try:
            with open(path, "rb") as src, self.fs.open_output_stream(tmp) as out:
                while chunk := src.read(CHUNK):
                    h.update(chunk)
                    out.write(chunk)
            try:
                _check_copy(sha, h.hexdigest(), Path(path))
                self.fs.move(tmp, final)
            except BaseException:
                self.fs.delete_file(tmp)
                raise
        finally:
            _WRITING.discard(name)
        return True

    def open(self, sha: str) -> BinaryIO:
        return self.fs.open_input_stream(self.path(sha))

    def list(self) -> Iterator[BlobInfo]:
        import pyarrow.fs as pafs

        sel = pafs.FileSelector(self.base, recursive=True, allow_not_found=True)
        for info in self.fs.get_file_info(sel):
            if info.type != pafs.FileType.File:
                continue
            rel = info.path[len(self.base):].strip("/").split("/")
            mtime = info.mtime.timestamp() if info.mtime is not None else time.time()
            if len(rel) == 2 and rel[0] == TMP_DIR:
                yield BlobInfo(rel[1], mtime, is_temp=True)
            elif len(rel) == 2 and len(rel[0]) == 2:
                yield BlobInfo(rel[0] + rel[1], mtime)

    def delete(self, info: BlobInfo) -> None:
        p = f"{self.base}/{TMP_DIR}/{info.sha256}" if info.is_temp else self.path(info.sha256)
        self.fs.delete_file(p)

    def write_intent(self, name: str, data: dict) -> None:
        self.fs.create_dir(f"{self.base}/{INTENT_DIR}", recursive=True)
        with self.fs.open_output_stream(f"{self.base}/{INTENT_DIR}/{name}.json") as out:
            out.write(json.dumps(data).encode())

    def intents(self) -> list[tuple[str, dict, float]]:
        import pyarrow.fs as pafs

        sel = pafs.FileSelector(f"{self.base}/{INTENT_DIR}", allow_not_found=True)
        out = []
        for info in self.fs.get_file_info(sel):
            if info.type != pafs.FileType.File or not info.path.endswith(".json"):
                continue
            try:
                with self.fs.open_input_stream(info.path) as f:
                    data = json.loads(f.read())
            except (OSError, ValueError):
                continue
            mtime = info.mtime.timestamp() if info.mtime is not None else time.time()
            out.append((info.path.rsplit("/", 1)[1][:-5], data, mtime))
        return out

    def delete_intent(self, name: str) -> None:
        try:
            self.fs.delete_file(f"{self.base}/{INTENT_DIR}/{name}.json")
        except FileNotFoundError:
            pass

    def trash(self, sha: str) -> Trashed | None:
        # an object store's move is a copy: the mtime says nothing, gc relies on its re-check
        name = f"{sha}.{temp_name()}"
        self.fs.create_dir(f"{self.base}/{TRASH_DIR}", recursive=True)
        try:
            self.fs.move(self.path(sha), f"{self.base}/{TRASH_DIR}/{name}")
        except FileNotFoundError:
            return None
        return Trashed(sha, name, None)

    def trashed(self) -> list[Trashed]:
        import pyarrow.fs as pafs

        sel = pafs.FileSelector(f"{self.base}/{TRASH_DIR}", allow_not_found=True)
        out = []
        for info in self.fs.get_file_info(sel):
            if info.type == pafs.FileType.File:
                name = info.path.rsplit("/", 1)[1]
                out.append(Trashed(name[:64], name, info.mtime.timestamp() if info.mtime else None))
        return out

    def restore(self, t: Trashed) -> None:
        src = f"{self.base}/{TRASH_DIR}/{t.name}"
        try:
            if self.exists(t.sha256):
                self.fs.delete_file(src)
            else:
                self.fs.move(src, self.path(t.sha256))
        except FileNotFoundError:
            pass

    def purge(self, t: Trashed) -> None:
        try:
            self.fs.delete_file(f"{self.base}/{TRASH_DIR}/{t.name}")
        except FileNotFoundError:
            pass


def arrow_filesystem(uri: str):
    """(pyarrow FileSystem, path) for a URI; falls back to fsspec (e.g. memory://)."""
    import pyarrow.fs as pafs

    try:
        return pafs.FileSystem.from_uri(uri)
    except Exception:
        import fsspec

        fs, path = fsspec.core.url_to_fs(uri)
        return pafs.PyFileSystem(pafs.FSSpecHandler(fs)), path
