"""sfm stage on real KITTI frames (known PINHOLE intrinsics): all frames register, ATE <= 1 %."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from conftest import shared_data_path
from vid2sim.factory.sfm import metric, sfm
from vid2sim.factory.evaluation.poses import evaluate, load_kitti_poses, load_posed_clip
from vid2sim.factory.runtime.runner import run_stage

pytestmark = pytest.mark.slow  # SfM + metric frame on 51 KITTI frames (minutes)


def kitti_intrinsics(calib: Path) -> list[float]:
    P0 = np.array([v for v in calib.read_text().splitlines()[0].split() if ":" not in v], float).reshape(3, 4)
    return [P0[0, 0], P0[1, 1], P0[0, 2], P0[1, 2]]


@pytest.mark.shared_data
def test_kitti_registers_with_low_ate(tmp_path):
    data = shared_data_path("kitti_rural")
    conf = sfm.preset("fast", camera_model="PINHOLE", camera_params=kitti_intrinsics(data / "calib.txt"),
                      max_image_size=1241)
    out = run_stage(sfm.work(conf, data / "image_l", None), tmp_path / "sfm")
    q = json.loads((out / "quality.json").read_text())
    assert q["registered_fraction"] >= 0.98
    assert q["mean_reproj_error_px"] < 1.0
    assert (out / "sparse" / "0" / "images.bin").exists() and (out / "transforms.json").exists()
    posed = run_stage(metric.work(metric.MetricConfig(capture_height_m=1.65), out), tmp_path / "metric")
    report = evaluate(load_posed_clip(posed), load_kitti_poses(data / "poses.txt"))
    assert report["matched_fraction"] >= 0.98
    assert report["ate"]["rmse_pct_of_path"] <= 1.0
    # metric scale from the known KITTI camera height (1.65 m): Sim(3) scale close to 1
    assert report["ate"]["scale"] == pytest.approx(1.0, abs=0.1)
