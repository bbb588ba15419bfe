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
