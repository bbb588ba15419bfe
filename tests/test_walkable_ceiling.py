"""Ceiling and IoU breakdown of the walkable map on analytic scenes (evaluation/walkable_ceiling)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from vid2sim.factory.evaluation.geometry_metrics import erode_walkable
from vid2sim.factory.evaluation.walkable_ceiling import ceiling, iou_breakdown, path_clearance
from vid2sim.formats.walkable import WalkableGrid

PATH = np.array([[x, 0.0, 1.5] for x in np.linspace(-3.0, 3.0, 13)])  # walks along +x at y = 0


def box_at(y_near: float, side: int = 1) -> trimesh.Trimesh:
    """A 1 m long, 0.5 m tall planter whose near face is y_near from the path (side +1 left)."""
    b = trimesh.creation.box(extents=(1.0, 0.4, 0.5))
    b.apply_translation((0.0, side * (y_near + 0.2), 0.25))
    return b


def gt_map(box: trimesh.Trimesh, radius: float) -> WalkableGrid:
    """Robot-centre map of a 4 m wide sidewalk y in [-2, 2) minus the box footprint."""
    res = 0.05
    x, y = np.meshgrid(np.arange(-4, 4, res) + res / 2, np.arange(-2, 2, res) + res / 2)
    lo, hi = box.bounds
    free = ~((x >= lo[0]) & (x <= hi[0]) & (y >= lo[1]) & (y <= hi[1]))
    return erode_walkable(WalkableGrid(free.astype(np.uint8), np.array([-4.0, -2.0]), res), radius)


@pytest.mark.parametrize("y_near, reachable", [(0.4, True), (0.2, False)])
def test_ceiling_is_the_gt_maps_corridor_and_the_paths_clearance(y_near, reachable):
    box = box_at(y_near)
    c = ceiling(gt_map(box, 0.3), box, PATH, 0.3)
    assert c["gt_clearance_min_m"] == pytest.approx(y_near, abs=0.02)
    assert (c["gt_walkable_fraction"] == 1.0) == reachable
    assert (c["gt_path_within_robot_radius"] == 0.0) == reachable
    assert (c["gt_corridor_area_m2"] == 0.0) == reachable  # 0.4 m: outside the 0.25 m body


def test_clearance_ignores_geometry_outside_the_robot_band():
    low = trimesh.creation.box(extents=(1.0, 0.4, 0.1))  # a 0.1 m kerb-like slab at y = 0.2
    low.apply_translation((0.0, 0.4, 0.05))
    assert np.isinf(path_clearance(low, PATH)).all()
    assert path_clearance(box_at(0.2), PATH).min() == pytest.approx(0.2, abs=0.02)


def test_iou_breakdown_puts_missed_and_extra_area_on_their_side_of_the_path():
    gt = gt_map(box_at(5.0), 0.3)  # the box lies off the sidewalk: a plain 4 m strip
    ours = WalkableGrid(gt.grid.copy(), gt.origin, gt.resolution)
    rows = np.arange(gt.grid.shape[0])
    y = gt.origin[1] + (rows + 0.5) * gt.resolution
    ours.grid[(y > 1.2) & (y < 1.6)] = 0  # a 0.4 m strip missing on the left
    ours.grid[(y > -2.0) & (y < -1.8)] = 1  # a 0.2 m strip too much on the right (GT: y > -1.7)
    b = iou_breakdown(ours, gt, PATH, -2.0, 2.0)
    assert b["missed_left_m2"] == pytest.approx(4.0 * 0.4, abs=0.1)
    assert b["missed_right_m2"] == 0.0 and b["extra_left_m2"] == 0.0
    assert b["extra_right_m2"] == pytest.approx(4.0 * 0.2, abs=0.1)


def test_iou_breakdown_names_the_cause_of_the_missed_area():
    from vid2sim.factory.geometry.map_evidence import MapEvidence

    gt = gt_map(box_at(5.0), 0.3)
    ours = WalkableGrid(gt.grid.copy(), gt.origin, gt.resolution)
    shape = gt.grid.shape
    y = gt.origin[1] + (np.arange(shape[0]) + 0.5) * gt.resolution
    seen, by_obs, by_kerb = np.ones(shape, bool), np.zeros(shape, bool), np.zeros(shape, bool)
    by_obs[(y > 1.2) & (y < 1.6)] = True  # 0.4 m strip blocked by an obstacle's clearance
    seen[(y > -1.0) & (y < -0.9)] = False  # 0.1 m strip never seen
    ours.grid[~seen | by_obs] = 0
    ev = MapEvidence(seen, by_obs, by_kerb, np.zeros((0, 2)))
    b = iou_breakdown(ours, gt, PATH, -2.0, 2.0, evidence=ev)
    assert b["missed_obstacle_m2"] == pytest.approx(4.0 * 0.4, abs=0.1)
    assert b["missed_unseen_m2"] == pytest.approx(4.0 * 0.1, abs=0.1)
    assert b["missed_kerb_m2"] == 0.0 and b["missed_component_m2"] == 0.0
    assert b["missed_obstacle_m2"] + b["missed_unseen_m2"] == pytest.approx(
        b["missed_left_m2"] + b["missed_right_m2"])
    assert "missed_obstacle_m2" not in iou_breakdown(ours, gt, PATH, -2.0, 2.0)
