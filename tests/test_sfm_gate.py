"""sfm stage quality gate and lens choice: named failures, nothing marked done."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from vid2sim.factory.sfm import sfm
from vid2sim.factory.sfm.camera_model import LensHint, choose_camera_model
from vid2sim.factory.runtime.stage_cache import StageError
from vid2sim.factory.runtime.runner import run_stage


def _texture(rng: np.random.Generator, w: int = 640, h: int = 360) -> np.ndarray:
    """A textured scene (blurred noise at several scales) with plenty of SIFT keypoints."""
    img = np.zeros((h, w), np.float32)
    for k in (3, 9, 27):
        img += cv2.GaussianBlur(rng.normal(0, 1, (h, w)).astype(np.float32), (0, 0), k) * k
    img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX)
    return cv2.cvtColor(img.astype(np.uint8), cv2.COLOR_GRAY2BGR)


def _write_frames(folder: Path, frames: list[np.ndarray]) -> Path:
    folder.mkdir(parents=True)
    for i, f in enumerate(frames):
        cv2.imwrite(str(folder / f"{i:06d}.jpg"), f, [cv2.IMWRITE_JPEG_QUALITY, 95])
    return folder


def test_static_camera_fails_named(tmp_path):
    rng = np.random.default_rng(0)
    base = _texture(rng).astype(np.float32)
    frames = [np.clip(base + rng.normal(0, 2, base.shape), 0, 255).astype(np.uint8) for _ in range(12)]
    images = _write_frames(tmp_path / "images", frames)
    conf = sfm.preset("fast", max_image_size=640, max_num_features=1024, overlap=5)
    with pytest.raises(StageError) as e:
        run_stage(sfm.work(conf, images, None), tmp_path / "sfm")
    assert e.value.reason in ("static_camera", "too_few_registered")
    assert not (tmp_path / "sfm" / "stage.json").exists()
    assert sfm.load_quality(tmp_path / "sfm")["failed"] == e.value.reason


def test_too_few_frames_fails_named(tmp_path):
    rng = np.random.default_rng(1)
    images = _write_frames(tmp_path / "images", [_texture(rng, 160, 120) for _ in range(4)])
    with pytest.raises(StageError) as e:
        run_stage(sfm.work(sfm.preset("fast"), images, None), tmp_path / "sfm")
    assert e.value.reason == "too_few_frames"
    assert not (tmp_path / "sfm" / "stage.json").exists()


def test_missing_images_folder_is_named(tmp_path):
    with pytest.raises(StageError) as e:
        run_stage(sfm.work(sfm.preset("fast"), tmp_path / "nope", None), tmp_path / "sfm")
    assert e.value.reason == "missing_input"


def test_presets():
    fast, acc = sfm.preset("fast"), sfm.preset("accurate")
    assert fast.max_image_size < acc.max_image_size and fast.max_num_features < acc.max_num_features
    assert sfm.preset("fast", overlap=3).overlap == 3
    with pytest.raises(ValueError):
        sfm.preset("nope")


def test_loop_detection_without_vocab_tree_is_named(tmp_path):
    conf = sfm.preset("fast", loop_detection=True)
    with pytest.raises(StageError) as e:
        sfm.match(conf, tmp_path / "database.db")
    assert e.value.reason == "missing_vocab_tree"


@pytest.mark.parametrize("hint,expected", [
    (LensHint(make="GoPro", model="MAX"), "OPENCV"),
    (LensHint(hfov_deg=150.0), "OPENCV_FISHEYE"),
    (LensHint(wide=True, hfov_deg=120.0), "OPENCV"),
    (LensHint(make="Apple", model="iPhone 4S", focal_px=900.0), "OPENCV"),
    (LensHint(), "OPENCV"),
])
def test_lens_choice(hint, expected):
    choice = choose_camera_model(848, 480, hint)
    assert choice.model == expected
    if hint.focal_px:
        assert choice.params[0] == pytest.approx(hint.focal_px)


def test_requested_model_and_bad_model():
    assert choose_camera_model(640, 480, requested="SIMPLE_RADIAL").model == "SIMPLE_RADIAL"
    with pytest.raises(ValueError):
        choose_camera_model(640, 480, requested="KANNALA")


def test_cli_reports_named_error(tmp_path):
    from typer.testing import CliRunner

    from vid2sim.cli.app import app

    rng = np.random.default_rng(2)
    images = _write_frames(tmp_path / "images", [_texture(rng, 160, 120) for _ in range(3)])
    res = CliRunner().invoke(app, ["sfm", "run", "--images", str(images), "--out", str(tmp_path / "sfm")])
    assert res.exit_code == 2
    assert "too_few_frames" in res.output
