"""Manifests (yaml / csv / parquet), validation errors and clip planning."""

from __future__ import annotations

from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
import yaml

from ingest_media import make_video
from vid2sim.factory.ingest.clips import ClipsConfig, plan_clips, split_windows
from vid2sim.factory.ingest.clip_list import load_manifest, parse_row
from vid2sim.factory.ingest.sources import resolve_source
from vid2sim.factory.runtime.stage_cache import StageError

ROWS = [
    {"source": "walk.mp4", "licence": "CC-BY-4.0", "start": 0.0, "end": 1.5, "group": "g1",
     "city": "Lund", "weather": "overcast", "capture_height": 1.6},
    {"source": "walk.mp4", "licence": "CC-BY-4.0", "city": "Lund"},
]


def _write(path: Path, rows: list[dict]) -> Path:
    if path.suffix == ".yaml":
        path.write_text(yaml.safe_dump({"sources": rows}))
    elif path.suffix == ".csv":
        cols = sorted({k for r in rows for k in r})
        lines = [",".join(cols)] + [",".join(str(r.get(c, "")) for c in cols) for r in rows]
        path.write_text("\n".join(lines) + "\n")
    else:
        cols = sorted({k for r in rows for k in r})
        pq.write_table(pa.Table.from_pylist([{c: r.get(c) for c in cols} for r in rows]), path)
    return path


@pytest.mark.parametrize("suffix", [".yaml", ".csv", ".parquet"])
def test_formats_agree(tmp_path: Path, suffix: str) -> None:
    rows = load_manifest(_write(tmp_path / f"m{suffix}", ROWS))
    assert len(rows) == 2
    a, b = rows
    assert a.window == (0.0, 1.5) and a.group == "g1" and a.capture_height == 1.6
    assert a.tags["city"] == "Lund" and a.tags["weather"] == "overcast" and a.tags["licence"] == "CC-BY-4.0"
    assert Path(a.source) == tmp_path / "walk.mp4"  # relative to the manifest's folder
    assert b.window is None and b.group == "walk" and b.capture_height == 1.5


def test_nested_tags_and_uri(tmp_path: Path) -> None:
    row = parse_row({"source": "https://example.org/a/b.mp4", "tags": {"licence": "MIT", "city": "X"}}, 0)
    assert row.licence == "MIT" and row.tags["city"] == "X" and row.source.startswith("https://")
    assert row.group == "b"


@pytest.mark.parametrize("suffix", [".yaml", ".csv", ".parquet"])
def test_row_with_missing_fields(tmp_path: Path, suffix: str) -> None:
    bad = ROWS + [{"city": "Lund", "licence": "", "source": ""}]
    path = _write(tmp_path / f"m{suffix}", bad)
    before = sorted(tmp_path.iterdir())
    with pytest.raises(StageError) as e:
        load_manifest(path)
    assert e.value.stage == "manifest" and e.value.reason == "missing_fields"
    assert "row 2" in e.value.detail and "source" in e.value.detail and "licence" in e.value.detail
    assert sorted(tmp_path.iterdir()) == before  # nothing written


@pytest.mark.parametrize("rec,reason", [
    ({"source": "a.mp4", "licence": "MIT", "start": 3, "end": 2}, "bad_window"),
    ({"source": "a.mp4", "licence": "MIT", "start": 3}, "bad_window"),
    ({"source": "a.mp4", "licence": "MIT", "capture_height": "tall"}, "bad_value"),
])
def test_bad_values(rec: dict, reason: str) -> None:
    with pytest.raises(StageError) as e:
        parse_row(rec, 0)
    assert e.value.reason == reason


def test_unknown_format_and_empty(tmp_path: Path) -> None:
    (tmp_path / "m.json").write_text("[]")
    with pytest.raises(StageError) as e:
        load_manifest(tmp_path / "m.json")
    assert e.value.reason == "unknown_format"
    (tmp_path / "m.yaml").write_text("sources: []\n")
    with pytest.raises(StageError) as e:
        load_manifest(tmp_path / "m.yaml")
    assert e.value.reason == "empty_manifest"


def test_split_windows() -> None:
    assert split_windows(10.5) == [(0.0, 10.5)]  # shorter than 15 s: one clip
    assert split_windows(40.0) == [(0.0, 15.0), (15.0, 30.0), (30.0, 40.0)]
    assert split_windows(32.0) == [(0.0, 15.0), (15.0, 32.0)]  # a 2 s tail is merged
    assert split_windows(6.0, clip_seconds=2.0) == [(0.0, 2.0), (2.0, 4.0), (4.0, 6.0)]
    assert split_windows(0.0) == []


def test_plan_clips(tmp_path: Path) -> None:
    video = make_video(tmp_path / "walk.mp4", n=90, fps=30)  # 3 s
    rows = load_manifest(_write(tmp_path / "m.yaml", ROWS))
    src = resolve_source(rows[0].source)
    one = plan_clips(rows[0], src)
    assert len(one) == 1 and one[0].window == (0.0, 1.5) and one[0].capture_height == 1.6
    cut = plan_clips(rows[1], src, ClipsConfig(clip_seconds=1.0, min_seconds=0.5))
    assert [c.window for c in cut] == [(0.0, 1.0), (1.0, 2.0), (2.0, 3.0)]
    assert len({c.clip_id for c in cut}) == 3 and all(c.group == "walk" for c in cut)
    assert video.exists()


def test_plan_manifest_isolates_bad_sources(tmp_path: Path) -> None:
    import socket

    from vid2sim.factory.ingest.clips import plan_manifest

    with socket.socket() as sock:  # a loopback port with nobody listening
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    make_video(tmp_path / "walk.mp4", n=60, fps=30)
    rows = ROWS + [{"source": "gone.mp4", "licence": "MIT"},
                   {"source": f"http://127.0.0.1:{port}/x.mp4", "licence": "MIT"}]
    clips, failed = plan_manifest(_write(tmp_path / "m.yaml", rows), cache_dir=tmp_path / "cache")
    assert [c.window for c in clips] == [(0.0, 1.5), (0.0, 2.0)]
    assert [e.reason for _, e in failed] == ["missing_source", "unreachable_uri"]
