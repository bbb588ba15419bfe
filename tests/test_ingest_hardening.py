"""Ingest hardening: scene ids name the exact clip; bad manifest values are refused."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from ingest_media import make_video
from registry_fixtures import make_bundle

from tests.http_folder import serve_folder
from vid2sim.factory.ingest.clip_list import load_manifest
from vid2sim.factory.runtime.pipeline import PipelineConfig, plan_jobs
from vid2sim.factory.runtime.stage_cache import StageError
from vid2sim.registry import Registry


def _manifest(path: Path, rows: list[dict]) -> Path:
    path.write_text(yaml.safe_dump({"sources": rows}))
    return path


def test_windows_of_one_video_are_different_scenes(tmp_path):
    make_video(tmp_path / "walk.mp4", n=40, fps=10)  # 4 s
    windows = [(0.0, 4.0), (0.0, 3.5), (0.5, 4.0)]
    rows = [{"source": "walk.mp4", "licence": "MIT", "start": a, "end": b} for a, b in windows]
    m = _manifest(tmp_path / "m.yaml", rows)
    jobs, failed = plan_jobs(load_manifest(m), PipelineConfig())
    ids = [j.scene_id for j in jobs]
    assert not failed and len(set(ids)) == 3, ids
    assert ids[0].startswith("walk-") and ids[0].endswith("-0-4s") and ids[2].endswith("-0.5-4s")
    again, _ = plan_jobs(load_manifest(m), PipelineConfig())
    assert [j.scene_id for j in again] == ids  # the same clip keeps its id
    reg = Registry(tmp_path / "reg")
    for i, sid in enumerate(ids):  # committed: three scenes, none hidden behind another's version
        reg.add(make_bundle(tmp_path / f"b{i}", sid, seed=i))
    assert sorted(r.ref for r in reg.list()) == sorted(f"{s}@1" for s in ids)
    reg.add(make_bundle(tmp_path / "b0", ids[0], seed=7))  # re-ingest of clip 0 with new content
    assert reg.show(ids[0]).version == 2 and len(reg.list()) == 3


def test_long_stem_still_gives_a_valid_id(tmp_path):
    from vid2sim.formats.scene import is_valid_scene_id

    make_video(tmp_path / ("a" * 80 + ".mp4"), n=10, fps=10)
    m = _manifest(tmp_path / "m.yaml", [{"source": "a" * 80 + ".mp4", "licence": "MIT",
                                         "start": 0.123, "end": 0.9876}])
    jobs, _ = plan_jobs(load_manifest(m), PipelineConfig())
    assert is_valid_scene_id(jobs[0].scene_id) and jobs[0].scene_id.endswith("-0.123-0.988s")


BAD_ROWS = {
    "strat": ({"strat": 0.0}, "unknown_field", "did you mean 'start'"),
    "ennd": ({"start": 0.0, "ennd": 1.0}, "unknown_field", "did you mean 'end'"),
    "capture_hieght": ({"capture_hieght": 1.6}, "unknown_field", "capture_height"),
    "capture_height 0": ({"capture_height": 0}, "bad_value", "capture_height=0"),
    "end .inf": ({"start": 0.0, "end": float("inf")}, "bad_value", "not a finite number"),
}


@pytest.mark.parametrize("case", sorted(BAD_ROWS))
def test_bad_manifest_values_are_named(tmp_path, case):
    extra, reason, text = BAD_ROWS[case]
    m = _manifest(tmp_path / "m.yaml", [{"source": "walk.mp4", "licence": "MIT", **extra}])
    with pytest.raises(StageError) as e:
        load_manifest(m)
    assert e.value.reason == reason and text in str(e.value)


def test_extra_columns_still_become_tags(tmp_path):
    m = _manifest(tmp_path / "m.yaml", [{"source": "walk.mp4", "licence": "MIT", "camera": "gopro"}])
    assert load_manifest(m)[0].tags["camera"] == "gopro"


def test_broken_yaml_is_one_line(tmp_path):
    m = tmp_path / "m.yaml"
    m.write_text("sources:\n  - source: a.mp4\n    licence: [MIT\n")
    with pytest.raises(StageError) as e:
        load_manifest(m)
    assert e.value.reason == "bad_yaml" and "line" in str(e.value)


def test_secrets_in_source_url_are_never_stored(tmp_path):
    from vid2sim.factory.ingest.sources import redact_uri, resolve_source

    url = "http://user:hunter2@127.0.0.1:{port}/clip.mp4?X-Amz-Signature=abc123&X-Amz-Credential=AKIA&v=2"
    assert redact_uri(url.format(port=80)) == "http://127.0.0.1:80/clip.mp4"  # an allow-list: v goes too
    (tmp_path / "srv").mkdir()
    video = make_video(tmp_path / "srv" / "clip.mp4", n=10, fps=10)
    with serve_folder(video.parent) as port:
        src = resolve_source(url.format(port=port), cache_dir=tmp_path / "cache")
        with pytest.raises(StageError) as e:
            resolve_source(url.format(port=port).replace("clip.mp4", "gone.mp4"), cache_dir=tmp_path / "cache")
    assert "hunter2" not in src.uri and "abc123" not in src.uri and src.uri.endswith("clip.mp4")
    stored = "".join(p.read_text(errors="ignore") for p in (tmp_path / "cache").rglob("*.json"))
    assert stored and "hunter2" not in stored and "abc123" not in stored and "AKIA" not in stored
    assert e.value.reason == "unreachable_uri" and "hunter2" not in str(e.value)
    assert "FileNotFoundError" not in str(e.value) and "nothing found" in str(e.value)


def test_num_cpus_zero_is_refused_at_once():
    from vid2sim.factory.runtime.orchestrator import ensure_ray

    with pytest.raises(ValueError, match="at least 1 CPU"):
        ensure_ray(num_cpus=0)
    from typer.testing import CliRunner

    from vid2sim.cli.app import app

    r = CliRunner().invoke(app, ["ingest", "x.mp4", "--num-cpus", "0"])
    assert r.exit_code == 2 and "--num-cpus" in r.output


