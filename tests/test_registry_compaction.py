"""Manifest maintenance on real Delta tables: automatic compaction + checkpoint, time travel across
it, lost compaction races never failing a commit, explicit vacuum; and the latest-version view
(`list`) against a straightforward row-by-row reference."""

from __future__ import annotations

import logging
import random
from pathlib import Path

import pytest
from registry_fixtures import make_bundle, synthetic_record

from vid2sim.registry.records import SceneRecord
from vid2sim.registry.store import Registry, RegistryConfig


def _compactions(reg: Registry) -> int:
    return sum(h.get("vid2sim.operation") == "compact" for h in reg.manifest.history())


def _parquet_on_disk(reg: Registry) -> int:
    return len(list((Path(reg.root) / "manifests").glob("*.parquet")))


def _state(reg: Registry, as_of=None) -> list[tuple]:
    return [(r.ref, r.tags, r.status) for r in reg.list(as_of=as_of, include_deprecated=True)]


def test_auto_compaction_triggers_and_time_travel_keeps_old_state(tmp_path):
    reg = Registry(tmp_path / "reg", config=RegistryConfig(auto_compact_files=3))
    states = {}
    for i, sid in enumerate(["a", "b", "c"]):
        reg.add(make_bundle(tmp_path / sid, sid, seed=i))
        states[reg.version] = _state(reg)
    assert reg.manifest.num_files() == 3 and _compactions(reg) == 0  # at the threshold: not yet
    rows_before = reg.history()
    reg.tag("a", "night")  # 4th file -> this commit compacts
    assert reg.manifest.num_files() == 1 and _compactions(reg) == 1
    assert reg.version == 5  # 0 = create, 1-3 adds, 4 tag, 5 compaction
    log = Path(reg.root) / "manifests" / "_delta_log"
    assert (log / f"{reg.version:020d}.checkpoint.parquet").is_file() and (log / "_last_checkpoint").is_file()
    assert reg.history() == rows_before + [reg.show("a", 2)]  # rows unchanged by compaction
    for v, state in states.items():  # versions before the compaction still read their old state
        assert _state(reg, as_of=v) == state
        assert _state(Registry(reg.root), as_of=v) == state  # fresh handle: checkpoint + old files
    assert _parquet_on_disk(reg) == 5  # replaced files kept (only tombstoned) for time travel
    assert reg.verify() == []


def test_auto_compaction_off_and_default_threshold(tmp_path):
    off = Registry(tmp_path / "off", config=RegistryConfig(auto_compact_files=0))
    for i in range(3):
        off.manifest.append_bulk([synthetic_record(f"s{i}", "g").to_row()])
    assert off.manifest.num_files() == 3 and _compactions(off) == 0
    assert Registry(tmp_path / "x").config.auto_compact_files == 50


def test_lost_compaction_race_never_fails_the_commit(tmp_path, caplog):
    root = tmp_path / "reg"
    reg = Registry(root, config=RegistryConfig(auto_compact_files=1))
    other = Registry(root, config=RegistryConfig(auto_compact_files=0))
    reg.add(make_bundle(tmp_path / "a", "a"))
    # a real concurrent commit lands between the compaction's snapshot read and its commit
    real_read, real_compact, racing = reg.manifest.read, reg.manifest.compact, []

    def read(as_of=None, check=True):
        out = real_read(as_of, check)
        if racing and not racing[0]:
            racing[0] = other.tag("a", "race").ref
        return out

    def compact():
        racing[:] = [None]
        try:
            return real_compact()
        finally:
            racing.clear()

    reg.manifest.read, reg.manifest.compact = read, compact
    with caplog.at_level(logging.INFO, logger="vid2sim.registry.manifest"):
        rec = reg.add(make_bundle(tmp_path / "b", "b", seed=1))  # 2 files -> compaction, which loses
    assert rec.ref == "b@1" and "lost a race" in caplog.text
    assert _compactions(reg) == 0 and Registry(root).manifest.num_files() == 3
    assert [r.ref for r in reg.history()] == ["a@1", "b@1", "a@2"]  # nothing lost or duplicated
    metrics = Registry(root).compact()  # explicit compaction retries until it wins
    assert metrics["numFilesRemoved"] == 3 and metrics["numFilesAdded"] == 1
    assert [r.ref for r in Registry(root).history()] == ["a@1", "b@1", "a@2"]


def test_vacuum_only_on_explicit_request(tmp_path):
    reg = Registry(tmp_path / "reg", config=RegistryConfig(auto_compact_files=2))
    for i, sid in enumerate(["a", "b", "c"]):
        reg.add(make_bundle(tmp_path / sid, sid, seed=i))  # 3rd add compacts
    assert _compactions(reg) == 1
    old = _state(reg, as_of=1)
    on_disk = _parquet_on_disk(reg)
    assert reg.compact()["numFilesRemoved"] == 0 and _parquet_on_disk(reg) == on_disk  # 1 file: no-op
    dry = reg.compact(vacuum_hours=0, dry_run=True)["vacuumed"]
    assert len(dry) == 3 and _parquet_on_disk(reg) == on_disk  # the 3 replaced files, none deleted yet
    assert reg.compact(vacuum_hours=48)["vacuumed"] == []  # replaced seconds ago: inside the window
    assert _state(reg, as_of=1) == old
    assert sorted(reg.compact(vacuum_hours=0)["vacuumed"]) == sorted(dry)
    assert _parquet_on_disk(reg) == on_disk - 3
    with pytest.raises(ValueError, match="no longer readable"):
        reg.list(as_of=1)
    assert [r.ref for r in Registry(reg.root).list()] == ["a@1", "b@1", "c@1"] and reg.verify() == []


def _reference_latest(reg: Registry, as_of=None) -> list[SceneRecord]:
    """The straightforward path: every row -> SceneRecord, keep the max version per scene."""
    _, table = reg.manifest.read(as_of)
    best: dict[str, SceneRecord] = {}
    for row in table.to_pylist():
        rec = SceneRecord.from_row(row)
        if rec.scene_id not in best or rec.version > best[rec.scene_id].version:
            best[rec.scene_id] = rec
    return [best[s] for s in sorted(best)]


def test_list_matches_row_by_row_reference_on_200_rows(tmp_path):
    rng = random.Random(7)
    rows = []
    for s in range(60):  # 60 scenes, 1-6 versions each, some end deprecated
        n = rng.randint(1, 6)
        for v in range(1, n + 1):
            dep = v == n and s % 7 == 0
            rows.append(synthetic_record(f"scene-{s:03d}", f"g{s % 9}", psnr=20.0 + rng.random() * 10,
                                         tags=tuple(sorted(rng.sample(["a", "b", "night", "rain"], v % 3))),
                                         status="deprecated" if dep else "active", version=v).to_row())
    rows = rows[:200]
    rng.shuffle(rows)  # versions of a scene land in any order, across files
    reg = Registry(tmp_path / "reg", config=RegistryConfig(auto_compact_files=0))
    for i in range(0, len(rows), 40):
        reg.manifest.append_bulk(rows[i:i + 40])
    assert len(reg.history()) == 200
    ref = _reference_latest(reg)
    assert len(ref) == 60 and any(r.status == "deprecated" for r in ref)
    assert reg.list(include_deprecated=True) == ref
    assert Registry(reg.root).list() == [r for r in ref if r.status == "active"]
    assert reg.list(as_of=2, include_deprecated=True) == _reference_latest(reg, as_of=2)
    _, table = reg.manifest.read()
    assert reg.history() == sorted((SceneRecord.from_row(r) for r in table.to_pylist()),
                                   key=lambda r: (r.created_at, r.scene_id, r.version))
