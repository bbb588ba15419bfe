"""metric stage on a synthetic street: known ground plane, cameras at 1.5 m, unknown Sim(3)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vid2sim.factory.sfm import metric
from vid2sim.factory.evaluation.poses import load_transforms_json
from vid2sim.factory.sfm.posed import PosedClip
from vid2sim.factory.runtime.stage_cache import StageError, mark_done
from vid2sim.factory.runtime.runner import run_stage

W, H, F = 640, 480, 400.0


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _street(rng: np.random.Generator, noise: float, outliers: int) -> tuple[np.ndarray, np.ndarray]:
    """World (z up, ground z=0) points [M, 3] and camera-to-world [N, 4, 4] walking along +x."""
    ground = np.c_[rng.uniform(-2, 25, 1500), rng.uniform(-3.5, 3.5, 1500), rng.normal(0, noise, 1500)]
    facade = np.c_[rng.uniform(-2, 25, 800), rng.choice([-4.0, 4.0], 800), rng.uniform(0.3, 6, 800)]
    junk = np.c_[rng.uniform(0, 20, outliers), rng.uniform(-3, 3, outliers), rng.uniform(-1, 3, outliers)]
    base = np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0]], float).T  # columns: camera x, y, z in world
    c2w = []
    for i in range(30):
        T = np.eye(4)
        yaw = 0.05 * np.sin(i / 5)
        Rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
        T[:3, :3] = Rz @ base
        T[:3, 3] = [0.4 * i, 0.05 * np.sin(i), 1.5 + 0.03 * np.sin(i * 1.3)]
        c2w.append(T)
    return np.concatenate([ground, facade, junk]), np.stack(c2w)


def _reconstruction(xyz: np.ndarray, c2w: np.ndarray):
    """A pycolmap model with the points observed where they project inside the images."""
    import pycolmap

    rec = pycolmap.Reconstruction()
    cam = pycolmap.Camera.create_from_model_name(1, "PINHOLE", F, W, H)
    rec.add_camera_with_trivial_rig(cam)
    K = cam.calibration_matrix()
    obs: dict[int, list[tuple[int, int]]] = {}
    for i, T in enumerate(c2w):
        w2c = np.linalg.inv(T)
        pc = xyz @ w2c[:3, :3].T + w2c[:3, 3]
        uv = pc @ K.T
        uv = uv[:, :2] / np.maximum(uv[:, 2:], 1e-9)
        vis = np.flatnonzero((pc[:, 2] > 0.3) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H))
        image = pycolmap.Image(name=f"{i:06d}.jpg", keypoints=uv[vis], camera_id=1, image_id=i + 1)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(w2c[:3, :4]))
        for k, p in enumerate(vis):
            obs.setdefault(int(p), []).append((i + 1, k))
    for p, els in obs.items():
        if len(els) >= 2:
            track = pycolmap.Track([pycolmap.TrackElement(i, k) for i, k in els])
            pid = rec.add_point3D(xyz[p], track, np.array([128, 128, 128], np.uint8))
            for i, k in els:
                rec.image(i).set_point3D_for_point2D(k, pid)
    return rec


def _hidden_sim3(rec, rng):
    import pycolmap

    s, R, t = 0.37, _rotation(rng), rng.normal(size=3) * 5
    rec.transform(pycolmap.Sim3d(s, pycolmap.Rotation3d(R), t))
    return s, R, t


@pytest.mark.parametrize("noise,outliers,tol_deg,tol_scale", [(0.0, 0, 1.0, 1e-6), (0.01, 200, 1.0, 0.02)])
def test_align_recovers_gravity_and_height(noise, outliers, tol_deg, tol_scale):
    rng = np.random.default_rng(3)
    xyz, c2w = _street(rng, noise, outliers)
    rec = _reconstruction(xyz, c2w)
    s0, R0, _ = _hidden_sim3(rec, rng)
    s, R, t, facts = metric.align(metric.MetricConfig(), rec, None)
    up_in_sfm = R0 @ np.array([0.0, 0.0, 1.0])
    assert metric.angle_deg(R[2], up_in_sfm) < tol_deg
    median_h = np.median(c2w[:, 2, 3])  # true median camera height (~1.5 m)
    assert s * s0 == pytest.approx(1.5 / median_h, rel=tol_scale)
    assert facts["scale_source"] == "capture_height"
    assert facts["camera_height_m"]["median"] == pytest.approx(1.5, rel=1e-6)
    assert facts["plane_residual_rms_m"] < 3 * noise + 1e-6


def _sfm_dir(tmp: Path, rec) -> Path:
    sfm = tmp / "sfm"
    (sfm / "undistorted" / "sparse").mkdir(parents=True)
    (sfm / "undistorted" / "images").mkdir()
    rec.write_binary(str(sfm / "undistorted" / "sparse"))
    (sfm / "quality.json").write_text(json.dumps({"images_dir": ""}))
    mark_done(sfm, "sfm", "synthetic", {}, 0.0)
    return sfm


def test_main_writes_posed_clip_in_metric_world(tmp_path):
    rng = np.random.default_rng(5)
    xyz, c2w = _street(rng, 0.005, 50)
    rec = _reconstruction(xyz, c2w)
    _hidden_sim3(rec, rng)
    conf = metric.MetricConfig(capture_height_m=1.6)
    out = run_stage(metric.work(conf, _sfm_dir(tmp_path, rec)), tmp_path / "metric")
    clip = PosedClip.load(out)
    assert len(clip.frames) == 30
    assert [f.split for f in clip.frames[:9]] == ["test"] + ["train"] * 7 + ["test"]
    z = np.array([f.cam_to_world[2, 3] for f in clip.frames])
    assert np.median(z) == pytest.approx(1.6, rel=1e-3)
    # cameras look level (OpenCV y axis points down = -z), walking along +x
    down = np.array([f.cam_to_world[:3, 1] for f in clip.frames]).mean(0)
    assert down[2] < -0.99
    x = np.array([f.cam_to_world[0, 3] for f in clip.frames])
    assert x[-1] - x[0] == pytest.approx(0.4 * 29 * 1.6 / np.median(c2w[:, 2, 3]), rel=0.02)
    assert abs(np.percentile(clip.points_xyz[:, 2], 20)) < 0.05  # many points on the ground at z=0
    assert clip.frame_info["scale_source"] == "capture_height"
    assert (out / "sparse" / "images.bin").exists()
    exported = load_transforms_json(out / "transforms.json")  # OpenGL axes back to OpenCV
    ours = np.stack([f.cam_to_world for f in clip.frames])
    np.testing.assert_allclose(exported.T, ours, atol=1e-9)
    assert run_stage(metric.work(metric.MetricConfig(capture_height_m=1.6), tmp_path / "sfm"), out) == out  # cached


def test_no_ground_points_is_a_named_error(tmp_path):
    rng = np.random.default_rng(7)
    xyz, c2w = _street(rng, 0.0, 0)
    rec = _reconstruction(xyz[1500:], c2w)  # facades only: little below the cameras
    with pytest.raises(StageError) as e:
        run_stage(metric.work(metric.MetricConfig(min_ground_points=10_000), _sfm_dir(tmp_path, rec)), tmp_path / "m")
    assert e.value.reason == "no_ground_plane"
    assert not (tmp_path / "m" / "stage.json").exists()


def test_missing_sfm_input_is_named(tmp_path):
    with pytest.raises(StageError) as e:
        run_stage(metric.work(metric.MetricConfig(), tmp_path / "nope"), tmp_path / "m")
    assert e.value.reason == "missing_input"
