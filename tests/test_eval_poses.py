"""Pose evaluation: Umeyama, ATE/RPE, loaders (KITTI, transforms.json, COLMAP, PosedClip), GoPro."""

from __future__ import annotations

import json

import numpy as np
import pycolmap
import pytest
from scipy.spatial.transform import Rotation
from typer.testing import CliRunner

from tests.conftest import shared_data_path
from vid2sim.cli.app import app
from vid2sim.factory.evaluation.poses import (
    PoseEvalError, Trajectory, apply_sim3, ate, evaluate, gopro_rotation_errors, load_colmap_model,
    load_gopro_orientation, load_kitti_poses, load_trajectory, load_transforms_json, rpe, umeyama,
)
from vid2sim.factory.sfm.posed import PosedClip, PosedFrame
from vid2sim.factory.synthetic import StreetConfig
from vid2sim.factory.synthetic.trajectory import walking_poses


def random_traj(n: int = 60, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.05, (n, 3)), 0)).as_matrix()
    T[:, :3, 3] = np.cumsum(rng.normal(0, 0.3, (n, 3)) + [0.5, 0, 0], 0)
    return T


def random_sim3(seed: int = 1) -> tuple[float, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return float(rng.uniform(0.2, 5.0)), Rotation.random(random_state=seed).as_matrix(), rng.normal(0, 10, 3)


def test_umeyama_recovers_known_sim3():
    for seed in range(5):
        gt = random_traj(seed=seed)
        s, R, t = random_sim3(seed + 10)
        est = apply_sim3(gt, s, R, t)  # est = S(gt): aligning est -> gt must find S^-1
        s2, R2, t2 = umeyama(est[:, :3, 3], gt[:, :3, 3])
        assert s2 == pytest.approx(1 / s, rel=1e-9)
        assert np.allclose(R2, R.T, atol=1e-9) and np.allclose(s2 * R2 @ t + t2, 0, atol=1e-7)
        a = ate(est[:, :3, 3], gt[:, :3, 3])
        assert a["rmse"] < 1e-9 and a["rmse_pct_of_path"] < 1e-8


def test_ate_grows_with_noise():
    gt = random_traj()
    rng = np.random.default_rng(3)
    errs = []
    for sigma in (0.0, 0.01, 0.1, 0.5):
        est = gt[:, :3, 3] + rng.normal(0, sigma, gt[:, :3, 3].shape)
        errs.append(ate(est, gt[:, :3, 3])["rmse"])
    assert errs[0] < 1e-9 and errs[0] < errs[1] < errs[2] < errs[3]
    assert errs[2] == pytest.approx(0.1 * np.sqrt(3), rel=0.35)


def test_rpe_zero_for_identical_and_positive_for_perturbed():
    gt = random_traj()
    for d in (1, 5):
        r = rpe(gt, gt, d)
        assert r["trans_rmse"] < 1e-9 and r["rot_mean_deg"] < 1e-5
    noisy = gt.copy()
    noisy[:, :3, :3] = noisy[:, :3, :3] @ Rotation.from_rotvec(
        np.random.default_rng(0).normal(0, 0.02, (len(gt), 3))).as_matrix()
    assert rpe(noisy, gt, 1)["rot_mean_deg"] > 0.5


def test_evaluate_aligns_before_rpe():
    gt = random_traj(seed=4)
    s, R, t = random_sim3(2)
    keys = np.arange(len(gt))
    rep = evaluate(Trajectory(keys, apply_sim3(gt, s, R, t)), Trajectory(keys, gt), deltas=(1, 10))
    assert rep["ate"]["rmse"] < 1e-8 and rep["rpe"]["10"]["trans_rmse"] < 1e-7
    assert rep["rpe"]["1"]["rot_mean_deg"] < 1e-5 and rep["matched_fraction"] == 1.0


@pytest.mark.shared_data
def test_kitti_loader_on_real_file():
    path = shared_data_path("kitti_rural") / "poses.txt"
    traj = load_kitti_poses(path)
    assert len(traj) == 51 and np.allclose(traj.T[0], np.eye(4), atol=1e-6)
    R = traj.T[:, :3, :3]
    assert np.allclose(np.linalg.det(R), 1, atol=1e-5)
    length = np.linalg.norm(np.diff(traj.positions, axis=0), axis=1).sum()
    assert 10 < length < 200  # 51 frames at 10 Hz from a car
    s, Rs, t = random_sim3(5)
    rep = evaluate(Trajectory(traj.keys, apply_sim3(traj.T, s, Rs, t)), traj)
    assert rep["ate"]["rmse_pct_of_path"] < 1e-6 and rep["ate"]["scale"] == pytest.approx(1 / s)


@pytest.mark.shared_data
def test_transforms_json_loader_on_fox():
    path = shared_data_path("instant_ngp_fox") / "transforms.json"
    traj = load_transforms_json(path)
    assert len(traj) == len(json.loads(path.read_text())["frames"]) >= 50
    R = traj.T[:, :3, :3]
    assert np.allclose(np.linalg.det(R), 1, atol=1e-4)
    # orbit around the fox: OpenCV optical axes (+z) point roughly at the centroid of the cameras
    to_centre = traj.positions.mean(0) - traj.positions
    cosang = np.sum(R[:, :, 2] * to_centre, 1) / np.linalg.norm(to_centre, axis=1)
    assert np.median(cosang) > 0.5


def test_colmap_and_posed_clip_loaders(tmp_path):
    gt = random_traj(20, seed=7)
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera.create_from_model_name(1, "PINHOLE", 500.0, 640, 480))
    for i in range(0, 20, 2):  # every other frame "registered"
        w2c = np.linalg.inv(gt[i])
        q = Rotation.from_matrix(w2c[:3, :3]).as_quat()  # x y z w
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(q), w2c[:3, 3])
        rec.add_image_with_trivial_frame(pycolmap.Image(name=f"frame_{i:05d}.png", camera_id=1, image_id=i + 1), pose)
    (tmp_path / "sparse" / "0").mkdir(parents=True)
    rec.write(str(tmp_path / "sparse" / "0"))
    est = load_trajectory(tmp_path)  # auto-detects sparse/0
    assert list(est.keys) == list(range(0, 20, 2)) and np.allclose(est.T, gt[::2], atol=1e-9)
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    frames = [PosedFrame(i, f"frame_{i:05d}.png", i / 30, 640, 480, K, gt[i]) for i in range(20)]
    PosedClip(frames, tmp_path / "images").save(tmp_path / "gt")
    rep = evaluate(est, load_trajectory(tmp_path / "gt", "synthetic"))
    assert rep["n_matched"] == 10 and rep["matched_fraction"] == 0.5 and rep["ate"]["rmse"] < 1e-9
    with pytest.raises(PoseEvalError, match="unreadable COLMAP model|no registered"):
        load_colmap_model(tmp_path / "images_missing")


def test_synthetic_gt_vs_perturbed_estimate(tmp_path):
    conf = StreetConfig(duration_s=2.0)
    ts, T = walking_poses(conf)
    K = np.eye(3)
    gt_frames = [PosedFrame(i, f"frame_{i:05d}.png", ts[i], 64, 48, K, T[i]) for i in range(len(ts))]
    PosedClip(gt_frames, tmp_path).save(tmp_path / "gt")
    s, R, t = random_sim3(9)
    E = apply_sim3(T, s, R, t)
    E[:, :3, 3] += np.random.default_rng(0).normal(0, 0.01 * s, (len(E), 3))
    # estimate sampled at 15 fps: matched to GT frames by timestamp
    est_frames = [PosedFrame(j, f"e{j}.png", ts[i], 64, 48, K, E[i]) for j, i in enumerate(range(0, len(ts), 2))]
    PosedClip(est_frames, tmp_path).save(tmp_path / "est")
    rep = evaluate(load_trajectory(tmp_path / "est"), load_trajectory(tmp_path / "gt", "synthetic"))
    assert rep["n_matched"] == len(ts) // 2
    assert 0.005 < rep["ate"]["rmse"] < 0.03 and rep["ate"]["scale"] == pytest.approx(1 / s, rel=0.02)


def test_bad_inputs_raise_named_errors(tmp_path):
    bad = tmp_path / "poses.txt"
    bad.write_text("1 2 3\n")
    with pytest.raises(PoseEvalError, match="12 numbers"):
        load_kitti_poses(bad)
    with pytest.raises(PoseEvalError, match="does not exist"):
        load_trajectory(tmp_path / "nope")
    with pytest.raises(PoseEvalError, match="unknown pose format"):
        load_trajectory(bad, "xyz")


@pytest.mark.shared_data
def test_gopro_relative_rotation_fit_recovers_extrinsic():
    csv = shared_data_path("gopro_max_sidewalk") / "telemetry_orientation_per_frame.csv"
    idx, Rg = load_gopro_orientation(csv)
    assert len(idx) >= 315 and np.allclose(np.linalg.det(Rg), 1, atol=1e-4)
    X = Rotation.from_euler("xyz", [5, -90, 3], degrees=True).as_matrix()  # est camera -> IMU camera
    T = np.tile(np.eye(4), (len(idx), 1, 1))
    T[:, :3, :3] = Rotation.random(random_state=0).as_matrix() @ Rg @ X  # any world frame
    rep = gopro_rotation_errors(Trajectory(idx, T), csv)
    assert np.allclose(rep["extrinsic_cam_to_imu"], X, atol=1e-3)
    for d in rep["deltas"].values():
        assert d["fitted_mean_deg"] < 1e-3 and d["angle_gap_mean_deg"] < 1e-3
    noisy = T.copy()
    noisy[:, :3, :3] = noisy[:, :3, :3] @ Rotation.from_rotvec(
        np.random.default_rng(1).normal(0, 0.01, (len(idx), 3))).as_matrix()
    rep2 = gopro_rotation_errors(Trajectory(idx, noisy), csv)
    assert rep2["deltas"]["1"]["fitted_mean_deg"] > 0.3


@pytest.mark.shared_data
def test_cli_eval_poses_json():
    path = shared_data_path("kitti_rural") / "poses.txt"
    res = CliRunner().invoke(app, ["eval", "poses", "--estimate", str(path), "--gt", str(path),
                                   "--gt-format", "kitti", "--json"])
    assert res.exit_code == 0, res.output
    rep = json.loads(res.output)
    assert rep["n_matched"] == 51 and rep["ate"]["rmse"] < 1e-9
    res = CliRunner().invoke(app, ["eval", "poses", "--estimate", str(path) + ".missing", "--gt", str(path)])
    assert res.exit_code == 2


@pytest.mark.shared_data
def test_gopro_cori_convention_matches_gravity():
    """Documented convention: R(cori) maps world -> camera body, so R(cori)^T @ GRAV (a body-frame
    vector) is ~constant."""
    import csv as _csv
    path = shared_data_path("gopro_max_sidewalk") / "telemetry_orientation_per_frame.csv"
    _, c2w = load_gopro_orientation(path, stabilised=False)
    with open(path, newline="") as f:
        g = np.array([[float(r[f"grav_{a}"]) for a in "xyz"] for r in _csv.DictReader(f)])
    world_g = np.einsum("nij,nj->ni", c2w, g)  # R(q)^T g
    other = np.einsum("nji,nj->ni", c2w, g)  # R(q) g
    assert world_g.std(0).sum() < 0.5 * other.std(0).sum()
    assert world_g.std(0).max() < 0.03
