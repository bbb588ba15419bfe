"""Where stage outputs live: one narrow interface, resolved relative to a root.

Stages and the runtime address artifacts by POSIX paths relative to the storage root
(`<clip_id>/<stage>/<file>`), never by absolute local paths, so the same records work for a
local folder now and an object store later (the cluster issue adds a URI-backed Storage).
`LocalStorage` keeps everything under one local folder; `put_dir`/`get_dir` copy folders in
and out (a no-op round trip locally), and `write_marker` replaces a marker atomically.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import Protocol


class StorageError(ValueError):
    """A relative artifact path is invalid or an artifact is missing; names the path."""


class Storage(Protocol):
    """What the runtime needs from a store of stage outputs."""

    def exists(self, rel: str) -> bool: ...

    def read_bytes(self, rel: str) -> bytes: ...

    def write_bytes(self, rel: str, data: bytes) -> None: ...

    def put_dir(self, local: Path, rel: str) -> None: ...

    def get_dir(self, rel: str, local: Path) -> Path: ...

    def write_marker(self, rel: str, data: bytes) -> None: ...


def check_rel(rel: str) -> str:
    """A clean relative POSIX path (no '..', not absolute, not empty) or StorageError."""
    p = PurePosixPath(rel)
    if not rel or p.is_absolute() or ".." in p.parts or "\\" in rel:
        raise StorageError(f"invalid artifact path {rel!r}: must be relative, without '..'")
    return p.as_posix()


@dataclass(frozen=True)
class LocalStorage:
    """Artifacts under a local root folder."""

    root: Path

    def path(self, rel: str) -> Path:
        """Local path of an artifact (for libraries that need a file name)."""
        return Path(self.root) / check_rel(rel)

    def exists(self, rel: str) -> bool:
        return self.path(rel).exists()

    def read_bytes(self, rel: str) -> bytes:
        p = self.path(rel)
        if not p.is_file():
            raise StorageError(f"{rel}: no such artifact under {self.root}")
        return p.read_bytes()

    def write_bytes(self, rel: str, data: bytes) -> None:
        p = self.path(rel)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data)

    def put_dir(self, local: Path, rel: str) -> None:
        """Copy the folder `local` to `rel` (replacing it); a no-op when it is already there."""
        dst = self.path(rel)
        if Path(local).resolve() == dst.resolve():
            return
        if dst.exists():
            shutil.rmtree(dst)
        shutil.copytree(local, dst)

    def get_dir(self, rel: str, local: Path) -> Path:
        """Copy folder `rel` to `local` and return it; returns the stored folder itself when
        `local` is that folder."""
        src = self.path(rel)
        if not src.is_dir():
            raise StorageError(f"{rel}: no such folder under {self.root}")
        if Path(local).resolve() != src.resolve():
            shutil.copytree(src, local, dirs_exist_ok=True)
        return Path(local)

    def write_marker(self, rel: str, data: bytes) -> None:
        """Write `data` at `rel` atomically (temp file in the same folder, then rename)."""
        p = self.path(rel)
        p.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=p.parent, prefix=".marker-")
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.chmod(tmp, 0o644)
        os.replace(tmp, p)
