"""The env mesh rasteriser: numba kernel vs numpy reference, depth, occlusion, near clipping."""

from __future__ import annotations

import numpy as np
import pytest

from vid2sim.envs.raster import NEAR, rasterize, rasterize_reference

W, H = 64, 40
K = np.array([[40.0, 0.0, 32.0], [0.0, 40.0, 20.0], [0.0, 0.0, 1.0]])
EYE = np.eye(4)


def _quad(z_left: float, z_right: float, color=(200, 10, 10)):
    """A plane spanning x in [-6, 6], y in [-4, 4] with depth z_left..z_right along x."""
    v = np.array([[-6, -4, z_left], [6, -4, z_right], [6, 4, z_right], [-6, 4, z_left]], np.float32)
    f = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    return v, f, np.array([color, color], np.uint8)


def _random_soup(rng: np.random.Generator, n: int):
    centres = rng.uniform([-2, -1.5, -0.5], [2, 1.5, 6], size=(n, 1, 3))
    v = (centres + rng.normal(0, 0.6, size=(n, 3, 3))).reshape(-1, 3).astype(np.float32)
    f = np.arange(3 * n, dtype=np.int32).reshape(n, 3)
    return v, f, rng.integers(0, 256, size=(n, 3), dtype=np.uint8)


def test_kernel_agrees_with_reference_including_near_clipping() -> None:
    v, f, c = _random_soup(np.random.default_rng(0), 300)
    crossing = ((v[f][:, :, 2] < NEAR).any(1) & (v[f][:, :, 2] >= NEAR).any(1)).sum()
    assert crossing > 20  # the soup really exercises the near-plane clipping
    rgb, depth = rasterize(v, f, c, K, EYE, W, H)
    rgb_r, depth_r = rasterize_reference(v, f, c, K, EYE, W, H)
    both = np.isfinite(depth) & np.isfinite(depth_r)
    assert (np.isfinite(depth) != np.isfinite(depth_r)).mean() < 0.002
    assert np.allclose(depth[both], depth_r[both], rtol=1e-5)
    assert (rgb != rgb_r).any(-1).mean() < 0.002
    assert np.isfinite(depth).mean() > 0.5


def test_tilted_plane_depth_is_perspective_correct() -> None:
    v, f, c = _quad(2.0, 6.0)
    rgb, depth = rasterize(v, f, c, K, EYE, W, H)
    jj, ii = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    dx = (jj - K[0, 2]) / K[0, 0]  # ray x per unit z
    z_true = 4.0 / (1.0 - dx / 3.0)  # plane z = 4 + x / 3 intersected with the ray x = dx z
    inside = np.isfinite(depth)
    assert inside.all()
    assert np.allclose(depth[inside], z_true[inside], rtol=1e-4)
    assert (rgb[inside] == [200, 10, 10]).all()
    assert (rgb[~inside] == 0).all()


def test_nearest_surface_wins_in_any_draw_order() -> None:
    vf, ff, cf = _quad(2.0, 2.0, (0, 255, 0))
    vb, fb, cb = _quad(5.0, 5.0, (0, 0, 255))
    for order in ((vf, ff, cf, vb, fb, cb), (vb, fb, cb, vf, ff, cf)):
        v = np.concatenate([order[0], order[3]])
        f = np.concatenate([order[1], order[4] + 4])
        rgb, depth = rasterize(v, f, np.concatenate([order[2], order[5]]), K, EYE, W, H)
        assert (rgb[H // 2, W // 2] == [0, 255, 0]).all()
        assert depth[H // 2, W // 2] == pytest.approx(2.0)


def test_geometry_behind_camera_is_clipped_not_wrapped() -> None:
    behind = np.array([[-1, -1, -2], [1, -1, -2], [0, 1, -2]], np.float32)
    rgb, depth = rasterize(behind, np.array([[0, 1, 2]], np.int32),
                           np.array([[9, 9, 9]], np.uint8), K, EYE, W, H)
    assert np.isinf(depth).all() and (rgb == 0).all()
    # a floor from behind the camera to 10 m ahead, 1 m below: only the lower half is drawn
    floor = np.array([[-20, 1, -5], [20, 1, -5], [20, 1, 10], [-20, 1, 10]], np.float32)
    rgb, depth = rasterize(floor, np.array([[0, 1, 2], [0, 2, 3]], np.int32),
                           np.array([[50, 50, 50]] * 2, np.uint8), K, EYE, W, H)
    assert np.isinf(depth[: H // 2]).all()
    assert np.isfinite(depth[H // 2 + 4:]).all()  # the far edge (z = 10 m) projects to v = 24
    assert depth[np.isfinite(depth)].min() >= NEAR


def test_world_to_cam_moves_the_camera() -> None:
    v, f, c = _quad(3.0, 3.0)
    w2c = np.eye(4)
    w2c[2, 3] = -1.0  # camera 1 m further forward: plane at 2 m
    _, depth = rasterize(v, f, c, K, w2c, W, H)
    assert depth[H // 2, W // 2] == pytest.approx(2.0)


def test_bad_shapes_raise() -> None:
    v, f, c = _quad(2.0, 2.0)
    with pytest.raises(ValueError, match="face_colors"):
        rasterize(v, f, c[:1], K, EYE, W, H)
    with pytest.raises(ValueError, match="vertices"):
        rasterize(v[:, :2], f, c, K, EYE, W, H)


def test_rasterize_into_is_the_composite_over_a_layer() -> None:
    """Drawing over a layer in place equals rasterising alone and compositing by z-buffer."""
    from vid2sim.envs.compositing import composite
    from vid2sim.envs.raster import rasterize_into

    rng = np.random.default_rng(3)
    v, f, c = _random_soup(rng, 120)
    rgb_a = rng.integers(0, 256, size=(H, W, 3), dtype=np.uint8)
    depth_a = rng.uniform(0.5, 5.0, size=(H, W)).astype(np.float32)
    depth_a[rng.random((H, W)) < 0.3] = np.inf  # empty splat pixels
    want_rgb, want_depth = composite(rgb_a, depth_a, *rasterize(v, f, c, K, EYE, W, H))
    rgb, depth = rgb_a.copy(), depth_a.copy()
    rasterize_into(v, f, c, K, EYE, rgb, depth)
    np.testing.assert_array_equal(rgb, want_rgb)
    np.testing.assert_array_equal(depth, want_depth)
    assert (rgb != rgb_a).any(-1).mean() > 0.1 and (rgb == rgb_a).all(-1).mean() > 0.1
    with pytest.raises(ValueError, match="rasterize_into"):
        rasterize_into(v, f, c, K, EYE, rgb.astype(np.float32), depth)
