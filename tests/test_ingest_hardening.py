"""Issue 11, ingest side: scene ids name the exact clip; bad manifest values are refused."""

from __future__ import annotations

from pathlib import Path

import yaml
from ingest_media import make_video
from registry_fixtures import make_bundle

from vid2sim.factory.ingest.clip_list import load_manifest
from vid2sim.factory.runtime.pipeline import PipelineConfig, plan_jobs
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
