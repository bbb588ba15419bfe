"""The synthetic-street scorer: ground truth scored against itself is perfect; a shifted
estimate is realigned by the Sim(3) fit."""

from __future__ import annotations

import numpy as np
import trimesh

from vid2sim.factory.evaluation.geometry_metrics import erode_walkable
from vid2sim.factory.sfm.posed import PosedClip
from vid2sim.factory.synthetic.config import preset
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
    g, o, r = scene.walkable_grid(pad=0.3)
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
