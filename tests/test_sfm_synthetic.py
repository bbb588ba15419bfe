"""decode -> sfm -> metric on the synthetic street: poses, metric scale and ground vs ground truth."""

from __future__ import annotations

import numpy as np
import pytest

from vid2sim.factory.ingest import decode
from vid2sim.factory.sfm import metric, sfm
from vid2sim.factory.evaluation.poses import evaluate, load_posed_clip
from vid2sim.factory.synthetic import generate_street, render_video
from vid2sim.factory.synthetic import preset as street_preset
from vid2sim.factory.runtime.runner import run_stage

pytestmark = pytest.mark.slow  # renders a street and runs SfM (over a minute)


def test_synthetic_street_metric_poses(tmp_path):
    conf = street_preset("demo", seed=1, duration_s=4.0, write_depth=False)
    clip = render_video(generate_street(conf), conf, tmp_path / "render")
    dconf = decode.DecodeConfig(fps=10.0, max_side=854, workers=1)
    dec = run_stage(decode.work(dconf, str(clip.video)), tmp_path / "decode")
    sdir = run_stage(sfm.work(sfm.preset("fast"), dec / "images", None), tmp_path / "sfm")
    q = sfm.load_quality(sdir)
    assert q["registered_fraction"] >= 0.95 and q["mean_reproj_error_px"] < 1.0
    pdir = run_stage(metric.work(metric.MetricConfig(capture_height_m=conf.capture_height), sdir), tmp_path / "metric")
    ev = evaluate(load_posed_clip(pdir), load_posed_clip(tmp_path / "render"))
    assert ev["n_matched"] >= 0.95 * q["num_frames"]  # GT has every video frame, we sample 10 fps
    assert ev["ate"]["rmse_pct_of_path"] <= 0.5
    assert abs(1 / ev["ate"]["scale"] - 1) <= 0.1  # metric scale from the capture height
    R = np.asarray(ev["ate"]["rotation"])  # our world -> GT world: z must stay z
    assert np.degrees(np.arccos(np.clip((R @ [0, 0, 1.0])[2], -1, 1))) <= 2.0
