"""The Ray orchestrator on a real local Ray runtime: isolation of failures,
retry of a dead worker, ordering of stages per clip. A stage takes the clip's state (here a
dict) and returns the next one."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest
import ray

from vid2sim.factory.runtime.orchestrator import StageSpec, ensure_ray, run_clips
from vid2sim.factory.runtime.stage_cache import StageError


# Test functions live in a module Ray workers cannot import: ship them by value.
ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])


@pytest.fixture(scope="module", autouse=True)
def local_ray():
    ensure_ray(num_cpus=2)
    yield
    ray.shutdown()


def _write(ctx: dict) -> dict:
    path = Path(ctx["root"]) / f"{ctx['clip']}.txt"
    path.write_text("a")
    return {**ctx, "written": str(path)}


def _append_or_fail(ctx: dict) -> dict:
    if ctx["clip"] == "bad":
        raise StageError("append", "corrupt_video", f"{ctx['clip']} cannot be decoded")
    Path(ctx["written"]).write_text(Path(ctx["written"]).read_text() + "b")
    return {**ctx, "done": True}


def _die_once(ctx: dict) -> dict:
    marker = Path(ctx["root"]) / f"{ctx['clip']}.died"
    if not marker.exists():
        marker.write_text("x")
        os._exit(1)  # the worker process dies: Ray must retry the task
    return {**ctx, "survived": True}


def test_failed_clip_is_isolated_and_named(tmp_path):
    stages = [StageSpec("write", _write), StageSpec("append", _append_or_fail)]
    clips = [(c, {"clip": c, "root": str(tmp_path)}) for c in ("a", "bad", "c")]
    committed = []
    results = {r.clip_id: r for r in run_clips(clips, stages, on_clip_done=lambda s: committed.append(s.clip_id))}
    assert results["a"].ok and results["c"].ok
    assert not results["bad"].ok
    assert results["bad"].failed_stage == "append"
    assert results["bad"].reason == "corrupt_video"
    assert sorted(committed) == ["a", "c"]
    assert (tmp_path / "a.txt").read_text() == "ab"
    assert (tmp_path / "bad.txt").read_text() == "a"  # stage 1 output kept, stage 2 never ran


def test_dead_worker_is_retried(tmp_path):
    results = run_clips([("x", {"clip": "x", "root": str(tmp_path)})], [StageSpec("die", _die_once)],
                        max_retries=2)
    assert results[0].ok, results[0].detail
    assert results[0].work["survived"] is True


def test_commit_hook_error_marks_clip_failed(tmp_path):
    def reject(state):
        raise StageError("commit", "invalid_bundle", "scene.json missing")

    results = run_clips([("y", {"clip": "y", "root": str(tmp_path)})], [StageSpec("write", _write)],
                        on_clip_done=reject)
    assert not results[0].ok and results[0].failed_stage == "commit"
    assert results[0].reason == "invalid_bundle"
