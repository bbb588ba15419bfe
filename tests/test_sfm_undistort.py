"""The sfm stage's undistortion against COLMAP's own (`pycolmap.undistort_images`)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from vid2sim.factory.sfm.undistort import undistort_project

W, H = 320, 180


def lens_model(tmp: Path):
    """A 3-frame model of an OPENCV camera with visible distortion, textured frames and masks."""
    import pycolmap

    rng = np.random.default_rng(0)
    rec = pycolmap.Reconstruction()
    cam = pycolmap.Camera.create_from_model_name(1, "OPENCV", 240.0, W, H)
    cam.params = [240.0, 236.0, 161.0, 88.0, -0.12, 0.03, 0.001, -0.002]
    rec.add_camera_with_trivial_rig(cam)
    (tmp / "images").mkdir()
    (tmp / "masks").mkdir()
    smooth = cv2.resize(rng.integers(0, 256, (H // 8, W // 8, 3), dtype=np.uint8), (W, H),
                        interpolation=cv2.INTER_CUBIC)
    for i in range(3):
        name = f"{i:06d}.jpg"
        keypoints = rng.uniform([0, 0], [W, H], (40, 2))
        image = pycolmap.Image(name=name, keypoints=keypoints, camera_id=1, image_id=i + 1)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d())
        cv2.imwrite(str(tmp / "images" / name), np.roll(smooth, 7 * i, axis=1), [cv2.IMWRITE_JPEG_QUALITY, 100])
        mask = np.full((H, W), 255, np.uint8)
        mask[40:90, 100:170] = 0
        cv2.imwrite(str(tmp / "masks" / f"{name}.png"), mask)
    return rec


def test_undistortion_matches_colmaps_and_ignores_the_thread_count(tmp_path):
    import pycolmap

    rec = lens_model(tmp_path)
    ours = {k: undistort_project(rec, tmp_path / "images", tmp_path / "masks", tmp_path / f"ours{k}", threads=k)
            for k in (1, 2)}
    (tmp_path / "lens").mkdir()
    rec.write(str(tmp_path / "lens"))
    pycolmap.undistort_images(str(tmp_path / "colmap"), str(tmp_path / "lens"), str(tmp_path / "images"),
                              output_type="COLMAP", num_threads=1)
    colmap = pycolmap.Reconstruction(str(tmp_path / "colmap" / "sparse"))
    reread = pycolmap.Reconstruction(str(tmp_path / "ours1" / "sparse"))
    for model in (ours[1], reread):
        assert model.cameras[1].model == colmap.cameras[1].model  # PINHOLE
        assert (model.cameras[1].width, model.cameras[1].height) == (colmap.cameras[1].width, colmap.cameras[1].height)
        np.testing.assert_allclose(model.cameras[1].params, colmap.cameras[1].params, rtol=1e-12)
        for image_id, image in colmap.images.items():
            np.testing.assert_allclose([p.xy for p in model.images[image_id].points2D],
                                       [p.xy for p in image.points2D], atol=1e-9)
    moved = np.abs(np.array([p.xy for p in rec.images[1].points2D]) -
                   np.array([p.xy for p in colmap.images[1].points2D])).max()
    assert moved > 1.0  # the distortion is visible: the points did move
    for name in ("000000.jpg", "000001.jpg", "000002.jpg"):
        a, b = (tmp_path / "ours1" / "images" / name).read_bytes(), (tmp_path / "ours2" / "images" / name).read_bytes()
        assert a == b
        mine = cv2.imread(str(tmp_path / "ours1" / "images" / name)).astype(int)
        theirs = cv2.imread(str(tmp_path / "colmap" / "images" / name)).astype(int)
        assert mine.shape == theirs.shape
        assert np.abs(mine - theirs).mean() < 1.5
        mask = cv2.imread(str(tmp_path / "ours1" / "masks" / f"{name}.png"), cv2.IMREAD_GRAYSCALE)
        assert mask.shape == mine.shape[:2] and set(np.unique(mask)) <= {0, 255}
        assert 0.05 < (mask == 0).mean() < 0.3  # the masked box, moved with the frame


def test_a_missing_registered_frame_is_named(tmp_path):
    rec = lens_model(tmp_path)
    (tmp_path / "images" / "000001.jpg").unlink()
    with pytest.raises(FileNotFoundError, match="000001.jpg"):
        undistort_project(rec, tmp_path / "images", None, tmp_path / "out")
