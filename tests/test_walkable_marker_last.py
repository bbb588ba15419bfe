"""The walkable stage's marker is the last file it writes: the corridor report (corridor.json)
is written before `stage.json`, and the corridor gate after it writes nothing, on a fresh run,
on a gated run and on a cached re-run. Small analytic inputs (a ground plane, a box beside the
walk), the walkable step run by the pipeline's runner; no Ray."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import trimesh

from vid2sim.factory.evaluation.corridor import CorridorConfig
from vid2sim.factory.geometry import meshing
from vid2sim.factory.runtime import runner
from vid2sim.factory.ingest.clips import ClipSpec
from vid2sim.factory.ingest.sources import Source
from vid2sim.factory.runtime.config import ClipJob, PipelineConfig
from vid2sim.factory.runtime.runner import ClipWork, clip_work, run_step
from vid2sim.factory.runtime.stage_cache import MARKER, StageError
from vid2sim.factory.runtime.steps import STEPS
from vid2sim.factory.runtime.steps import meshing as meshing_step
from vid2sim.factory.runtime.steps import metric
from vid2sim.factory.runtime.steps.walkable import CORRIDOR_REPORT
from vid2sim.factory.sfm.posed import PosedClip, PosedFrame

PATH = np.array([[x, 0.0, 1.5] for x in np.linspace(-3.0, 3.0, 13)])  # camera path along +x


WALKABLE = next(s for s in STEPS if s.name == "walkable")


def _work(root: Path, conf: PipelineConfig) -> ClipWork:
    """A posed clip walking PATH, and a meshing folder: ground plane + a box 1.2 m to the side."""
    K = np.array([[50.0, 0, 32], [0, 50.0, 18], [0, 0, 1]])
    frames = []
    for i, p in enumerate(PATH):
        c2w = np.eye(4)
        c2w[:3, :3] = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)  # looking along +x
        c2w[:3, 3] = p
        frames.append(PosedFrame(i, f"{i:06d}.jpg", i / 10, 64, 36, K, c2w))
    posed = PosedClip(frames, root / "images").save(root / "metric")
    mesh_dir = root / "meshing"
    mesh_dir.mkdir()
    x, y = np.meshgrid(np.arange(-4, 4, 0.05) + 0.025, np.arange(-2, 2, 0.05) + 0.025)
    np.save(mesh_dir / meshing.OUTPUTS.ground_points,
            np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1).astype(np.float32))
    box = trimesh.creation.box(extents=(1.0, 0.6, 1.0))
    box.apply_translation((0.0, 1.2, 0.5))
    box.export(mesh_dir / meshing.OUTPUTS.collision)
    job = ClipJob(ClipSpec("clip", Source("video", root / "v.mp4", "file:///v.mp4", "a" * 64), None, "g"), "s", "CC0")
    return clip_work(job, conf, root, metric=metric.Outputs(posed), meshing=meshing_step.Outputs(mesh_dir))


def stage_walkable(work: ClipWork) -> Path:
    """The walkable step's folder after the runner ran it on the clip."""
    out = run_step(WALKABLE, work).outputs["walkable"]
    return out.under(Path(work.workdir) / work.clip_id).dir


def _state(folder: Path) -> dict[str, tuple[int, int]]:
    """{file name: (mtime_ns, size)} of every file in the folder."""
    return {p.name: (p.stat().st_mtime_ns, p.stat().st_size) for p in sorted(folder.iterdir()) if p.is_file()}


@pytest.fixture
def recorded(monkeypatch):
    """Records the folder's files at the moment the marker is written (the runner's `mark_done`,
    the one writer of markers)."""
    at_marker: list[dict] = []
    real = runner.mark_done

    def mark_done(out_dir, *args, **kwargs):
        at_marker.append(_state(Path(out_dir)))
        return real(out_dir, *args, **kwargs)

    monkeypatch.setattr(runner, "mark_done", mark_done)
    return at_marker


def _check_marker_last(walk_dir: Path, before_marker: dict) -> None:
    after = _state(walk_dir)
    assert MARKER not in before_marker and CORRIDOR_REPORT in before_marker
    # nothing written or changed after the marker ...
    assert {k: v for k, v in after.items() if k != MARKER} == before_marker
    # ... and on disk the marker is the newest file of the folder
    assert after[MARKER][0] >= max(t for t, _ in before_marker.values())


def test_the_marker_is_the_last_file_the_walkable_stage_writes(tmp_path, recorded):
    work = _work(tmp_path, PipelineConfig())
    walk_dir = stage_walkable(work)
    assert walk_dir == tmp_path / "clip" / "walkable" and len(recorded) == 1
    _check_marker_last(walk_dir, recorded[0])
    report = json.loads((walk_dir / CORRIDOR_REPORT).read_text())
    assert report["passed"] and report["walkable_fraction"] == 1.0
    # a cached re-run writes nothing at all
    done = _state(walk_dir)
    assert stage_walkable(work) == walk_dir and _state(walk_dir) == done and len(recorded) == 1


def test_a_gated_clip_keeps_the_marker_last_and_is_gated_again_from_the_cache(tmp_path, recorded):
    strict = CorridorConfig(gate_max_components=0)  # a walked path has at least one component: none can pass
    work = _work(tmp_path, PipelineConfig(corridor=strict))
    with pytest.raises(StageError) as e:
        stage_walkable(work)
    assert e.value.stage == "walkable" and e.value.reason == "corridor_split"
    walk_dir = tmp_path / "clip" / "walkable"
    assert len(recorded) == 1
    _check_marker_last(walk_dir, recorded[0])
    assert json.loads((walk_dir / CORRIDOR_REPORT).read_text())["passed"] is False
    done = _state(walk_dir)
    with pytest.raises(StageError) as again:
        stage_walkable(work)
    assert again.value.reason == "corridor_split" and _state(walk_dir) == done and len(recorded) == 1
    # the corridor config decides corridor.json, a file of the stage: changing it reruns the stage
    assert stage_walkable(replace(work, conf=PipelineConfig())) == walk_dir
    assert len(recorded) == 2
    _check_marker_last(walk_dir, recorded[1])
    assert json.loads((walk_dir / CORRIDOR_REPORT).read_text())["passed"] is True
