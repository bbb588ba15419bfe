"""The registry on a real S3 endpoint (moto's server on 127.0.0.1): concurrent committers in
separate processes lose nothing (delta-rs conditional put), and unsafe rename is refused."""

from __future__ import annotations

import multiprocessing as mp

import pytest
from cluster_fixtures import s3_server
from registry_fixtures import concurrent_worker, make_bundle

from vid2sim.registry import Registry
from vid2sim.registry.manifest import safe_storage_options

N_PROCS, N_EACH = 3, 3


@pytest.fixture
def s3(monkeypatch):
    with s3_server() as server:
        for k, v in server.env.items():
            monkeypatch.setenv(k, v)
        yield server


def test_storage_options_are_made_safe():
    assert safe_storage_options("s3://b/reg/manifests") == {"conditional_put": "etag"}
    assert safe_storage_options("/tmp/reg/manifests", None) is None
    locked = {"AWS_S3_LOCKING_PROVIDER": "dynamodb", "DELTA_DYNAMO_TABLE_NAME": "delta_log"}
    assert safe_storage_options("s3://b/m", locked) == locked
    with pytest.raises(ValueError, match="UNSAFE_RENAME"):
        safe_storage_options("s3://b/m", {"AWS_S3_ALLOW_UNSAFE_RENAME": "true"})


@pytest.mark.timeout(300)
def test_concurrent_committers_on_s3_lose_nothing(s3, tmp_path):
    root = s3.uri("registry")
    reg = Registry(root)
    reg.add(make_bundle(tmp_path / "shared", "shared"))
    common = str(make_bundle(tmp_path / "common", "common", seed=99))
    jobs = [[str(make_bundle(tmp_path / f"b{w}-{i}", f"w{w}-s{i}", seed=w * 10 + i)) for i in range(N_EACH)]
            for w in range(N_PROCS)]
    with mp.get_context("spawn").Pool(N_PROCS) as pool:  # children inherit the AWS_* environment
        results = pool.starmap(concurrent_worker, [(root, w, jobs[w], common, "shared", 4)
                                                   for w in range(N_PROCS)])
    assert sum(len(r) for r in results) == 2 * N_PROCS * N_EACH

    reg = Registry(root)
    rows = reg.history()
    keys = [(r.scene_id, r.version) for r in rows]
    assert len(keys) == len(set(keys)), "duplicate (scene_id, version)"
    shared = reg.history("shared")
    assert [r.version for r in shared] == list(range(1, 2 + N_PROCS * N_EACH))  # no tag lost
    assert set(shared[-1].tags) == {f"w{w}-{i}" for w in range(N_PROCS) for i in range(N_EACH)}
    assert len(reg.history("common")) == 1
    assert len(reg.list()) == 2 + N_PROCS * N_EACH
    assert reg.verify() == []
    assert reg.manifest.storage_options == {"conditional_put": "etag"}


@pytest.mark.timeout(300)
@pytest.mark.parametrize("damage", ["missing", "empty"])
def test_log_gap_on_s3_is_lost_history(s3, tmp_path, damage):
    """The log continuity check runs on an object store too: a deleted or emptied middle commit
    file is named by reads, verify, time travel, gc and add, never read as a shorter history."""
    import pyarrow.fs as pafs

    from vid2sim.registry.blobs import arrow_filesystem
    from vid2sim.registry.errors import HistoryLost

    root = s3.uri("registry")
    reg = Registry(root)  # versions: 0 create, 1..3 one add each
    for i in range(3):
        reg.add(make_bundle(tmp_path / f"b{i}", f"s{i}", seed=i))
    assert reg.verify() == [] and [r.scene_id for r in reg.list()] == ["s0", "s1", "s2"]
    fs, base = arrow_filesystem(f"{root}/manifests/_delta_log")
    entry = f"{base}/{2:020d}.json"
    assert fs.get_file_info(entry).type == pafs.FileType.File
    if damage == "missing":
        fs.delete_file(entry)
    else:
        with fs.open_output_stream(entry) as f:
            f.write(b"")
    why = "version 2 is missing" if damage == "missing" else "version 2 is empty"
    fresh = Registry(root)
    for read in (fresh.list, fresh.history, lambda: fresh.list(as_of=1)):
        with pytest.raises(HistoryLost, match=why):
            read()
    assert any(why in p for p in fresh.verify())
    with pytest.raises(HistoryLost, match="gc refused"):
        fresh.gc(grace_s=0)
    with pytest.raises(HistoryLost, match=why):  # nothing is committed on top of lost history
        fresh.add(make_bundle(tmp_path / "b9", "s9", seed=9))
    assert fs.get_file_info(f"{base}/{4:020d}.json").type == pafs.FileType.NotFound
