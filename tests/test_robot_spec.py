"""One robot spec (`vid2sim.formats.robot.ROBOT`): the factory and the envs read it and agree.

Fails when any of them describes the robot by hand again and drifts: the envs' box, bicycle
model and camera, the walkable map's body band and clearance, the walker's body radius of the
carving and the corridor check, the sim-ready views' camera, and the spec a bundle records in
its scene.json."""

from __future__ import annotations

import json
from dataclasses import fields

import numpy as np
import pytest
import trimesh

from vid2sim.envs.camera import splat_camera, world_to_camera
from vid2sim.envs.config import CameraConfig, RobotConfig
from vid2sim.factory.evaluation.corridor import CorridorConfig
from vid2sim.factory.geometry.carving import CarveConfig
from vid2sim.factory.geometry.walkable import WalkableConfig
from vid2sim.factory.geometry.walked_path import BODY_RADIUS_M
from vid2sim.formats.errors import BundleError
from vid2sim.formats.robot import ROBOT, RobotSpec
from vid2sim.formats.scene import check_scene_json, make_scene_json
from vid2sim.splats.cpu.env_simready import SimReadyConfig, robot_cameras


def test_the_spec_is_the_documented_robot():
    assert (ROBOT.length_m, ROBOT.width_m, ROBOT.height_m, ROBOT.ground_clearance_m) == (0.9, 0.6, 0.6, 0.15)
    assert (ROBOT.wheelbase_m, ROBOT.max_steer_deg, ROBOT.max_speed_mps) == (0.8, 30.0, 1.0)
    assert ROBOT.walker_radius_m == 0.25
    assert (ROBOT.body_bottom_m, ROBOT.body_top_m) == (0.15, 0.75)
    assert (ROBOT.camera_height_m, ROBOT.camera_forward_m) == (0.65, 0.45)
    assert (ROBOT.camera_width_px, ROBOT.camera_height_px, ROBOT.camera_vfov_deg) == (128, 72, 60.0)
    assert ROBOT.camera_focal_px == pytest.approx(62.354, abs=1e-3)


def _robot_from_envs(robot: RobotConfig, cam: CameraConfig) -> RobotSpec:
    """The spec as the envs' configs state it (the walker radius is the factory's alone)."""
    return RobotSpec(length_m=robot.length, width_m=robot.width, height_m=robot.height,
                     ground_clearance_m=robot.ground_clearance, wheelbase_m=robot.wheelbase,
                     max_steer_deg=robot.max_steer_deg, max_speed_mps=robot.max_speed,
                     walker_radius_m=ROBOT.walker_radius_m, camera_height_m=cam.mount_height,
                     camera_forward_m=cam.mount_forward, camera_width_px=cam.width,
                     camera_height_px=cam.height, camera_vfov_deg=cam.vfov_deg)


def test_the_envs_robot_and_camera_are_the_spec():
    assert _robot_from_envs(RobotConfig(), CameraConfig()) == ROBOT
    assert CameraConfig().focal == pytest.approx(ROBOT.camera_focal_px)


def test_the_factory_clears_the_envs_robot():
    walk, robot = WalkableConfig(), RobotConfig()
    # the body band the map keeps free is the envs' box, bottom to top
    assert walk.body_bottom_m == robot.ground_clearance == ROBOT.body_bottom_m
    assert walk.body_top_m == pytest.approx(robot.ground_clearance + robot.height)
    assert walk.body_top_m == ROBOT.body_top_m
    # one walker body: map clearance, body carving and corridor check
    assert walk.robot_radius_m == BODY_RADIUS_M == CarveConfig().body_radius_m == \
        CorridorConfig().body_radius_m == ROBOT.walker_radius_m
    assert SimReadyConfig().width == CameraConfig().width and SimReadyConfig().height == CameraConfig().height


def test_the_sim_ready_views_use_the_envs_camera():
    """robot_cameras (what the sim-ready set and its benchmarks measure on) gives the env's own
    camera, mount and intrinsics, for the same robot pose."""
    conf = CameraConfig()
    rng = np.random.default_rng(0)
    xy, yaw = rng.uniform(-5, 5, (6, 2)), rng.uniform(-np.pi, np.pi, 6)
    for cam, (x, y), a in zip(robot_cameras(xy, yaw), xy, yaw):
        env = splat_camera(conf, world_to_camera(float(x), float(y), float(a), conf))
        assert (cam.width, cam.height) == (env.width, env.height)
        assert np.allclose([cam.fx, cam.fy, cam.cx, cam.cy], [env.fx, env.fy, env.cx, env.cy])
        assert np.allclose(cam.world_to_cam.numpy(), env.world_to_cam.numpy(), atol=1e-9)


def _scene(**kw) -> dict:
    return make_scene_json("s-1", source_uri="file:///v.mp4", source_sha256="a" * 64, clip_start_s=0,
                           clip_end_s=10, scale_source="capture_height", **kw)


def test_scene_json_records_and_checks_the_robot():
    scene = _scene(robot=ROBOT)
    assert RobotSpec.from_dict(json.loads(json.dumps(scene))["robot"]) == ROBOT
    assert "robot" not in _scene()  # optional: earlier bundles have none
    for bad in ({**ROBOT.to_dict(), "length_m": -1.0}, {**ROBOT.to_dict(), "wings": 2},
                {k: v for k, v in ROBOT.to_dict().items() if k != "wheelbase_m"}, [0.9]):
        with pytest.raises(BundleError, match="invalid robot"):
            check_scene_json({**scene, "robot": bad})


def test_an_assembled_bundle_records_the_robot_the_envs_drive(tmp_path, monkeypatch):
    from vid2sim.factory.geometry import meshing, walkable
    from vid2sim.factory.ingest.clips import ClipSpec
    from vid2sim.factory.ingest.sources import Source
    from vid2sim.factory.runtime.steps import bundle, meshing as meshing_step, metric, recon
    from vid2sim.factory.runtime.steps import walkable as walkable_step
    from vid2sim.factory.runtime.pipeline import ClipJob, PipelineConfig
    from vid2sim.factory.runtime.runner import run_stage
    from vid2sim.factory.sfm.posed import PosedClip, PosedFrame
    from vid2sim.formats.bundle import validate_bundle
    from vid2sim.formats.walkable import WalkableGrid
    from vid2sim.splats.cpu.synthetic import street_scene
    from vid2sim.splats.ply import write_ply

    K = np.array([[40.0, 0, 32], [0, 40.0, 18], [0, 0, 1]])
    frames = []
    for i, x in enumerate(np.linspace(-2.0, 2.0, 5)):
        c2w = np.eye(4)
        c2w[:3, :3] = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)  # looking along +x
        c2w[:3, 3] = (x, 0.0, 1.5)
        frames.append(PosedFrame(i, f"{i:06d}.jpg", i / 10, 64, 36, K, c2w))
    posed = PosedClip(frames, tmp_path / "images", frame_info={"scale_source": "capture_height"}
                      ).save(tmp_path / "metric")
    dirs = {k: tmp_path / k for k in ("recon", "meshing", "walkable")}
    for d in dirs.values():
        d.mkdir()
    write_ply(street_scene(300, length=8.0, seed=0), dirs["recon"] / "splats.ply")
    box = trimesh.creation.box(extents=(1.0, 0.6, 1.0))
    box.apply_translation((0.0, 1.5, 0.5))
    box.export(dirs["meshing"] / meshing.OUTPUTS.visual)
    box.export(dirs["walkable"] / walkable.OUTPUTS.collision)
    WalkableGrid(np.ones((30, 60), np.uint8), np.array([-3.0, -1.5]), 0.1).save(
        dirs["walkable"] / walkable.OUTPUTS.grid)
    source = Source("video", tmp_path / "v.mp4", "file:///v.mp4", "b" * 64)
    job = ClipJob(ClipSpec("clip0", source, (0.0, 0.4), "g"), "robot-spec-1", "CC0")
    inputs = bundle.Inputs(metric.Outputs(posed), recon.Outputs(dirs["recon"]), meshing_step.Outputs(dirs["meshing"]),
                           walkable_step.Outputs(dirs["walkable"]))
    out = run_stage(bundle.work(bundle.configure(PipelineConfig(), job), inputs), tmp_path / "bundle")
    info = validate_bundle(bundle.Outputs(out).scene)
    recorded = RobotSpec.from_dict(info.scene["robot"])
    assert recorded == ROBOT == _robot_from_envs(RobotConfig(), CameraConfig())
    assert sorted(f.name for f in fields(RobotSpec)) == sorted(info.scene["robot"])
