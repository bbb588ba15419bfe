"""The step runner is the one code that checks and writes stage markers (`stage.json`).

- The cache keys are those of existing work folders: each step's key from fixed inputs
  (tests/step_inputs.py: folders marked done with known keys) is the one the stage code computed
  before the runner took the markers over (`fast` and `paper` presets).
- A failed run leaves no marker, and no folder when it wrote nothing; recon resumes a
  checkpoint of its own key and empties a folder left by another.
- The back half on a real local work folder (a ray-cast PosedClip -> recon -> meshing ->
  walkable -> bundle, tiny settings, no Ray): the marker is the last file of every folder; an
  unchanged re-run rewrites nothing; a changed config of meshing, or a bumped walkable version,
  reruns exactly that step and the ones after it, never those before. The slow variant does the
  same on the synthetic street rendered to video, from decode on.
- The same back half on an S3 work store (a moto server), each step on a fresh node's scratch:
  in the order the server received the writes, every step's marker is the last object written
  into its folder; an unchanged re-run writes nothing (the slow variant: every step, from decode).
"""

from __future__ import annotations

import json
import urllib.request
from dataclasses import replace
from pathlib import Path
from urllib.parse import parse_qs, unquote, urlsplit

import pytest

from cluster_fixtures import s3_server
from recon_toy import make_toy_clip
from step_inputs import KEYS, finished_outputs, job, step_inputs
from vid2sim.factory.geometry import meshing as meshing_stage
from vid2sim.factory.geometry import walkable as walkable_stage
from vid2sim.factory.ingest import decode, masks
from vid2sim.factory.ingest.clips import ClipSpec
from vid2sim.factory.ingest.sources import Source, resolve_source
from vid2sim.factory.recon import config as recon_config
from vid2sim.factory.recon import data as recon_data
from vid2sim.factory.recon import trainer
from vid2sim.factory.recon.data import load_views
from vid2sim.factory.runtime.config import ClipJob, PipelineConfig, preset
from vid2sim.factory.runtime.object_store import ObjectStore
from vid2sim.factory.runtime.runner import ClipWork, cache_key, clip_work, run_stage, run_step
from vid2sim.factory.runtime.stage_cache import MARKER, StageError, StageWork, load_record, stage_key
from vid2sim.factory.runtime.staging import local_clip_dir
from vid2sim.factory.runtime.steps import STEPS, bundle, metric
from vid2sim.factory.sfm import metric as metric_stage
from vid2sim.factory.sfm import sfm
from vid2sim.factory.sfm.posed import PosedClip
from vid2sim.versioning import config_hash

BY_NAME = {s.name: s for s in STEPS}

def _keys_before(conf: PipelineConfig, clip_job: ClipJob) -> dict[str, str]:
    """Each step's cache key for tests/step_inputs.py as the stage code computed it before the
    runner wrote the markers (checked equal to that code's keys, both presets, when it moved)."""
    c, spec, k = conf.resolved(), clip_job.spec, KEYS
    tags = {"scene_id": clip_job.scene_id, "licence": clip_job.licence, "tags": spec.tags}
    return {
        "decode": stage_key("decode", decode.STAGE_VERSION, replace(conf.decode, workers=1), spec.source.sha256,
                            list(spec.window)),
        "masks": stage_key("masks", masks.STAGE_VERSION, conf.masks, k["decode"], conf.masks.segmenter_path),
        "sfm": stage_key("sfm", sfm.STAGE_VERSION, c.sfm, k["decode"], k["masks"]),
        "metric": stage_key("metric", metric_stage.STAGE_VERSION,
                            replace(c.metric, capture_height_m=spec.capture_height), k["sfm"]),
        "recon": stage_key("recon", recon_data.STAGE_VERSION, conf.recon, k["metric"]),
        "meshing": stage_key("meshing", meshing_stage.STAGE_VERSION, conf.meshing, config_hash(k["recon"], conf.views)),
        "walkable": stage_key("walkable", walkable_stage.STAGE_VERSION, conf.walkable,
                              config_hash(k["meshing"], k["metric"], conf.corridor)),
        "bundle": stage_key("bundle", bundle.VERSION, tags, k["metric"], k["recon"], k["meshing"], k["walkable"]),
    }


@pytest.mark.parametrize("name", ["fast", "paper"])
def test_every_step_keeps_the_cache_key_of_existing_work_folders(tmp_path, name):
    clip_job = job(tmp_path)
    outputs = finished_outputs(tmp_path, STEPS)
    conf = preset(name)
    keys = {s.name: cache_key(s.work(s.configure(conf, clip_job), step_inputs(s, clip_job, outputs))) for s in STEPS}
    assert keys == _keys_before(conf, clip_job)


def _failing(out: Path) -> dict:
    (out / "partial.txt").write_text("half done")
    raise StageError("toy", "broken", "fails after writing a file")


def _refusing(out: Path) -> dict:
    raise StageError("toy", "bad_input", "fails before writing anything")


def test_a_failed_run_leaves_no_marker_and_no_empty_folder(tmp_path):
    with pytest.raises(StageError, match="broken"):
        run_stage(StageWork("toy", 1, {}, (), _failing), tmp_path / "a")
    assert (tmp_path / "a" / "partial.txt").is_file() and not (tmp_path / "a" / MARKER).exists()
    with pytest.raises(StageError, match="bad_input"):
        run_stage(StageWork("toy", 1, {}, (), _refusing), tmp_path / "b")
    assert not (tmp_path / "b").exists()


def test_recon_resumes_a_checkpoint_of_its_own_key_and_drops_another(tmp_path):
    toy = make_toy_clip(tmp_path / "toy", n_frames=9, width=48, height=36, n_points=800)
    conf = replace(recon_config.baseline(_tiny_recon()), checkpoint_every=10)
    views = load_views(PosedClip.load(toy), conf.max_width)
    for key, resumed in ((cache_key(trainer.work(conf, toy)), 10), ("another-key", 0)):
        out = tmp_path / f"recon-{resumed}"
        out.mkdir()
        trainer.train(conf, PosedClip.load(toy), views, {}, out, key=key)  # a run killed after its checkpoint
        (out / "stray.txt").write_text("left by the killed run")
        run_stage(trainer.work(conf, toy), out)
        assert json.loads((out / "metrics.json").read_text())["resumed_from"] == resumed
        assert (out / "stray.txt").exists() == bool(resumed)  # another key's folder was emptied


# ----------------------------------------------------------------------------- a real chain


def _state(folder: Path) -> dict[str, tuple[int, int]]:
    """{path in the folder: (mtime_ns, size)} of every file."""
    return {p.relative_to(folder).as_posix(): (p.stat().st_mtime_ns, p.stat().st_size)
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture
def at_marker(monkeypatch) -> dict[str, dict]:
    """{step: its folder's files at the moment the runner wrote the marker} (the last write)."""
    from vid2sim.factory.runtime import runner

    seen: dict[str, dict] = {}
    real = runner.mark_done

    def mark_done(out_dir, stage, *args):
        seen[stage] = _state(Path(out_dir))
        return real(out_dir, stage, *args)

    monkeypatch.setattr(runner, "mark_done", mark_done)
    return seen


def _chain(work: ClipWork, names: tuple[str, ...], at_marker: dict) -> dict[str, tuple[str, int]]:
    """Run the steps through the runner; check the marker is the last file of each folder written
    now; returns {step: (marker key, marker mtime_ns)}."""
    at_marker.clear()
    for name in names:
        work = run_step(BY_NAME[name], work)
    clip_dir = Path(work.workdir) / work.clip_id
    for name, before in at_marker.items():
        after = _state(clip_dir / name)
        assert MARKER not in before and {k: v for k, v in after.items() if k != MARKER} == before
        assert after[MARKER][0] >= max(t for t, _ in before.values())
    return {n: (load_record(clip_dir / n).key, (clip_dir / n / MARKER).stat().st_mtime_ns) for n in names}


def _rerun(before: dict, after: dict) -> set[str]:
    return {s for s in before if before[s] != after[s]}


def _reruns_exactly_downstream(work: ClipWork, names: tuple[str, ...], at_marker: dict, monkeypatch,
                               changed: PipelineConfig, step_of_config: str, bumped) -> None:
    """Unchanged: nothing reruns; `changed` config: `step_of_config` and after; `bumped` version
    (module, name of the step): that step and after."""
    first = _chain(work, names, at_marker)
    assert set(at_marker) == set(names)
    assert _chain(work, names, at_marker) == first and not at_marker  # nothing rewritten
    second = _chain(replace(work, conf=changed), names, at_marker)
    assert _rerun(first, second) == set(names[names.index(step_of_config):]) == set(at_marker)
    module, step_name = bumped
    monkeypatch.setattr(module, "STAGE_VERSION", module.STAGE_VERSION + 1)
    third = _chain(replace(work, conf=changed), names, at_marker)
    assert _rerun(second, third) == set(names[names.index(step_name):]) == set(at_marker)


BACK_HALF = ("recon", "meshing", "walkable", "bundle")


def _tiny_recon() -> recon_config.ReconConfig:
    conf = recon_config.preset("fast", iterations=20, max_width=40, checkpoint_every=1000, max_init_points=600)
    conf.densify = replace(conf.densify, start_iter=5, stop_iter=15, every=5, max_gaussians=2000)
    conf.prior = replace(conf.prior, num_planes=16)
    return conf


def _toy_back_half(tmp_path: Path, workdir: str | Path) -> ClipWork:
    """A clip entering the chain at a ray-cast PosedClip (tiny settings), worked in `workdir`."""
    toy = make_toy_clip(tmp_path / "toy", n_frames=9, width=48, height=36, n_points=800)
    conf = PipelineConfig(recon=recon_config.baseline(_tiny_recon()),
                          views=replace(PipelineConfig().views, scale=1.0, every=1, min_alpha=0.1))
    (tmp_path / "v.mp4").write_bytes(b"")  # posed already: never decoded (a work store checks it is here)
    source = Source("video", tmp_path / "v.mp4", "file:///v.mp4", "a" * 64)
    clip = ClipJob(ClipSpec("clip0", source, (0.0, 0.8), "g"), "toy-1", "CC0")
    return clip_work(clip, conf, workdir, metric=metric.Outputs(toy))


def test_a_changed_step_reruns_it_and_the_steps_after_it_not_before(tmp_path, at_marker, monkeypatch):
    work = _toy_back_half(tmp_path, tmp_path / "work")
    conf = work.conf
    changed = replace(conf, meshing=replace(conf.meshing, voxel_m=conf.meshing.voxel_m * 1.5))
    _reruns_exactly_downstream(work, BACK_HALF, at_marker, monkeypatch, changed, "meshing",
                               (walkable_stage, "walkable"))


@pytest.mark.slow
def test_the_whole_chain_on_the_synthetic_street_reruns_exactly_downstream(tmp_path, at_marker, monkeypatch):
    from vid2sim.factory.synthetic import generate_street, render_video
    from vid2sim.factory.synthetic import preset as street_preset

    street = street_preset("demo", seed=1, duration_s=4.0, write_depth=False)
    video = render_video(generate_street(street), street, tmp_path / "render").video
    conf = replace(preset("fast"), recon=_tiny_recon())
    clip = ClipJob(ClipSpec("clip0", resolve_source(video), None, "g"), "street-1", "CC0")
    work = clip_work(clip, conf, tmp_path / "work")
    names = tuple(s.name for s in STEPS)
    changed = replace(conf, meshing=replace(conf.meshing, voxel_m=conf.meshing.voxel_m * 1.5))
    _reruns_exactly_downstream(work, names, at_marker, monkeypatch, changed, "meshing", (walkable_stage, "walkable"))


# ----------------------------------------------------------------------------- on the work store


@pytest.fixture
def s3_log(tmp_path, monkeypatch):
    """A moto S3 server (tests/cluster_fixtures.py) that logs every request it receives, in the
    order received (moto's recorder, on the server side), with the clients pointed at it."""
    log = tmp_path / "s3-requests.jsonl"
    monkeypatch.setenv("MOTO_RECORDER_FILEPATH", str(log))  # the server process reads it at start
    with s3_server() as server:
        for k, v in server.env.items():
            monkeypatch.setenv(k, v)
        start = urllib.request.Request(f"{server.endpoint}/moto-api/recorder/start-recording", method="POST")
        urllib.request.urlopen(start, timeout=10).read()
        yield server, log


def _objects_written(log: Path, bucket: str) -> list[str]:
    """Keys of the objects the S3 server was asked to store, in the order it received them: a
    PutObject, or the CompleteMultipartUpload that makes a multipart upload's object appear
    (parts and the empty 'folder/' placeholders left out)."""
    keys = []
    for line in log.read_text().splitlines() if log.is_file() else []:
        request = json.loads(line)
        url = urlsplit(request["url"])
        query = parse_qs(url.query, keep_blank_values=True)
        stored = (request["method"] == "PUT" and not query) or (request["method"] == "POST" and "uploadId" in query)
        key = unquote(url.path).removeprefix(f"/{bucket}/")
        if stored and not key.endswith("/"):
            keys.append(key)
    return keys


def _store_chain(work: ClipWork, names: tuple[str, ...], s3_log, tmp_path: Path, monkeypatch) -> None:
    """Run the steps with an S3 work folder through the runner's store path, each on a fresh node
    scratch, so it fetches the folders it reads from the store and uploads its own. Checked is
    the order in which the S3 server received the writes (not their timestamps): each step's
    folder gets its marker once, after every other object of the folder, and nothing after it.
    An unchanged re-run, again on fresh nodes, writes nothing."""
    server, log = s3_log
    for i, name in enumerate(names):
        monkeypatch.setenv("VID2SIM_SCRATCH", str(tmp_path / f"node-{name}"))
        work = run_step(BY_NAME[name], work)
        node = local_clip_dir(work.workdir, work.clip_id)
        assert all((node / before / MARKER).is_file() for before in names[:i])  # fetched from the store
    written, store = _objects_written(log, server.bucket), ObjectStore(work.workdir)
    prefix = work.workdir.removeprefix(f"s3://{server.bucket}/")
    for name in names:
        folder = f"{prefix}/{work.clip_id}/{name}/"
        mine = [k.removeprefix(folder) for k in written if k.startswith(folder)]
        assert mine[-1] == MARKER and mine.count(MARKER) == 1, f"{name}: objects written {mine}"
        assert sorted(mine) == sorted(store.list_files(f"{work.clip_id}/{name}"))
    for name in names:
        monkeypatch.setenv("VID2SIM_SCRATCH", str(tmp_path / f"again-{name}"))
        work = run_step(BY_NAME[name], work)
    assert _objects_written(log, server.bucket) == written


def test_on_the_work_store_the_marker_is_the_last_object_written_of_every_step(tmp_path, s3_log, monkeypatch):
    """The back half (recon -> meshing -> walkable -> bundle) on S3, see `_store_chain`."""
    _store_chain(_toy_back_half(tmp_path, s3_log[0].uri("work")), BACK_HALF, s3_log, tmp_path, monkeypatch)


@pytest.mark.slow
def test_on_the_work_store_the_whole_chain_writes_every_marker_last(tmp_path, s3_log, monkeypatch):
    """Every step, from decode on, on the synthetic street rendered to video, on S3."""
    from vid2sim.factory.synthetic import generate_street, render_video
    from vid2sim.factory.synthetic import preset as street_preset

    street = street_preset("demo", seed=1, duration_s=4.0, write_depth=False)
    video = render_video(generate_street(street), street, tmp_path / "render").video
    clip = ClipJob(ClipSpec("clip0", resolve_source(video), None, "g"), "street-1", "CC0")
    work = clip_work(clip, replace(preset("fast"), recon=_tiny_recon()), s3_log[0].uri("work"))
    _store_chain(work, tuple(s.name for s in STEPS), s3_log, tmp_path, monkeypatch)
