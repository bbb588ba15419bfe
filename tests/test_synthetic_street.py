"""Synthetic street: determinism, GT poses, depth vs mesh, video, walkable grid."""

from __future__ import annotations

import json

import av
import numpy as np
import open3d as o3d
import pytest

from vid2sim.factory.synthetic import SyntheticClip, generate_street, preset, render_video
from vid2sim.factory.synthetic.geometry import GROUND_MATERIALS
from vid2sim.factory.synthetic.mesh_io import read_mesh_ply
from vid2sim.factory.synthetic.render import StreetRenderer, rendered_frames


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> SyntheticClip:
    conf = preset("test", seed=3)
    return render_video(generate_street(conf), conf, tmp_path_factory.mktemp("syn") / "clip")


def test_generator_deterministic_per_seed():
    a, b = generate_street(preset("test", seed=5)), generate_street(preset("test", seed=5))
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.face_material, b.face_material)
    c = generate_street(preset("test", seed=6))
    assert a.vertices.shape != c.vertices.shape or not np.allclose(a.vertices, c.vertices)


def test_scene_has_all_parts():
    s = generate_street(preset("test", seed=0))
    assert set(np.unique(s.face_material)) >= set(range(1, 10))
    v, f = s.without_ground()
    assert 0 < len(f) < s.n_faces
    assert v[:, 2].max() > 5.0  # facades


def test_clip_files_and_video(clip):
    out = clip.out_dir
    for name in ("video.mp4", "cameras.parquet", "scene_mesh.ply", "ground_truth.json", "walkable_gt.npz"):
        assert (out / name).is_file(), name
    with av.open(str(clip.video)) as c:
        frames = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    assert len(frames) == 30 and frames[0].shape == (90, 160, 3)
    assert frames[10].std() > 20  # textured, not a flat image


def test_gt_poses_height_and_motion(clip):
    c = clip.cam_to_world[:, :3, 3]
    assert abs(c[:, 2].mean() - 1.5) < 0.02 and np.ptp(c[:, 2]) < 0.15
    speed = np.linalg.norm(np.diff(c, axis=0), axis=1).sum() / 1.0
    assert 1.2 < speed < 1.7
    R = clip.cam_to_world[:, :3, :3]
    assert np.allclose(np.einsum("nij,nkj->nik", R, R), np.eye(3), atol=1e-9)
    # optical axis looks roughly along +x, image "down" is roughly world -z
    assert (R[:, 0, 2] > 0.95).all() and (R[:, 2, 1] < -0.95).all()
    gt = json.loads((clip.out_dir / "ground_truth.json").read_text())
    assert gt["ground_plane"]["normal"] == [0.0, 0.0, 1.0] and gt["capture_height"] == 1.5


def test_depth_reprojects_onto_mesh(clip):
    mesh = read_mesh_ply(clip.mesh_path)
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.core.Tensor(mesh["vertices"].astype(np.float32)),
                     o3d.core.Tensor(mesh["triangles"].astype(np.uint32)))
    K = clip.K
    for i in (0, 17):
        depth = clip.depth(i)
        v, u = np.nonzero(depth > 0)
        assert len(u) > 0.5 * depth.size
        sel = np.random.default_rng(i).choice(len(u), 200, replace=False)
        u, v = u[sel] + 0.5, v[sel] + 0.5
        z = depth[v.astype(int), u.astype(int)]
        pc = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], 1)
        T = clip.cam_to_world[i]
        pw = pc @ T[:3, :3].T + T[:3, 3]
        dist = rc.compute_distance(o3d.core.Tensor(pw.astype(np.float32))).numpy()
        assert np.median(dist) < 2e-3 and np.percentile(dist, 95) < 1e-2


def test_walkable_gt_excludes_obstacles(clip):
    w = np.load(clip.out_dir / "walkable_gt.npz")
    grid, origin, res = w["grid"], w["origin"], float(w["resolution"])
    assert grid.dtype == np.uint8 and 0 < grid.mean() < 1
    s = generate_street(preset("test", seed=3))
    ob = s.obstacles[0]
    cx, cy = (ob.params[0], ob.params[1]) if ob.shape == "circle" else (
        (ob.params[0] + ob.params[2]) / 2, (ob.params[1] + ob.params[3]) / 2)
    assert grid[int((cy - origin[1]) / res), int((cx - origin[0]) / res)] == 0
    cam = clip.cam_to_world[0, :3, 3]
    assert grid[int((cam[1] - origin[1]) / res), int((cam[0] - origin[0]) / res)] == 1
    assert set(np.unique(read_mesh_ply(clip.mesh_path)["face_material"])) & set(GROUND_MATERIALS)


def test_render_skips_finished_work(clip):
    conf = preset("test", seed=3)
    mtime = clip.video.stat().st_mtime_ns
    again = render_video(generate_street(conf), conf, clip.out_dir)
    assert clip.video.stat().st_mtime_ns == mtime
    assert np.allclose(again.cam_to_world, clip.cam_to_world)


def test_frames_rendered_side_by_side_equal_one_at_a_time(clip):
    """Threads change when a frame is made, not what it holds; the video of the module's clip
    (rendered with every CPU) decodes to the frames made one at a time."""
    conf = preset("test", seed=3)
    renderer = StreetRenderer(generate_street(conf), conf)
    poses = clip.cam_to_world[::3]
    one = list(rendered_frames(renderer, poses, threads=1))
    many = list(rendered_frames(renderer, poses, threads=3))
    assert len(one) == len(many) == len(poses)
    for a, b in zip(one, many):
        for key in ("rgb", "depth", "normal"):
            np.testing.assert_array_equal(a[key], b[key])
    with av.open(str(clip.video)) as container:
        decoded = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)][::3]
    err = [np.abs(d.astype(int) - f["rgb"]).mean() for d, f in zip(decoded, one)]
    assert max(err) < 6.0  # H.264 at the clip's crf: the frames are the video's, in order
