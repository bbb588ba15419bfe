"""Free-space carving on a hand-made scene: a wall seen by a walking camera, one view with a
floater in front of it (what a splat render produces): fast unit tests."""

from __future__ import annotations

import numpy as np
import trimesh

from vid2sim.factory.geometry.carving import CarveConfig, free_space, keep_mask
from vid2sim.factory.geometry.meshing import DepthView, MeshingConfig, backproject, fuse_tsdf
from vid2sim.factory.geometry.raycast import RaycastRenderer, look_at

W, H = 80, 60
K = np.array([[60.0, 0, W / 2], [0, 60.0, H / 2], [0, 0, 1]])


def scene() -> trimesh.Trimesh:
    """Ground z = 0 (x 0..8, y -4..4) and a wall at x = 6 up to 2.5 m."""
    ground = trimesh.creation.box(extents=(8, 8, 0.02))
    ground.apply_translation((4, 0, -0.01))
    wall = trimesh.creation.box(extents=(0.2, 8, 2.5))
    wall.apply_translation((6.1, 0, 1.25))
    return trimesh.util.concatenate([ground, wall])


def views(floater: bool = True) -> list[DepthView]:
    """Cameras 1.5 m up walking along +x (x 0..2) looking at the wall; view 0 has a floater
    patch 1.5 m ahead of it at body height."""
    rend = RaycastRenderer(scene())
    out = []
    for i, x in enumerate(np.linspace(0.0, 2.0, 9)):
        c2w = look_at(np.array([x, 0.3 * np.sin(i), 1.5]), np.array([6.0, 0.0, 1.0]))
        o = rend.render(K, c2w, W, H)
        d = o.depth.copy()
        if floater and i == 0:
            d[20:40, 30:50] = 2.5  # a phantom surface 2.5 m ahead, between the walker and the wall
        out.append(DepthView(d, K, c2w, None, None))
    return out


def carve_masks(vs: list[DepthView], conf: CarveConfig) -> list[np.ndarray]:
    space = free_space([v.depth for v in vs], [v.K for v in vs], [v.cam_to_world for v in vs],
                       8.0, conf)
    carved = space.carved(conf)
    return [keep_mask(v.depth, v.K, v.cam_to_world, space, carved, conf) for v in vs]


def test_rays_of_other_views_carve_the_floater_and_keep_the_wall():
    vs = views()
    keep = carve_masks(vs, CarveConfig(body=False, rays=True))
    assert not keep[0][22:38, 32:48].any()  # floater pixels dropped
    pts0 = backproject(vs[0].depth, K, vs[0].cam_to_world)
    wall0 = (vs[0].depth > 0) & (pts0[..., 0] > 5.9)
    assert keep[0][wall0].mean() > 0.95  # the wall survives in view 0 ...
    for v, k in zip(vs[1:], keep[1:]):  # ... and in every other view
        assert k[v.depth > 0].mean() > 0.95


def test_body_carving_drops_depth_inside_the_walked_corridor_only():
    vs = views()
    keep = carve_masks(vs, CarveConfig(rays=False))
    # the floater at 2.5 m ahead of view 0 (x ~ 2.5) is beyond the walked path (x <= 2)
    # except where it lies above the path's x range: pixels whose points are inside the body
    pts0 = backproject(vs[0].depth, K, vs[0].cam_to_world)
    in_body = (pts0[..., 0] <= 2.0) & (np.abs(pts0[..., 1]) < 0.2) & (pts0[..., 2] > 0.25) & \
        (pts0[..., 2] < 1.35)
    assert not keep[0][in_body].any()
    ground = (vs[3].depth > 0) & (backproject(vs[3].depth, K, vs[3].cam_to_world)[..., 2] < 0.05)
    assert keep[3][ground].all()  # the ground under the body is never carved


def test_fusion_without_carving_keeps_the_phantom_and_with_carving_removes_it():
    def phantom_faces(conf: MeshingConfig) -> int:
        mesh = fuse_tsdf(views(), conf).collision
        c = np.asarray(mesh.vertices)[np.asarray(mesh.triangles)].mean(axis=1)  # [F, 3]
        return int(np.sum((c[:, 0] > 2.0) & (c[:, 0] < 3.5) & (c[:, 2] > 0.3)))

    assert phantom_faces(MeshingConfig(carve=None)) > 10
    assert phantom_faces(MeshingConfig(carve=CarveConfig(rays=True))) == 0


def test_meshing_views_can_leave_out_low_opacity_splats():
    import torch

    from vid2sim.factory.geometry.splat_views import SplatViewConfig, meshing_model
    from vid2sim.splats.model import GaussianModel

    xyz = torch.tensor([[0.0, 0.0, 2.0], [0.5, 0.0, 2.0], [1.0, 0.0, 2.0]])
    model = GaussianModel.from_points(xyz, torch.full((3, 3), 0.5), sh_degree=0, opacity=0.1)
    model.opacity_logits = torch.tensor([-3.0, 0.0, 3.0])  # opacities 0.05, 0.5, 0.95
    assert meshing_model(model, SplatViewConfig()).num == 3
    kept = meshing_model(model, SplatViewConfig(min_opacity=0.2))
    assert kept.num == 2 and float(kept.opacities.min()) > 0.2
