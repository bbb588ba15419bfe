"""The synthetic-street scorer: ground truth scored against itself is perfect; a shifted
estimate is realigned by the Sim(3) fit."""

from __future__ import annotations

import numpy as np
import trimesh

from vid2sim.factory.evaluation.geometry_metrics import erode_walkable
from vid2sim.factory.sfm.posed import PosedClip
from vid2sim.factory.synthetic.config import preset
from vid2sim.factory.synthetic.geometry import GROUND_MATERIALS, POLE
from vid2sim.factory.evaluation.synthetic_gt import scene_errors, street_config
from vid2sim.factory.synthetic.make_street import main as make_street
from vid2sim.factory.synthetic.street import generate_street
from vid2sim.formats.walkable import WalkableGrid


def test_ground_truth_scores_perfectly_even_when_shifted(tmp_path):
    conf = preset("test", seed=2, duration_s=3.0)
    out = make_street(conf, tmp_path / "street")
    assert street_config(out) == conf
    scene = generate_street(conf)
    mesh = trimesh.Trimesh(*scene.without_ground(), process=False)
    g, o, r = scene.walkable_grid()
    gt_map = erode_walkable(WalkableGrid(g, o, r), 0.3)
    est = PosedClip.load(out)
    shift = np.array([3.0, 1.5, 0.0])  # the estimate's own frame: GT moved by `shift`
    for f in est.frames:
        f.cam_to_world[:3, 3] += shift
    moved = trimesh.Trimesh(mesh.vertices + shift, mesh.faces, process=False)
    moved_map = WalkableGrid(gt_map.grid, gt_map.origin + shift[:2], gt_map.resolution)
    err = scene_errors(est, out, moved, moved_map, samples=20_000)
    assert err["ate_m"] < 1e-6 and err["metric_scale_error_pct"] < 1e-6
    assert err["collision_accuracy_m"] < 0.05  # sampling distance only
    assert err["walkable_iou"] > 0.99
    by_material = {k: v for k, v in err.items() if k.startswith("near_path_completeness_")}
    assert "near_path_completeness_pole" in by_material and len(by_material) >= 3
    assert min(by_material.values()) > 0.99


def test_completeness_by_material_names_the_missing_obstacles(tmp_path):
    """A collision mesh without the poles is incomplete on the poles only."""
    conf = preset("test", seed=2, duration_s=3.0)
    out = make_street(conf, tmp_path / "street")
    scene = generate_street(conf)
    keep = ~np.isin(scene.face_material, GROUND_MATERIALS + (POLE,))
    mesh = trimesh.Trimesh(scene.vertices, scene.triangles[keep], process=False)
    g, o, r = scene.walkable_grid()
    err = scene_errors(PosedClip.load(out), out, mesh, erode_walkable(WalkableGrid(g, o, r), 0.3),
                       samples=20_000)
    assert err["near_path_completeness_pole"] < 0.05
    others = [v for k, v in err.items() if k.startswith("near_path_completeness_") and not k.endswith("pole")]
    assert others and min(others) > 0.99
    assert err["near_path_completeness"] < 0.99  # the poles are part of the whole figure


def test_gt_robot_centre_map_keeps_exactly_the_robot_radius_from_obstacles():
    """Robot-centre cells are farther than the radius from an obstacle: inflating the
    footprints AND eroding (the old scorer) would keep twice the radius."""
    scene = generate_street(preset("test", seed=2, duration_s=3.0))
    g, o, r = scene.walkable_grid()
    gt = erode_walkable(WalkableGrid(g, o, r), 0.3)
    ob = scene.obstacles[0]
    ys, xs = np.nonzero(gt.grid)
    X, Y = gt.cell_center(ys, xs)
    assert not ob.contains(X, Y, 0.3 - r).any()  # nothing within the radius is kept
    near = ob.contains(X, Y, 0.3 + 2 * r) & ~ob.contains(X, Y, 0.3 + r)
    assert near.any()  # cells just beyond the radius are kept
