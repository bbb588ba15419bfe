"""Stage folders on a local disk or an object store, behind one narrow interface.

`ObjectStore(root)` takes a folder or any pyarrow/fsspec URI (`s3://bucket/work`, `gs://...`);
credentials and endpoints come from the usual environment (e.g. `AWS_ENDPOINT_URL`). Keys are
'/'-separated paths relative to the root. A folder is "done" when its marker exists: `put_dir`
uploads every other file first and the marker last, in one atomic write (a single PUT on an
object store, write-then-rename on a local disk), so a reader never sees a marker whose files
are missing.
"""

from __future__ import annotations

import os
import uuid
from pathlib import Path
from typing import Iterator

import pyarrow.fs as pafs

from vid2sim.factory.runtime.stage_cache import MARKER as STAGE_MARKER
from vid2sim.registry.blobs import arrow_filesystem

MARKER = STAGE_MARKER  # the stage cache marker (runtime/stage_cache.py)
CHUNK = 1 << 22


def is_remote(uri: str) -> bool:
    """True for object-store URIs (`s3://`, `gs://`, `memory://`...), False for local paths."""
    scheme = uri.split("://", 1)[0] if "://" in uri else ""
    return scheme not in ("", "file") and len(scheme) > 1


class ObjectStore:
    """exists / read_bytes / write_bytes / put_dir / get_dir / marker under one root."""

    def __init__(self, root: str) -> None:
        root = str(root)
        if is_remote(root):
            self.fs, base = arrow_filesystem(root)
        else:
            local = Path(root.removeprefix("file://")).expanduser().resolve()
            local.mkdir(parents=True, exist_ok=True)
            self.fs, base = pafs.LocalFileSystem(), str(local)
        self.root, self.base = root.rstrip("/"), base.rstrip("/")
        self.atomic_rename = isinstance(self.fs, pafs.LocalFileSystem)

    def __repr__(self) -> str:
        return f"ObjectStore({self.root!r})"

    def _path(self, key: str) -> str:
        key = key.strip("/")
        if ".." in key.split("/"):
            raise ValueError(f"unsafe key {key!r}")
        return f"{self.base}/{key}" if key else self.base

    def exists(self, key: str) -> bool:
        return self.fs.get_file_info(self._path(key)).type == pafs.FileType.File

    def read_bytes(self, key: str) -> bytes:
        with self.fs.open_input_stream(self._path(key)) as f:
            return f.read()

    def write_bytes(self, key: str, data: bytes) -> None:
        """Whole-object write: readers see the old object, or none, or all of `data`."""
        path = self._path(key)
        parent = path.rsplit("/", 1)[0]
        self.fs.create_dir(parent, recursive=True)
        target = f"{parent}/.tmp-{uuid.uuid4().hex}" if self.atomic_rename else path
        with self.fs.open_output_stream(target) as f:
            f.write(data)
        if target != path:
            self.fs.move(target, path)

    def list_files(self, key: str) -> Iterator[str]:
        """Keys of the files under folder `key`, relative to it ('/'-separated)."""
        base = self._path(key)
        if self.fs.get_file_info(base).type != pafs.FileType.Directory:
            return
        for info in self.fs.get_file_info(pafs.FileSelector(base, recursive=True)):
            if info.type == pafs.FileType.File:
                yield info.path[len(base):].lstrip("/")

    def put_dir(self, local: Path, key: str, marker: str = MARKER) -> int:
        """Upload folder `local` to `key`, the marker last; returns the number of files."""
        local = Path(local)
        files = sorted(p for p in local.rglob("*") if p.is_file() and p.name != marker
                       and not p.name.startswith(".stage-"))
        for p in files:
            dest = self._path(f"{key}/{p.relative_to(local).as_posix()}")
            self.fs.create_dir(dest.rsplit("/", 1)[0], recursive=True)
            with open(p, "rb") as src, self.fs.open_output_stream(dest) as out:
                while chunk := src.read(CHUNK):
                    out.write(chunk)
        if (local / marker).is_file():
            self.write_bytes(f"{key}/{marker}", (local / marker).read_bytes())
        return len(files)

    def get_dir(self, key: str, local: Path, marker: str = MARKER) -> int:
        """Download folder `key` into `local` (the marker last); returns the number of files."""
        local = Path(local)
        names = sorted(self.list_files(key), key=lambda n: n == marker)
        for name in names:
            dest = local / name
            dest.parent.mkdir(parents=True, exist_ok=True)
            tmp = dest.with_name(f".dl-{uuid.uuid4().hex}")
            with self.fs.open_input_stream(self._path(f"{key}/{name}")) as src, open(tmp, "wb") as out:
                while chunk := src.read(CHUNK):
                    out.write(chunk)
            os.replace(tmp, dest)
        return len(names)

    def marker(self, key: str, marker: str = MARKER) -> bytes | None:
        """The marker's bytes of folder `key`, or None when the folder is not done."""
        try:
            return self.read_bytes(f"{key}/{marker}")
        except (FileNotFoundError, OSError):
            return None
