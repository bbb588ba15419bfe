"""Corridor check on hand-made grids and meshes (no fusion): fast unit tests."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from vid2sim.factory.evaluation.corridor import (
    CorridorConfig, CorridorError, corridor_area, corridor_check, gate_reasons, walked_path)
from vid2sim.formats.walkable import WalkableGrid

PATH = np.array([[x, 0.0, 1.5] for x in np.linspace(0.0, 4.0, 9)])  # [9, 3] along +x


def open_grid() -> WalkableGrid:
    return WalkableGrid(np.ones((20, 60), np.uint8), np.array([-1.0, -1.0]), 0.1)  # x -1..5, y -1..1


def wall(x: float, y0: float, y1: float, z0: float, z1: float) -> trimesh.Trimesh:
    """Vertical quad at x = const spanning y0..y1, z0..z1 (two triangles)."""
    v = np.array([[x, y0, z0], [x, y1, z0], [x, y1, z1], [x, y0, z1]])
    return trimesh.Trimesh(v, np.array([[0, 1, 2], [0, 2, 3]]), process=False)


def test_open_corridor_is_fully_walkable_and_clear():
    rep = corridor_check(open_grid(), wall(2.0, 0.6, 1.0, 0.0, 1.0), PATH)
    assert rep.walkable_fraction == 1.0
    assert rep.path_components == 1
    assert rep.corridor_area_m2 == 0.0  # the wall is 0.6 m to the side
    assert rep.path_length_m == pytest.approx(4.0, abs=1e-6)
    assert gate_reasons(rep, CorridorConfig()) == []


def test_wall_across_the_path_counts_its_area_inside_the_body():
    # across the path: the body (|y| <= 0.25) meets it between z = 0.2 and 1.0 -> 0.5 x 0.8
    rep = corridor_check(open_grid(), wall(2.0, -1.0, 1.0, 0.0, 1.0), PATH)
    assert rep.corridor_area_m2 == pytest.approx(0.4, rel=0.06)
    # a kerb-high wall stays below the body bottom (0.2 m)
    low = corridor_check(open_grid(), wall(2.0, -1.0, 1.0, 0.0, 0.15), PATH)
    assert low.corridor_area_m2 == 0.0
    # an overhang above the head gap does not count either
    high = corridor_check(open_grid(), wall(2.0, -1.0, 1.0, 1.45, 2.5), PATH)
    assert high.corridor_area_m2 == 0.0
    assert "corridor_obstructed" in gate_reasons(rep, CorridorConfig(gate_max_area_m2=0.05))


def test_gap_in_the_map_splits_the_corridor():
    wm = open_grid()
    wm.grid[:, 28:31] = 0  # x in [1.8, 2.1) not walkable
    rep = corridor_check(wm, None, PATH)
    assert rep.path_components == 2
    assert rep.walkable_fraction == pytest.approx(1 - 0.3 / 4.0, abs=0.03)
    assert set(gate_reasons(rep, CorridorConfig(gate_min_walkable_fraction=0.99))) == {
        "corridor_not_walkable", "corridor_split"}


def test_path_off_the_grid_is_not_walkable():
    rep = corridor_check(open_grid(), None, PATH + [0.0, 5.0, 0.0])
    assert rep.walkable_fraction == 0.0 and rep.path_components == 0


def test_walked_path_resamples_and_rejects_bad_paths():
    w = walked_path(PATH[[0, -1]], 0.05)
    assert len(w) == 81 and np.allclose(np.diff(w[:, 0]), 0.05)
    with pytest.raises(CorridorError, match="bad_camera_path"):
        walked_path(np.array([[0.0, np.nan, 1.0]]), 0.05)


def test_area_scales_with_the_body_radius():
    m = wall(2.0, -1.0, 1.0, 0.0, 1.0)
    w = walked_path(PATH, 0.05)
    a1 = corridor_area(m, w, CorridorConfig(body_radius_m=0.25))
    a2 = corridor_area(m, w, CorridorConfig(body_radius_m=0.5))
    assert a2 == pytest.approx(2 * a1, rel=0.08)


def test_pipeline_gate_writes_the_report_and_names_the_reason(tmp_path):
    from vid2sim.factory.runtime.pipeline import check_corridor
    from vid2sim.factory.runtime.stage_cache import StageError

    walk_dir = tmp_path / "walkable"
    walk_dir.mkdir()
    open_grid().save(walk_dir / "walkable.npz")
    wall(2.0, 0.6, 1.0, 0.0, 1.0).export(walk_dir / "collision.ply")  # the physical layer's mesh
    out = check_corridor(CorridorConfig(), walk_dir, PATH)
    assert out["passed"] and out["walkable_fraction"] == 1.0
    wall(2.0, -1.0, 1.0, 0.0, 1.0).export(walk_dir / "collision.ply")
    with pytest.raises(StageError) as e:
        check_corridor(CorridorConfig(gate_max_area_m2=0.05), walk_dir, PATH)
    assert e.value.reason == "corridor_obstructed"
    assert '"passed": false' in (walk_dir / "corridor.json").read_text()
