"""Sources: local files and folders, file:// and http URIs with a sha256-checked cache."""

from __future__ import annotations

import hashlib
import http.server
import socket
import threading
from pathlib import Path

import pytest

from ingest_media import make_video, texture
from vid2sim.factory.ingest.sources import list_images, resolve_source, sha256_file
from vid2sim.factory.runtime.stage_cache import StageError


@pytest.fixture
def video(tmp_path: Path) -> Path:
    return make_video(tmp_path / "walk.mp4", n=20)


class _Server:
    """A loopback HTTP server for a folder, counting GET requests."""

    def __init__(self, root: Path) -> None:
        self.hits = 0
        outer = self

        class Handler(http.server.SimpleHTTPRequestHandler):
            def __init__(self, *a, **kw):
                super().__init__(*a, directory=str(root), **kw)

            def do_GET(self):  # noqa: N802
                outer.hits += 1
                super().do_GET()

            def log_message(self, *a):
                pass

        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.port = self.httpd.server_address[1]
        self.thread = threading.Thread(target=self.httpd.serve_forever, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


@pytest.fixture
def server(tmp_path: Path, video: Path):
    srv = _Server(video.parent)
    yield srv
    srv.close()


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_local_video_and_file_uri(video: Path) -> None:
    src = resolve_source(video)
    assert src.kind == "video" and src.sha256 == hashlib.sha256(video.read_bytes()).hexdigest()
    assert resolve_source(f"file://{video}").sha256 == src.sha256


def test_image_folder_natural_order(tmp_path: Path) -> None:
    import cv2

    for name in ("10.jpg", "2.jpg", "1.jpg", "notes.txt"):
        p = tmp_path / name
        p.write_text("x") if name.endswith(".txt") else cv2.imwrite(str(p), texture(8, 8))
    src = resolve_source(tmp_path)
    assert src.kind == "images"
    assert [p.name for p in list_images(tmp_path)] == ["1.jpg", "2.jpg", "10.jpg"]


def test_http_uri_downloaded_once_and_checked(tmp_path: Path, video: Path, server: _Server) -> None:
    uri, cache = f"http://127.0.0.1:{server.port}/{video.name}", tmp_path / "cache"
    digest = sha256_file(video)
    a = resolve_source(uri, cache, expected_sha256=digest)
    b = resolve_source(uri, cache)
    assert a.path == b.path and a.sha256 == digest and server.hits == 1
    a.path.write_bytes(b"corrupted")  # a damaged cache entry is fetched again
    assert resolve_source(uri, cache).sha256 == digest and server.hits == 2
    with pytest.raises(StageError) as e:
        resolve_source(uri, tmp_path / "cache2", expected_sha256="0" * 64)
    assert e.value.reason == "sha256_mismatch"
    assert not list((tmp_path / "cache2").rglob("*.mp4"))  # nothing kept


def test_unreachable_uri(tmp_path: Path) -> None:
    cache = tmp_path / "cache"
    with pytest.raises(StageError) as e:
        resolve_source(f"http://127.0.0.1:{_closed_port()}/walk.mp4", cache)
    assert e.value.reason == "unreachable_uri"
    assert not [p for p in cache.rglob("*") if p.is_file()]


def test_missing_and_unsupported(tmp_path: Path) -> None:
    with pytest.raises(StageError) as e:
        resolve_source(tmp_path / "nope.mp4")
    assert e.value.reason == "missing_source"
    with pytest.raises(StageError) as e:
        resolve_source(f"file://{tmp_path}/nope.mp4")
    assert e.value.reason == "missing_source"
    (tmp_path / "notes.txt").write_text("hi")
    with pytest.raises(StageError) as e:
        resolve_source(tmp_path / "notes.txt")
    assert e.value.reason == "unsupported_source"
    (tmp_path / "empty").mkdir()
    with pytest.raises(StageError) as e:
        resolve_source(tmp_path / "empty")
    assert e.value.reason == "empty_folder"
