"""The transfer figures the work store's staging keeps, and the per-stage stats a Ray stage
task reports with them (node, CPU seconds, transfers)."""

from __future__ import annotations

from pathlib import Path

from vid2sim.factory.runtime.object_store import ObjectStore
from vid2sim.factory.runtime.orchestrator import _run_stage
from vid2sim.factory.runtime.stage_cache import StageError, mark_done
from vid2sim.factory.runtime.staging import sync_down, sync_up, transfer_totals


def _done_folder(path: Path, size: int) -> Path:
    path.mkdir(parents=True)
    (path / "data.bin").write_bytes(b"x" * size)
    mark_done(path, "step", "key-1", {}, 0.0)
    return path


def test_sync_up_and_down_add_to_the_totals(tmp_path):
    store = ObjectStore(str(tmp_path / "store"))
    _done_folder(tmp_path / "a" / "step", 1000)
    before = transfer_totals()
    assert sync_up(store, "clip", tmp_path / "a", ["step"]) == ["step"]
    assert sync_up(store, "clip", tmp_path / "a", ["step"]) == []  # the store holds the marker: no move
    assert sync_down(store, "clip", tmp_path / "b", ("step",)) == ["step"]
    after = transfer_totals()
    moved = {k: after[k] - before[k] for k in after}
    assert moved["up_folders"] == 1 and moved["down_folders"] == 1
    assert moved["up_bytes"] >= 1000 and moved["down_bytes"] == moved["up_bytes"]
    assert moved["up_s"] > 0 and moved["down_s"] > 0 and moved["source_s"] == 0


def test_stage_task_reports_its_transfers_and_cpu(tmp_path):
    store = ObjectStore(str(tmp_path / "store"))
    _done_folder(tmp_path / "a" / "step", 500)

    def stage(work: str) -> str:
        sync_up(store, "clip", tmp_path / "a", ["step"])
        sum(i * i for i in range(200_000))
        return work + "!"

    out = _run_stage(stage, "step", "w")
    assert out["ok"] and out["work"] == "w!"
    stats = out["stats"]
    assert stats["up_folders"] == 1 and stats["up_bytes"] >= 500 and stats["down_folders"] == 0
    assert 0 < stats["up_s"] <= out["seconds"] and stats["cpu_s"] > 0 and stats["node"] == ""

    def refuse(work: str) -> str:
        raise StageError("step", "bad_input", "no")

    failed = _run_stage(refuse, "step", "w")
    assert not failed["ok"] and failed["reason"] == "bad_input" and failed["stats"]["up_folders"] == 0
