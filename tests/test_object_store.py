"""The work store on a real S3 endpoint (moto server) and a local folder: folders round-trip,
the marker is written last, and a step run by the runner on one node's scratch resumes on
another's."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import pytest
from cluster_fixtures import s3_server

from vid2sim.factory.ingest.clips import ClipSpec
from vid2sim.factory.ingest.sources import Source
from vid2sim.factory.runtime.config import ClipJob, PipelineConfig
from vid2sim.factory.runtime.object_store import MARKER, ObjectStore
from vid2sim.factory.runtime.runner import clip_work, run_step
from vid2sim.factory.runtime.stage_cache import StageWork, is_done, mark_done
from vid2sim.factory.runtime.staging import local_clip_dir
from vid2sim.factory.runtime.steps.base import Step, StepOutputs


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


@dataclass(frozen=True)
class Written(StepOutputs):
    """The folder of a test step."""


@dataclass(frozen=True)
class FromClip:
    clip: ClipSpec


@dataclass(frozen=True)
class AfterCount:
    count: Written


def _writes(name: str, text: str):
    """A step's work: write `text` to `name` in its folder."""
    def build(out: Path) -> dict:
        (out / name).write_text(text)
        return {}
    return build


def _count(conf: None, inputs: FromClip) -> StageWork:
    """A real step: writes a file of its own output."""
    return StageWork("count", 1, conf, (), _writes("frames.txt", "frames"))


def _read(conf: None, inputs: AfterCount) -> StageWork:
    text = (inputs.count.dir / "frames.txt").read_text() + "+masks"
    return StageWork("read", 1, conf, (inputs.count.key,), _writes("masks.txt", text))


def _source(conf: None, inputs: FromClip) -> StageWork:
    """Records where the clip's source was found (it must be this node's own copy)."""
    return StageWork("source", 1, conf, (), _writes("source.txt", str(inputs.clip.source.path)))


def _step(name: str, inputs: type, work) -> Step:
    return Step(name, 1, inputs, Written, lambda conf, job: None, work)


def _job(clip_id: str) -> ClipJob:
    return ClipJob(ClipSpec(clip_id, Source("video", Path("v.mp4"), "v.mp4", "c" * 64), None, "g"), "s", "CC0")


def test_steps_on_two_scratch_dirs_share_only_the_store(s3, tmp_path, monkeypatch):
    work = clip_work(_job("clip0"), PipelineConfig(), s3.uri(f"w-{tmp_path.name}"))
    monkeypatch.setenv("VID2SIM_SCRATCH", str(tmp_path / "node-a"))
    work = run_step(_step("count", FromClip, _count), work)
    assert work.outputs["count"] == Written(Path("count"))  # relative: valid on any node
    monkeypatch.setenv("VID2SIM_SCRATCH", str(tmp_path / "node-b"))
    work = run_step(_step("read", AfterCount, _read), work)
    node_b = local_clip_dir(work.workdir, "clip0")
    assert str(tmp_path / "node-b") in str(node_b)
    assert (node_b / work.outputs["read"].dir / "masks.txt").read_text() == "frames+masks"
    store = ObjectStore(work.workdir)
    assert store.read_bytes("clip0/read/masks.txt") == b"frames+masks"
    assert not (tmp_path / "node-a" / node_b.relative_to(tmp_path / "node-b") / "read").exists()


def test_uri_source_is_fetched_by_the_node_that_runs_the_step(s3, tmp_path, monkeypatch):
    import shutil

    import pyarrow.fs as pafs
    from ingest_media import make_video

    from vid2sim.factory.runtime.pipeline import plan_jobs, preset, rows_from_inputs

    video = make_video(tmp_path / "v.mp4", n=20)
    fs, path = pafs.FileSystem.from_uri(s3.uri("videos/v.mp4"))
    pafs.copy_files(str(video), path, destination_filesystem=fs)
    conf = preset("fast")
    jobs, failed = plan_jobs(rows_from_inputs([s3.uri("videos/v.mp4")], "CC0"), conf, tmp_path / "driver-cache")
    assert not failed and len(jobs) == 1
    shutil.rmtree(tmp_path / "driver-cache")  # the driver's copy is not on the worker node
    work = clip_work(jobs[0], conf, s3.uri(f"w-{tmp_path.name}"))
    assert work.on_store and work.workdir.startswith("s3://")
    monkeypatch.setenv("VID2SIM_SCRATCH", str(tmp_path / "node-b"))
    work = run_step(_step("source", FromClip, _source), work)
    store = ObjectStore(work.workdir)
    used = store.read_bytes(f"{work.clip_id}/{work.outputs['source'].dir}/source.txt").decode()
    assert used.startswith(str(tmp_path / "node-b")) and Path(used).read_bytes() == video.read_bytes()
