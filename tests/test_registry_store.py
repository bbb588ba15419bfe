"""Registry API on real files: round trip, no-op re-add, mutations, time travel, verify, gc."""

from __future__ import annotations

import json
import os
import time
from datetime import datetime, timezone

import numpy as np
import pyarrow.parquet as pq
import pytest
from registry_fixtures import make_bundle, write_box_ply

from vid2sim.registry import BundleError, Registry, RegistryError, SceneNotFound, validate_bundle
from vid2sim.registry.blobs import ArrowBlobStore, sha256_file


@pytest.fixture
def reg(tmp_path):
    return Registry(tmp_path / "reg")


def test_save_then_load_round_trip(tmp_path, reg):
    src = make_bundle(tmp_path / "b", "street-01", extras=True, tags=("city",))
    rec = reg.add(src)
    assert rec.ref == "street-01@1" and rec.status == "active" and rec.tags == ("city",)
    assert rec.num_splats == 300 and rec.num_frames == 16 and rec.num_test_frames == 2
    assert rec.walkable_area_m2 == pytest.approx(9.0)
    names = {a.name for a in rec.artifacts}
    assert {"scene.json", "splats.ply", "collision.ply", "walkable.npz", "cameras.parquet", "preview.png",
            "visual.ply", "colmap/points3D.txt"} == names
    out = reg.checkout("street-01", dest=tmp_path / "co")
    for name in names:  # byte-identical artifacts
        assert sha256_file(out / name) == sha256_file(src / name)
    info = validate_bundle(out)
    assert info.scene == json.loads((src / "scene.json").read_text())
    assert reg.checkout("street-01", dest=tmp_path / "co") == out  # finished checkout is reused
    assert reg.add(out).ref == "street-01@1"  # re-adding a checkout is a no-op (marker ignored)
    assert reg.scene_json("street-01")["scene_id"] == "street-01"
    again = Registry(str(reg.root)).show("street-01", 1)  # a fresh handle reads the same record
    assert again == rec


def test_identical_content_stored_once_and_readd_is_noop(tmp_path, reg):
    b = make_bundle(tmp_path / "b", "a")
    first = reg.add(b)
    v = reg.version
    assert reg.add(b) == first and reg.version == v  # no new commit
    make_bundle(tmp_path / "b2", "b")  # same collision mesh / cameras / walkable bytes as "a"
    reg.add(tmp_path / "b2")
    blobs = [x for x in reg.blobs.list() if not x.is_temp]
    assert len(blobs) == len(reg.referenced())
    shared = {a.sha256 for a in reg.show("a").artifacts} & {a.sha256 for a in reg.show("b").artifacts}
    assert shared  # e.g. collision.ply: stored once, referenced twice
    make_bundle(tmp_path / "b", "a", seed=7)  # new content -> version 2
    assert reg.add(b).ref == "a@2"


def test_mutations_append_versions_and_history(tmp_path, reg):
    reg.add(make_bundle(tmp_path / "b", "a"))
    assert reg.tag("a", "good", "night").ref == "a@2"
    assert reg.tag("a", "good").ref == "a@2"  # already tagged: no-op
    assert reg.untag("a", "night").tags == ("good",)
    dep = reg.deprecate("a", "blurry")
    assert (dep.ref, dep.status, dep.message) == ("a@4", "deprecated", "blurry")
    assert reg.list() == [] and [r.ref for r in reg.list(include_deprecated=True)] == ["a@4"]
    assert [r.event for r in reg.history("a")] == ["add", "tag", "untag", "deprecate"]
    assert reg.show("a", 2).tags == ("good", "night")  # old versions never rewritten
    with pytest.raises(SceneNotFound, match="nope"):
        reg.tag("nope", "x")
    with pytest.raises(RegistryError, match="invalid tag"):
        reg.tag("a", "bad tag")
    with pytest.raises(SceneNotFound, match="a@9"):
        reg.show("a", 9)


def test_time_travel_returns_old_state(tmp_path, reg):
    reg.add(make_bundle(tmp_path / "a", "a"))
    v1 = reg.version
    time.sleep(0.05)
    t1 = datetime.now(timezone.utc)
    time.sleep(0.05)
    reg.tag("a", "later")
    reg.add(make_bundle(tmp_path / "b", "b", seed=1))
    reg.deprecate("a", "bad")
    assert [r.scene_id for r in reg.list()] == ["b"]
    for as_of in (v1, str(v1), t1, t1.isoformat()):
        old = reg.list(as_of=as_of)
        assert [(r.ref, r.tags, r.status) for r in old] == [("a@1", (), "active")]
    assert reg.query("select count(*) as n from scenes", as_of=v1).column("n").to_pylist() == [1]
    with pytest.raises(ValueError, match="as-of"):
        reg.list(as_of="yesterday")


def test_query_sql(tmp_path, reg):
    reg.add(make_bundle(tmp_path / "a", "a", metrics={"psnr": 20.0}))
    reg.add(make_bundle(tmp_path / "b", "b", seed=1, metrics={"psnr": 30.0}))
    reg.tag("b", "x")
    t = reg.query("select scene_id, version from latest "
                  "where cast(json_extract(metrics, '$.psnr') as double) > 25 order by scene_id")
    assert t.to_pylist() == [{"scene_id": "b", "version": 2}]
    assert reg.query("select count(*) as n from scenes").column("n").to_pylist() == [3]
    with pytest.raises(RegistryError, match="query failed"):
        reg.query("select nope from scenes")


def test_verify_catches_corrupt_and_missing_blob(tmp_path, reg):
    rec = reg.add(make_bundle(tmp_path / "a", "a"))
    assert reg.verify() == []
    splats = rec.artifact("splats.ply").sha256
    p = reg.blobs.path(splats)
    data = bytearray(p.read_bytes())
    data[-1] ^= 0xFF
    p.write_bytes(bytes(data))
    problems = reg.verify()
    assert len(problems) == 1 and "corrupt" in problems[0] and splats in problems[0] and "a@1:splats.ply" in problems[0]
    with pytest.raises(RegistryError, match="corrupt"):
        reg.checkout("a", dest=tmp_path / "co")
    assert not (tmp_path / "co").exists()
    reg.blobs.path(rec.artifact("preview.png").sha256).unlink()
    problems = reg.verify()
    assert any("missing" in x and "a@1:preview.png" in x for x in problems)


def test_gc_removes_only_unreferenced(tmp_path, reg):
    reg.add(make_bundle(tmp_path / "a", "a"))
    b = make_bundle(tmp_path / "b", "b", seed=3)
    orphan_info = validate_bundle(b)
    reg._store_blobs(orphan_info)  # what a committer killed before its commit leaves behind
    (reg.blobs.root / "tmp").mkdir(exist_ok=True)
    (reg.blobs.root / "tmp" / "partial").write_bytes(b"half a blob")
    stale = time.time() - 2 * 3600  # names no writer: gc waits an hour whatever the grace
    os.utime(reg.blobs.root / "tmp" / "partial", (stale, stale))
    refs = reg.referenced()
    assert reg.gc(grace_s=3 * 3600) == []  # within the grace period nothing goes
    removed = reg.gc(grace_s=0)
    assert "tmp/partial" in removed
    assert removed and all(r.startswith("tmp/") or r not in refs for r in removed)
    assert {x.sha256 for x in reg.blobs.list()} == refs
    assert reg.verify() == []


def _bad_scene(key, value):
    def edit(b):
        s = json.loads((b / "scene.json").read_text())
        s[key] = value
        (b / "scene.json").write_text(json.dumps(s))
    return edit


def _drop_source_field(b):
    s = json.loads((b / "scene.json").read_text())
    del s["source"]["clip_end_s"]
    (b / "scene.json").write_text(json.dumps(s))


def _bad_cameras(b):
    t = pq.read_table(b / "cameras.parquet").drop_columns(["split"])
    pq.write_table(t, b / "cameras.parquet")


BAD_INPUTS = {
    "missing scene.json": (lambda b: (b / "scene.json").unlink(), "scene.json"),
    "unknown field": (_bad_scene("owner", "me"), "unknown field"),
    "missing field": (_drop_source_field, "clip_end_s"),
    "id ../x": (_bad_scene("scene_id", "../x"), "invalid scene_id"),
    "id /abs": (_bad_scene("scene_id", "/abs"), "invalid scene_id"),
    "id uppercase": (_bad_scene("scene_id", "Street"), "invalid scene_id"),
    "id empty": (_bad_scene("scene_id", ""), "invalid scene_id"),
    "ply without 3dgs": (lambda b: write_box_ply(b / "splats.ply"), "splats.ply.*3DGS"),
    "unreadable mesh": (lambda b: (b / "collision.ply").write_bytes(b"\x00garbage"), "collision.ply"),
    "walkable keys": (lambda b: np.savez(b / "walkable.npz", grid=np.ones((2, 2), np.uint8)), "walkable.npz.*origin"),
    "cameras schema": (_bad_cameras, "cameras.parquet.*split"),
}


@pytest.mark.parametrize("case", sorted(BAD_INPUTS))
def test_bad_input_rejected_nothing_written(tmp_path, case):
    edit, pattern = BAD_INPUTS[case]
    b = make_bundle(tmp_path / "b", "ok-id")
    edit(b)
    root = tmp_path / "reg"
    with pytest.raises(BundleError, match=pattern):
        Registry(root).add(b)
    assert not root.exists()  # not a blob, not a manifest


def test_file_uri_root(tmp_path):
    reg = Registry(f"file://{tmp_path / 'reg'}")
    reg.add(make_bundle(tmp_path / "a", "a"))
    assert [r.ref for r in Registry(str(tmp_path / "reg")).list()] == ["a@1"]  # same store, two spellings
    assert reg.verify() == []


def test_arrow_blob_store_on_fsspec_memory(tmp_path):
    """The blob store interface over a non-local filesystem (fsspec memory:// via pyarrow)."""
    from vid2sim.registry.blobs import arrow_filesystem

    fs, base = arrow_filesystem("memory://vid2sim-test/blobs")
    store = ArrowBlobStore(fs, base)
    f = tmp_path / "x.bin"
    f.write_bytes(b"hello" * 1000)
    sha, size = sha256_file(f)
    assert store.put_file(f, sha) and not store.put_file(f, sha)  # stored once
    assert store.exists(sha) and store.rehash(sha) == (sha, size)
    assert [b.sha256 for b in store.list()] == [sha]
    out = tmp_path / "y.bin"
    assert store.copy_to(sha, out) == (sha, size) and out.read_bytes() == f.read_bytes()
    store.delete(next(iter(store.list())))
    assert not store.exists(sha)
    with pytest.raises(IOError, match="content changed"):
        store.put_file(f, "0" * 64)
