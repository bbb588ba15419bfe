"""The sfm stage is reproducible: the same frames give the same COLMAP model, bit for bit.

Every later stage (metric frame, splats, collision mesh, walkable map) inherits the SfM model,
so a scene can only be rebuilt from its video when this holds (`SfMConfig.deterministic`).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from conftest import shared_data_path
from test_sfm_kitti import kitti_intrinsics
from vid2sim.factory.sfm import sfm
from vid2sim.factory.runtime.runner import run_stage


def model_fingerprint(sfm_dir: Path) -> dict:
    """Camera parameters, each image's id and pose, and the 3D points of a finished sfm stage."""
    import pycolmap

    rec = pycolmap.Reconstruction(str(sfm_dir / "sparse" / "0"))
    images = sorted(rec.images.values(), key=lambda im: im.name)
    return {
        "params": np.concatenate([np.asarray(c.params) for c in rec.cameras.values()]),
        "ids": [(im.name, im.image_id) for im in images],
        "centres": np.array([im.projection_center() for im in images]),  # [N, 3]
        "points": np.array(sorted(tuple(p.xyz) for p in rec.points3D.values())),  # [P, 3]
    }


def kitti_frames(tmp_path: Path, n: int = 16) -> tuple[Path, list[float]]:
    """The first n KITTI frames copied into tmp_path/frames, and the camera's PINHOLE intrinsics."""
    data = shared_data_path("kitti_rural")
    frames = tmp_path / "frames"
    frames.mkdir()
    for name in sorted(p.name for p in (data / "image_l").iterdir())[:n]:
        shutil.copy(data / "image_l" / name, frames / name)
    return frames, kitti_intrinsics(data / "calib.txt")


@pytest.mark.shared_data
def test_same_frames_give_the_same_model(tmp_path):
    frames, K = kitti_frames(tmp_path)
    conf = sfm.preset("fast", camera_model="PINHOLE", camera_params=K, max_image_size=800, undistort=False)
    assert conf.deterministic and sfm.colmap_threads(conf) == 1
    runs = [model_fingerprint(run_stage(sfm.work(conf, frames, None), tmp_path / f"sfm{i}")) for i in range(2)]
    assert len(runs[0]["ids"]) >= 15 and len(runs[0]["points"]) > 200
    assert runs[0]["ids"] == runs[1]["ids"]
    for key in ("params", "centres", "points"):
        assert runs[0][key].shape == runs[1][key].shape and np.array_equal(runs[0][key], runs[1][key]), key
