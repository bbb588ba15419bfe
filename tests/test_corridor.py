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
    from vid2sim.factory.runtime.steps.walkable import check_corridor
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


def test_miss_causes_name_the_first_reason_per_sample_and_sum_to_the_miss():
    from vid2sim.factory.geometry.map_evidence import MISS_CAUSES, MapEvidence, path_miss_causes

    wm = open_grid()  # x -1..5 at 0.1 m; the path runs along y = 0 from x 0 to 4
    shape = wm.grid.shape
    seen, by_obs, by_kerb = np.ones(shape, bool), np.zeros(shape, bool), np.zeros(shape, bool)
    seen[:, 11:16] = False  # x [0.1, 0.6): unseen
    by_obs[:, 21:26] = True  # x [1.1, 1.6): blocked by the surface point at (1.3, -0.25)
    by_obs[:, 31:36] = True  # x [2.1, 2.6): blocked, but its point is 0.35 m from the path
    by_kerb[:, 41:46] = True  # x [3.1, 3.6): beyond-kerb inflation
    wm.grid[:] = 0
    wm.grid[:, 10:50] = 1
    wm.grid[~seen | by_obs | by_kerb] = 0
    wm.grid[:, 47:49] = 0  # x [3.7, 3.9) free in the evidence, but cut off (component)
    pts = np.array([[1.3, -0.25], [2.3, -0.35]])
    out = path_miss_causes(wm, MapEvidence(seen, by_obs, by_kerb, pts), PATH, robot_radius_m=0.3)
    rep = corridor_check(wm, None, PATH)
    assert sum(out[k] for k in MISS_CAUSES) == pytest.approx(1 - rep.walkable_fraction)
    n = len(walked_path(PATH, 0.05))
    assert out["unseen"] == pytest.approx(10 / n) and out["kerb"] == pytest.approx(10 / n)
    assert out["component"] == pytest.approx(4 / n, abs=1.5 / n)
    # x [1.1, 1.6): within 0.3 m of (1.3, -0.25) is x in [1.134, 1.466] (7 samples), the rest
    # of that stretch and all of x [2.1, 2.6) clear every point: discretisation
    assert out["obstacle_within_radius"] == pytest.approx(7 / n, abs=1.5 / n)
    assert out["obstacle_cell"] == pytest.approx(13 / n, abs=1.5 / n)
    assert out["off_grid"] == 0.0 and out["obstacle_clearance_min_m"] == pytest.approx(0.25)
    off = path_miss_causes(wm, MapEvidence(seen, by_obs, by_kerb, pts), PATH + [0, 5.0, 0], 0.3)
    assert off["off_grid"] == 1.0
