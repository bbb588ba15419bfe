"""Z-buffer compositing: a cone in front of a (real, rendered) splat wall is drawn, behind it hidden."""

from __future__ import annotations

import functools

import numpy as np
import pybullet as pb
import pytest
import torch
import trimesh

from vid2sim.envs.compositing import composite
from vid2sim.envs.pedestrians import Crowd
from vid2sim.envs.planning import GridPlanner
from vid2sim.formats.walkable import WalkableGrid
from vid2sim.envs.raster import rasterize
from vid2sim.splats.camera import Camera
from vid2sim.splats.model import GaussianModel
from vid2sim.splats.render import render

W, H = 64, 40
K = np.array([[40.0, 0.0, 32.0], [0.0, 40.0, 20.0], [0.0, 0.0, 1.0]])
# camera at the origin of the world, looking along +x (world z up): rows = camera x, y, z axes
W2C = np.array([[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]], dtype=np.float64)


@functools.lru_cache(maxsize=1)
def _splat_wall(x: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """Render a grey Gaussian wall at world x = `x` with the torch splat backend."""
    ys, zs = np.meshgrid(np.linspace(-5, 5, 60), np.linspace(-3, 3, 36))
    xyz = np.stack([np.full(ys.size, x), ys.ravel(), zs.ravel()], 1)
    model = GaussianModel.from_points(xyz, np.full(xyz.shape, 128, np.uint8), sh_degree=0,
                                      opacity=0.99)
    cam = Camera(K[0, 0], K[1, 1], K[0, 2], K[1, 2], W, H, torch.from_numpy(W2C))
    out = render(model, cam, backend="torch")
    rgb = (out.rgb.clamp(0, 1) * 255).round().to(torch.uint8).numpy()  # [H, W, 3]
    depth = torch.where(out.alpha > 0.5, out.depth, torch.zeros_like(out.depth)).numpy()
    return rgb, depth


def _cone(x: float) -> tuple[np.ndarray, np.ndarray]:
    """An orange 1 m cone standing at world (x, 0), base 0.3 m below the camera."""
    mesh = trimesh.creation.cone(radius=0.35, height=1.0, sections=16)
    v = mesh.vertices + [x, 0.0, -0.3]
    c = np.tile(np.array([[255, 100, 0]], np.uint8), (len(mesh.faces), 1))
    return rasterize(v, mesh.faces, c, K, W2C, W, H)


@pytest.mark.parametrize("cone_x, visible", [(2.5, True), (6.5, False)])
def test_cone_in_front_of_wall_drawn_behind_hidden(cone_x: float, visible: bool) -> None:
    wall_rgb, wall_depth = _splat_wall()
    assert (wall_depth[H // 2] == pytest.approx(5.0, abs=0.2))  # the base is a real splat wall
    cone_rgb, cone_depth = _cone(cone_x)
    cone_px = np.isfinite(cone_depth)
    assert cone_px.sum() > 5
    rgb, depth = composite(wall_rgb, wall_depth, cone_rgb, cone_depth)
    orange = (rgb == [255, 100, 0]).all(-1)
    if visible:
        assert orange[cone_px].all()
        assert np.allclose(depth[cone_px], cone_depth[cone_px])
    else:
        assert not orange.any()
        assert np.allclose(depth[cone_px], wall_depth[cone_px])


@pytest.mark.parametrize("person_x, visible", [(3.0, True), (7.0, False)])
def test_pedestrian_in_front_of_wall_drawn_behind_hidden(person_x: float, visible: bool) -> None:
    wall_rgb, wall_depth = _splat_wall()
    cid = pb.connect(pb.DIRECT)
    planner = GridPlanner(WalkableGrid(np.ones((40, 100), np.uint8), np.array([0.0, -2.0]), 0.1))
    crowd = Crowd(planner, 1, np.random.default_rng(0), cid)
    crowd.walkers[0].xy = np.array([person_x, 0.0])
    crowd.walkers[0].yaw = 0.0  # walking away from the camera: shoulders across the view
    p_rgb, p_depth = crowd.draw(K, W2C, W, H)
    pb.disconnect(cid)
    person = np.isfinite(p_depth)
    assert person.sum() > 12
    rgb, depth = composite(wall_rgb, wall_depth, p_rgb, p_depth)
    if visible:
        assert np.array_equal(rgb[person], p_rgb[person])
    else:
        assert np.array_equal(rgb[person], wall_rgb[person])
        assert np.allclose(depth[person], wall_depth[person])


def test_empty_pixels_of_either_layer_never_win() -> None:
    rgb_a = np.full((2, 2, 3), 10, np.uint8)
    rgb_b = np.full((2, 2, 3), 200, np.uint8)
    depth_a = np.array([[0.0, 3.0], [np.nan, np.inf]], np.float32)  # 0 = uncovered splat pixel
    depth_b = np.array([[5.0, np.inf], [2.0, 1.0]], np.float32)
    rgb, depth = composite(rgb_a, depth_a, rgb_b, depth_b)
    assert (rgb[..., 0] == [[200, 10], [200, 200]]).all()
    assert np.array_equal(depth, np.array([[5.0, 3.0], [2.0, 1.0]], np.float32))


def test_shape_mismatch_raises() -> None:
    with pytest.raises(ValueError, match="differ"):
        composite(np.zeros((2, 2, 3), np.uint8), np.zeros((2, 2)), np.zeros((3, 2, 3), np.uint8),
                  np.zeros((3, 2)))
