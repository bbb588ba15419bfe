"""Sources: a video file, an ordered image folder, or a URI fetched once into a cache.

`resolve_source(spec)` turns a path or URI into a local `Source` with a content hash.
URIs (http(s), s3, gs, file, ... via fsspec) are downloaded once into
`cache_dir/<hash of uri>/<file name>` beside a `source.json` recording the sha256;
a cached copy is re-hashed before reuse and re-fetched when it no longer matches.
Errors are `StageError("ingest", reason)` with reasons `missing_source`,
`unreachable_uri`, `sha256_mismatch`, `unsupported_source`, `empty_folder`.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Union

from vid2sim.factory.runtime.stage_cache import StageError
from vid2sim.registry.redact import redact_uri, scrub, scrubbed_logs  # the allow-list lives with the registry

STAGE = "ingest"
VIDEO_EXTS = (".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm")
IMAGE_EXTS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp")
_URI_RE = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*://")


@dataclass(frozen=True)
class Source:
    """A local, hashed input. `kind` is "video" or "images"."""

    kind: str
    path: Path
    uri: str
    sha256: str

    def images(self) -> list[Path]:
        """Ordered image files of an image-folder source."""
        if self.kind != "images":
            raise ValueError("not an image folder source")
        return list_images(self.path)


def default_cache_dir() -> Path:
    return Path(os.environ.get("VID2SIM_CACHE", Path.home() / ".cache" / "vid2sim" / "sources"))


def sha256_file(path: Path, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()


def _natural_key(name: str) -> list:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def list_images(folder: Path) -> list[Path]:
    """Image files of `folder`, ordered by name (natural order: 2.jpg before 10.jpg)."""
    files = [p for p in Path(folder).iterdir() if p.suffix.lower() in IMAGE_EXTS and p.is_file()]
    return sorted(files, key=lambda p: _natural_key(p.name))


def _folder_hash(files: list[Path]) -> str:
    h = hashlib.sha256()
    for p in files:
        h.update(p.name.encode() + b"\0" + sha256_file(p).encode() + b"\n")
    return h.hexdigest()


def is_uri(spec: str) -> bool:
    return bool(_URI_RE.match(str(spec)))


def uri_name(uri: str) -> str:
    """The file name a source names: the last segment of a URI's path (no query, fragment or
    user info), or of a local path."""
    from urllib.parse import unquote, urlsplit

    if is_uri(uri):
        try:
            path = urlsplit(uri).path
        except ValueError:
            path = ""
        return Path(unquote(path).rstrip("/")).name
    return Path(uri).name


def resolve_source(spec: Union[str, Path], cache_dir: Optional[Path] = None,
                   expected_sha256: Optional[str] = None) -> Source:
    """Path or URI -> local `Source` (downloading a URI once into the cache)."""
    spec_s = str(spec)
    if is_uri(spec_s) and not spec_s.startswith("file://"):
        path = fetch_uri(spec_s, cache_dir or default_cache_dir(), expected_sha256)
        return _local_source(path, redact_uri(spec_s), expected_sha256)
    if spec_s.startswith("file://"):
        spec_s = spec_s[len("file://"):]
        return _local_source(Path(spec_s), redact_uri(str(spec)), expected_sha256)
    return _local_source(Path(spec_s), str(spec), expected_sha256)


def _local_source(path: Path, uri: str, expected_sha256: Optional[str]) -> Source:
    if not path.exists():
        raise StageError(STAGE, "missing_source", f"{uri}: no such file or folder")
    if path.is_dir():
        files = list_images(path)
        if not files:
            raise StageError(STAGE, "empty_folder", f"{uri}: no images ({', '.join(IMAGE_EXTS)})")
        return Source("images", path, uri, _folder_hash(files))
    if path.suffix.lower() not in VIDEO_EXTS:
        raise StageError(STAGE, "unsupported_source",
                         f"{uri}: expected a video ({', '.join(VIDEO_EXTS)}) or an image folder")
    digest = sha256_file(path)
    if expected_sha256 and digest != expected_sha256.lower():
        raise StageError(STAGE, "sha256_mismatch", f"{uri}: sha256 {digest} != expected {expected_sha256}")
    return Source("video", path, uri, digest)


def fetch_uri(uri: str, cache_dir: Path, expected_sha256: Optional[str] = None) -> Path:
    """Download `uri` once into `cache_dir`; reuse the cached copy while its sha256 matches."""
    slot = Path(cache_dir) / hashlib.sha256(uri.encode()).hexdigest()[:16]
    name = uri_name(uri) or "source"
    target, meta = slot / name, slot / "source.json"
    if target.is_file() and meta.is_file():
        recorded = json.loads(meta.read_text()).get("sha256")
        if recorded == sha256_file(target) and (not expected_sha256 or recorded == expected_sha256.lower()):
            return target
    slot.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=slot, prefix=".part-")
    try:
        with os.fdopen(fd, "wb") as out:
            _copy_uri(uri, out)
        digest = sha256_file(Path(tmp))
        if expected_sha256 and digest != expected_sha256.lower():
            raise StageError(STAGE, "sha256_mismatch",
                             f"{redact_uri(uri)}: sha256 {digest} != expected {expected_sha256}")
        os.replace(tmp, target)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    meta.write_text(json.dumps({"uri": redact_uri(uri), "sha256": digest, "file": name}, indent=2))
    return target


ARROW_SCHEMES = ("s3", "gs", "gcs")  # object stores pyarrow reads natively (no s3fs/gcsfs needed)


def _open_uri(uri: str):
    """A binary stream of `uri`: pyarrow for S3/GCS (endpoint and credentials from the usual
    environment, e.g. AWS_ENDPOINT_URL), fsspec for everything else."""
    if uri.split("://", 1)[0].lower() in ARROW_SCHEMES:
        import pyarrow.fs as pafs

        fs, path = pafs.FileSystem.from_uri(uri)
        return fs.open_input_stream(path)
    import fsspec

    kwargs = {}
    if uri.startswith(("http://", "https://")):
        import aiohttp

        kwargs["client_kwargs"] = {"timeout": aiohttp.ClientTimeout(total=None, sock_connect=30, sock_read=60)}
    return fsspec.open(uri, "rb", **kwargs)


def _copy_uri(uri: str, out) -> None:
    try:
        with scrubbed_logs(uri), _open_uri(uri) as f:  # backends log the full URL at DEBUG
            while block := f.read(1 << 20):
                out.write(block)
    except ImportError as e:  # e.g. s3fs / gcsfs not installed
        raise StageError(STAGE, "unsupported_uri", f"{redact_uri(uri)}: {scrub(str(e), uri)}") from None
    except FileNotFoundError:
        raise StageError(STAGE, "unreachable_uri", f"{redact_uri(uri)}: nothing found at that address "
                                                   "(HTTP 404 or no such object)") from None
    except Exception as e:  # noqa: BLE001 - network/filesystem errors of any backend
        detail = scrub(str(e), uri).splitlines()[0][:200] if str(e) else ""
        raise StageError(STAGE, "unreachable_uri", f"{redact_uri(uri)}: {type(e).__name__} {detail}") from None
