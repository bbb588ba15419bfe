"""Synthetic GT scene bundle: validates with the registry and matches the GT mesh."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from vid2sim.factory.synthetic import GTBundleConfig, generate_street, preset, render_video, write_ground_truth_bundle
from vid2sim.formats.bundle import validate_bundle
from vid2sim.formats.walkable import load_walkable
from vid2sim.splats.ply import read_ply


@pytest.fixture(scope="module")
def bundle(tmp_path_factory):
    conf = preset("test", seed=11)
    scene = generate_street(conf)
    root = tmp_path_factory.mktemp("gtb")
    clip = render_video(scene, conf, root / "clip")
    out = write_ground_truth_bundle(scene, clip, root / "bundle", GTBundleConfig(n_splats=20_000))
    return scene, clip, out


def test_bundle_validates(bundle):
    scene, clip, out = bundle
    info = validate_bundle(out)
    assert info.scene_id == "synthetic-street-s11" and info.num_splats == 20_000
    assert info.frame_counts["all"] == len(clip.cam_to_world)
    assert info.scene["world_frame"]["scale_source"] == "synthetic_gt"
    assert (out / "visual_mesh.ply").is_file() and (out / "ground_truth.json").is_file()


def test_splats_lie_on_mesh_and_face_along_normals(bundle):
    scene, _, out = bundle
    m = read_ply(out / "splats.ply")
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.core.Tensor(scene.vertices.astype(np.float32)),
                     o3d.core.Tensor(scene.triangles.astype(np.uint32)))
    xyz = m.means.numpy()
    from scipy.spatial.transform import Rotation
    q = m.quats.numpy()
    R = Rotation.from_quat(np.c_[q[:, 1:], q[:, 0]]).as_matrix()
    axis = R[:, :, 2]  # the Gaussian's thin axis
    # shoot a ray back along the thin axis from 5 cm off the surface: it must hit the mesh at 5 cm
    # on a face perpendicular to that axis
    rays = np.concatenate([xyz + 0.05 * axis, -axis], 1).astype(np.float32)
    ans = rc.cast_rays(o3d.core.Tensor(rays))
    t = ans["t_hit"].numpy()
    assert np.mean(np.abs(t - 0.05) < 1e-3) > 0.98
    n = ans["primitive_normals"].numpy()
    assert np.median(np.abs(np.sum(axis * n, 1))) > 0.999
    s = m.log_scales.exp().numpy()
    assert (s[:, 2] < 0.25 * s[:, 0]).all()
    rgb = m.sh[:, 0].numpy() * 0.28209479 + 0.5
    assert rgb.std() > 0.05  # textured colours, not one flat colour


def test_collision_mesh_has_no_ground_and_walkable_matches(bundle):
    import trimesh
    scene, clip, out = bundle
    mesh = trimesh.load(out / "collision.ply", force="mesh", process=False)
    face_z = mesh.vertices[mesh.faces][:, :, 2]
    assert not (np.ptp(face_z, axis=1) < 1e-9)[face_z.max(1) < 1e-6].any()  # no flat faces at ground level
    walk = load_walkable(out / "walkable.npz")
    g2, o2, r2 = scene.walkable_grid()
    assert np.array_equal(walk.grid, g2) and np.allclose(walk.origin, o2) and walk.resolution == r2
