"""Source URL secrets: an allow-list keeps scheme, host, port, path and `versionId`/`generation`;
user info, every other query parameter and the fragment never reach the ingest cache, the
registry, an error message or a log line. Real HTTP server, real cache and registry files."""

from __future__ import annotations

import json
import logging

import pytest
from ingest_media import make_video
from registry_fixtures import make_bundle

from tests.http_folder import QuietHandler, serve_folder
from vid2sim.factory.ingest.clip_list import parse_row
from vid2sim.factory.ingest.sources import redact_uri, resolve_source, uri_name
from vid2sim.factory.runtime.stage_cache import StageError
from vid2sim.registry import Registry, RegistryError
from vid2sim.registry.redact import scrub

SECRETS = ("CLIENTSECRET", "REFRESHTOK", "SASTOKEN", "FRAGTOKEN", "hunter2", "AKIAKEY", "S3SECRET",
           "ACCOUNTKEY", "SIGVALUE", "APIKEY")

CASES = [
    ("https://h.example/v/clip.mp4?client_secret=CLIENTSECRET&refresh_token=REFRESHTOK",
     "https://h.example/v/clip.mp4"),
    ("https://acct.blob.core.windows.net/c/clip.mp4?sas_token=SASTOKEN&sv=2024&sig=SIGVALUE",
     "https://acct.blob.core.windows.net/c/clip.mp4"),
    ("https://h.example/clip.mp4#access_token=FRAGTOKEN&token_type=bearer", "https://h.example/clip.mp4"),
    ("http://alice:hunter2@h.example:8080/clip.mp4", "http://h.example:8080/clip.mp4"),
    ("http://hunter2@h.example/clip.mp4", "http://h.example/clip.mp4"),
    ("s3://bucket/k/clip.mp4?access_key=AKIAKEY&secret_key=S3SECRET&versionId=3HL4kqtJ",
     "s3://bucket/k/clip.mp4?versionId=3HL4kqtJ"),
    ("s3://AKIAKEY:S3SECRET@bucket/clip.mp4", "s3://bucket/clip.mp4"),
    ("az://container/clip.mp4?account_key=ACCOUNTKEY&account_name=acct", "az://container/clip.mp4"),
    ("gs://b/clip.mp4?generation=1712&X-Goog-Signature=SIGVALUE", "gs://b/clip.mp4?generation=1712"),
    ("https://h.example/clip.mp4?weird_name_nobody_listed=APIKEY&v=2", "https://h.example/clip.mp4"),
    ("http://[::1]:9000/a/clip.mp4?key=APIKEY", "http://[::1]:9000/a/clip.mp4"),
    ("https://h.example:99999/clip.mp4?key=APIKEY", "https://[unparsable address]"),
]


@pytest.mark.parametrize("uri,want", CASES)
def test_allow_list(uri, want):
    got = redact_uri(uri)
    assert got == want
    assert not any(s in got for s in SECRETS)
    assert redact_uri(got) == got  # idempotent


def test_local_paths_and_generated_sources_are_unchanged():
    assert redact_uri("/data/videos/clip.mp4") == "/data/videos/clip.mp4"
    assert redact_uri("file:///data/videos/clip.mp4") == "file:///data/videos/clip.mp4"
    assert redact_uri("synthetic://street?seed=11") == "synthetic://street?seed=11"


def test_names_and_groups_never_carry_the_fragment_or_query():
    assert uri_name("https://h.example/v/clip.mp4#access_token=FRAG.TOKEN") == "clip.mp4"
    assert uri_name("https://u:hunter2@h.example/v/clip.mp4?sig=a.b") == "clip.mp4"
    row = parse_row({"source": "https://h.example/v/clip.mp4#access_token=FRAG.TOKEN", "licence": "CC-BY"}, 0)
    assert row.group == "clip"


def test_scrub_removes_secrets_from_backend_messages():
    uri = CASES[0][0]
    msg = (f"500, message='Internal Server Error', url='{uri}' "
           "(params client_secret=CLIENTSECRET; refresh_token=REFRESHTOK)")
    out = scrub(msg, uri)
    assert "CLIENTSECRET" not in out and "REFRESHTOK" not in out and "h.example/v/clip.mp4" in out


class _Handler(QuietHandler):
    def do_GET(self):  # noqa: N802 - http.server's name
        if self.path.startswith("/broken"):
            self.send_error(500, f"backend failure for {self.path}")  # echoes the query
            return
        super().do_GET()


def _secret_free(text: str) -> bool:
    return not any(s in text for s in SECRETS)


def test_fetch_stores_logs_and_prints_no_secret(tmp_path, caplog):
    (tmp_path / "srv").mkdir()
    video = make_video(tmp_path / "srv" / "clip.mp4", n=10, fps=10)
    cache = tmp_path / "cache"
    tail = ("?client_secret=CLIENTSECRET&refresh_token=REFRESHTOK&sas_token=SASTOKEN&sig=SIGVALUE"
            "#access_token=FRAGTOKEN")
    caplog.set_level(logging.DEBUG)
    with serve_folder(video.parent, _Handler) as port:
        url = f"http://alice:hunter2@127.0.0.1:{port}/clip.mp4{tail}"
        src = resolve_source(url, cache_dir=cache)
        again = resolve_source(url, cache_dir=cache)  # from the cache
        errors = []
        for bad in (url.replace("clip.mp4", "gone.mp4"), url.replace("clip.mp4", "broken.mp4")):
            with pytest.raises(StageError) as e:
                resolve_source(bad, cache_dir=cache)
            errors.append(str(e.value))
    assert src.uri == again.uri == f"http://127.0.0.1:{port}/clip.mp4"
    assert src.sha256 == again.sha256
    stored = [str(p.relative_to(cache)) for p in cache.rglob("*")]
    stored += [p.read_text(errors="ignore") for p in cache.rglob("*") if p.is_file() and p.suffix == ".json"]
    assert stored and all(_secret_free(s) for s in stored), stored
    assert all(_secret_free(e) for e in errors), errors
    assert "nothing found" in errors[0] and "unreachable_uri" in errors[1]
    assert _secret_free(caplog.text)

    # the registry: a bundle from that source stores only the redacted address
    bundle = make_bundle(tmp_path / "b", "s-1")
    scene = json.loads((bundle / "scene.json").read_text())
    scene["source"]["uri"] = src.uri
    (bundle / "scene.json").write_text(json.dumps(scene))
    reg = Registry(tmp_path / "reg")
    assert reg.add(bundle).source_uri == src.uri


@pytest.mark.parametrize("uri", [c[0] for c in CASES[:9]])
def test_registry_refuses_a_scene_json_that_carries_secrets(tmp_path, uri):
    bundle = make_bundle(tmp_path / "b", "s-1")
    scene = json.loads((bundle / "scene.json").read_text())
    scene["source"]["uri"] = uri
    (bundle / "scene.json").write_text(json.dumps(scene))
    reg = Registry(tmp_path / "reg")
    with pytest.raises(RegistryError, match="allow-list") as e:
        reg.add(bundle)
    assert _secret_free(str(e.value))
    assert not (tmp_path / "reg").exists()  # refused before anything was written
