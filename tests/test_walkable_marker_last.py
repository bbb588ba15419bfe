"""The walkable stage's marker is the last file it writes: the corridor report (corridor.json)
is written before `stage.json`, and the corridor gate after it writes nothing, on a fresh run,
on a gated run and on a cached re-run. Small analytic inputs (a ground plane, a box beside the
walk), the pipeline's own stage function; no Ray."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from vid2sim.factory.evaluation.corridor import CorridorConfig
from vid2sim.factory.geometry import meshing, walkable
from vid2sim.factory.runtime import pipeline
from vid2sim.factory.runtime.pipeline import CORRIDOR_REPORT, PipelineConfig, stage_walkable
from vid2sim.factory.runtime.stage_cache import MARKER, StageError
from vid2sim.factory.sfm.posed import PosedClip, PosedFrame

PATH = np.array([[x, 0.0, 1.5] for x in np.linspace(-3.0, 3.0, 13)])  # camera path along +x


def _inputs(root: Path) -> dict:
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
    return {"posed_dir": str(posed), "meshing_dir": str(mesh_dir), "clip_dir": str(root / "clip")}


def _state(folder: Path) -> dict[str, tuple[int, int]]:
    """{file name: (mtime_ns, size)} of every file in the folder."""
    return {p.name: (p.stat().st_mtime_ns, p.stat().st_size) for p in sorted(folder.iterdir()) if p.is_file()}


@pytest.fixture
def recorded(monkeypatch):
    """Runs stage_walkable without Ray; records the folder's files at the moment the marker is
    written (the walkable module's `mark_done`)."""
    monkeypatch.setattr(pipeline, "_threads", lambda ctx: 1)
    at_marker: list[dict] = []
    real = walkable.mark_done

    def mark_done(out_dir, *args, **kwargs):
        at_marker.append(_state(Path(out_dir)))
        return real(out_dir, *args, **kwargs)

    monkeypatch.setattr(walkable, "mark_done", mark_done)
    return at_marker


def _check_marker_last(walk_dir: Path, before_marker: dict) -> None:
    after = _state(walk_dir)
    assert MARKER not in before_marker and CORRIDOR_REPORT in before_marker
    # nothing written or changed after the marker ...
    assert {k: v for k, v in after.items() if k != MARKER} == before_marker
    # ... and on disk the marker is the newest file of the folder
    assert after[MARKER][0] >= max(t for t, _ in before_marker.values())


def test_the_marker_is_the_last_file_the_walkable_stage_writes(tmp_path, recorded):
    ctx = {**_inputs(tmp_path), "conf": PipelineConfig()}
    out = stage_walkable(ctx)
    walk_dir = Path(out["walkable_dir"])
    assert len(recorded) == 1
    _check_marker_last(walk_dir, recorded[0])
    report = json.loads((walk_dir / CORRIDOR_REPORT).read_text())
    assert report["passed"] and report["walkable_fraction"] == 1.0
    # a cached re-run writes nothing at all
    done = _state(walk_dir)
    assert stage_walkable(ctx) == out and _state(walk_dir) == done and len(recorded) == 1


def test_a_gated_clip_keeps_the_marker_last_and_is_gated_again_from_the_cache(tmp_path, recorded):
    strict = CorridorConfig(gate_min_walkable_fraction=1.01)  # no path can pass
    ctx = {**_inputs(tmp_path), "conf": PipelineConfig(corridor=strict)}
    with pytest.raises(StageError) as e:
        stage_walkable(ctx)
    assert e.value.stage == "walkable" and e.value.reason == "corridor_not_walkable"
    walk_dir = Path(ctx["clip_dir"]) / "walkable"
    assert len(recorded) == 1
    _check_marker_last(walk_dir, recorded[0])
    assert json.loads((walk_dir / CORRIDOR_REPORT).read_text())["passed"] is False
    done = _state(walk_dir)
    with pytest.raises(StageError) as again:
        stage_walkable(ctx)
    assert again.value.reason == "corridor_not_walkable" and _state(walk_dir) == done and len(recorded) == 1
    # the corridor config decides corridor.json, a file of the stage: changing it reruns the stage
    out = stage_walkable({**ctx, "conf": PipelineConfig()})
    assert len(recorded) == 2
    _check_marker_last(Path(out["walkable_dir"]), recorded[1])
    assert json.loads((walk_dir / CORRIDOR_REPORT).read_text())["passed"] is True
