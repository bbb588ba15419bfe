"""The work store on a real S3 endpoint (moto server) and a local folder: folders round-trip,
the marker is written last, and a stage run on one node's scratch resumes on another's."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cluster_fixtures import s3_server

from vid2sim.factory.runtime.object_store import MARKER, ObjectStore
from vid2sim.factory.runtime.staging import OnStore, local_clip_dir
from vid2sim.factory.runtime.stage_cache import is_done, mark_done


@pytest.fixture(scope="module")
def s3():
    with s3_server() as server:
        mp = pytest.MonkeyPatch()
        for k, v in server.env.items():
            mp.setenv(k, v)
        yield server
        mp.undo()


@pytest.fixture(params=["s3", "local"])
def store(request, s3, tmp_path) -> ObjectStore:
    root = s3.uri(f"work-{tmp_path.name}") if request.param == "s3" else str(tmp_path / "store")
    return ObjectStore(root)


def _folder(path: Path) -> Path:
    (path / "sub").mkdir(parents=True)
    (path / "a.bin").write_bytes(bytes(range(256)) * 100)
    (path / "sub" / "b.txt").write_text("b")
    return path


def test_round_trip_with_marker_last(store, tmp_path):
    src = _folder(tmp_path / "src")
    assert store.marker("clip/decode") is None
    assert store.put_dir(src, "clip/decode") == 2
    assert store.marker("clip/decode") is None  # no marker in the folder: not done
    mark_done(src, "decode", "k1", {}, 0.1)
    store.put_dir(src, "clip/decode")
    assert json.loads(store.marker("clip/decode"))["key"] == "k1"
    assert sorted(store.list_files("clip/decode")) == sorted([MARKER, "a.bin", "sub/b.txt"])
    dst = tmp_path / "dst"
    assert store.get_dir("clip/decode", dst) == 3
    assert (dst / "a.bin").read_bytes() == (src / "a.bin").read_bytes()
    assert is_done(dst, "k1")
    store.write_bytes("x/y.json", b"{}")
    assert store.exists("x/y.json") and store.read_bytes("x/y.json") == b"{}"
    assert not store.exists("x/nope")


def _count_stage(ctx: dict) -> dict:
    """A real stage: cached by its marker; counts its runs in a file of its own output."""
    out = Path(ctx["clip_dir"]) / "decode"
    if not is_done(out, "key-1"):
        out.mkdir(parents=True, exist_ok=True)
        (out / "frames.txt").write_text("frames")
        mark_done(out, "decode", "key-1", {}, 0.0)
    return {"decode_dir": str(out)}


def _read_stage(ctx: dict) -> dict:
    out = Path(ctx["clip_dir"]) / "masks"
    out.mkdir(parents=True, exist_ok=True)
    (out / "masks.txt").write_text(Path(ctx["decode_dir"], "frames.txt").read_text() + "+masks")
    mark_done(out, "masks", "key-2", {}, 0.0)
    return {"masks_dir": str(out)}


def test_stages_on_two_scratch_dirs_share_only_the_store(s3, tmp_path, monkeypatch):
    ctx = {"work_uri": s3.uri(f"w-{tmp_path.name}"), "clip_id": "clip0"}
    monkeypatch.setenv("VID2SIM_SCRATCH", str(tmp_path / "node-a"))
    added = OnStore(_count_stage)(ctx)
    assert added == {"decode_dir": "decode"}  # relative: valid on any node
    monkeypatch.setenv("VID2SIM_SCRATCH", str(tmp_path / "node-b"))
    out = OnStore(_read_stage)({**ctx, **added})
    node_b = local_clip_dir(ctx["work_uri"], "clip0")
    assert str(tmp_path / "node-b") in str(node_b)
    assert (node_b / out["masks_dir"] / "masks.txt").read_text() == "frames+masks"
    store = ObjectStore(ctx["work_uri"])
    assert store.read_bytes("clip0/masks/masks.txt") == b"frames+masks"
    assert not (tmp_path / "node-a" / node_b.relative_to(tmp_path / "node-b") / "masks").exists()


def _source_stage(ctx: dict) -> dict:
    """Records where the clip's source was found (it must be this node's own copy)."""
    out = Path(ctx["clip_dir"]) / "decode"
    out.mkdir(parents=True, exist_ok=True)
    (out / "source.txt").write_text(str(ctx["job"].spec.source.path))
    mark_done(out, "decode", "k", {}, 0.0)
    return {"decode_dir": str(out)}


def test_uri_source_is_fetched_by_the_node_that_runs_the_stage(s3, tmp_path, monkeypatch):
    import shutil

    import pyarrow.fs as pafs
    from ingest_media import make_video

    from vid2sim.factory.runtime.pipeline import clip_context, plan_jobs, preset, rows_from_inputs

    video = make_video(tmp_path / "v.mp4", n=20)
    fs, path = pafs.FileSystem.from_uri(s3.uri("videos/v.mp4"))
    pafs.copy_files(str(video), path, destination_filesystem=fs)
    conf = preset("fast")
    jobs, failed = plan_jobs(rows_from_inputs([s3.uri("videos/v.mp4")], "CC0"), conf, tmp_path / "driver-cache")
    assert not failed and len(jobs) == 1
    shutil.rmtree(tmp_path / "driver-cache")  # the driver's copy is not on the worker node
    ctx = clip_context(jobs[0], conf, 1, s3.uri(f"w-{tmp_path.name}"))
    assert "clip_dir" not in ctx and ctx["work_uri"].startswith("s3://")
    monkeypatch.setenv("VID2SIM_SCRATCH", str(tmp_path / "node-b"))
    out = OnStore(_source_stage)(ctx)
    store = ObjectStore(ctx["work_uri"])
    used = store.read_bytes(f"{ctx['clip_id']}/{out['decode_dir']}/source.txt").decode()
    assert used.startswith(str(tmp_path / "node-b")) and Path(used).read_bytes() == video.read_bytes()
