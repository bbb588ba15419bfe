"""Walkable map and geometry metrics on analytic inputs (no fusion): fast unit tests."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from vid2sim.factory.geometry import walkable
from vid2sim.factory.evaluation.geometry_metrics import chamfer_distance, grid_iou
from vid2sim.factory.geometry.walkable import WalkableConfig, WalkableError, walkable_map
from vid2sim.formats.errors import BundleError
from vid2sim.formats.walkable import WalkableGrid, load_walkable
from vid2sim.factory.runtime.runner import run_stage


def plane_points(x0, x1, y0, y1, step=0.05) -> np.ndarray:
    x, y = np.meshgrid(np.arange(x0, x1, step) + step / 2, np.arange(y0, y1, step) + step / 2)
    return np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)


def box(cx, cy, sx, sy, h, z0=0.0) -> trimesh.Trimesh:
    b = trimesh.creation.box(extents=(sx, sy, h))
    b.apply_translation((cx, cy, z0 + h / 2))
    return b


PATH = np.array([[x, 0.0, 1.5] for x in np.linspace(-3.5, 3.5, 15)])  # walks along +x


def test_obstacle_footprint_inflated_by_robot_radius():
    conf = WalkableConfig(robot_radius_m=0.4)
    wm = walkable_map(plane_points(-4, 4, -2, 2), box(0, 1.2, 1.0, 0.6, 1.0), PATH, conf)
    # box covers x in [-0.5, 0.5], y in [0.9, 1.5]
    assert not wm.lookup(np.array([0.0, 0.0, 0.0]), np.array([1.2, 0.9 - 0.3, 1.5 + 0.3])).any()
    assert wm.lookup(np.array([0.0, -0.9 + 0.0, 1.0]), np.array([0.9 - 0.6, 0.0, 0.2])).all()
    assert wm.lookup(PATH[:, 0], PATH[:, 1]).all()
    # a bigger robot blocks more
    big = walkable_map(plane_points(-4, 4, -2, 2), box(0, 1.2, 1.0, 0.6, 1.0), PATH,
                       WalkableConfig(robot_radius_m=0.8))
    assert big.area_m2() < wm.area_m2() - 1.0


def test_height_band_ignores_low_and_overhead_geometry():
    kerb = box(0, 1.0, 1.0, 1.0, 0.05)  # 5 cm: below the band
    awning = box(0, -1.0, 1.0, 1.0, 0.2, z0=2.2)  # above the band
    mesh = trimesh.util.concatenate([kerb, awning])
    wm = walkable_map(plane_points(-4, 4, -2, 2), mesh, PATH, WalkableConfig())
    assert wm.lookup(np.array([0.0, 0.0]), np.array([1.0, -1.0])).all()
    wall = box(0, 1.0, 1.0, 1.0, 3.0)  # spans the band
    wm2 = walkable_map(plane_points(-4, 4, -2, 2), wall, PATH, WalkableConfig())
    assert not wm2.lookup(np.array([0.0]), np.array([1.0])).any()


def test_only_the_path_component_is_kept():
    wall = box(0, 1.0, 8.0, 0.2, 1.0)  # splits the ground at y = 1
    wm = walkable_map(plane_points(-4, 4, -2, 3), wall, PATH, WalkableConfig())
    assert wm.lookup(np.array([0.0]), np.array([-1.0])).all()
    assert not wm.lookup(np.array([0.0, 2.0]), np.array([2.5, 2.5])).any()  # other side


def test_unseen_ground_is_not_walkable_and_small_holes_close():
    gp = plane_points(-4, 4, -2, 2)
    hole = (np.abs(gp[:, 0] - 2.0) < 0.12) & (np.abs(gp[:, 1] - 1.0) < 0.12)  # 0.25 m gap
    wm = walkable_map(gp[~hole], None, PATH, WalkableConfig())
    assert wm.lookup(np.array([2.0]), np.array([1.0])).all()  # closed
    assert not wm.lookup(np.array([0.0, 0.0]), np.array([3.0, -3.0])).any()  # never seen


def test_path_off_ground_raises():
    far_path = PATH + np.array([0.0, 20.0, 0.0])
    with pytest.raises(WalkableError) as e:
        walkable_map(plane_points(-4, 4, -2, 2), None, far_path,
                     WalkableConfig(path_radius_m=0.0, walked_radius_m=0.0,
                                    max_dist_from_path_m=100.0))
    assert e.value.reason == "path_off_ground"
    with pytest.raises(WalkableError, match="bad_camera_path"):
        walkable_map(plane_points(-4, 4, -2, 2), None, np.zeros((0, 3)), WalkableConfig())


def test_npz_round_trip_and_bad_files(tmp_path):
    wm = walkable_map(plane_points(-4, 4, -2, 2), box(0, 1.2, 1.0, 0.6, 1.0), PATH,
                      WalkableConfig())
    p = wm.save(tmp_path / "walkable.npz")
    with np.load(p) as z:
        assert set(z.files) == {"grid", "origin", "resolution"}
        assert z["grid"].dtype == np.uint8 and z["origin"].shape == (2,)
    back = load_walkable(p)
    assert np.array_equal(back.grid, wm.grid) and np.allclose(back.origin, wm.origin)
    assert back.resolution == wm.resolution and grid_iou(back, wm) == 1.0
    np.savez(tmp_path / "nokeys.npz", grid=wm.grid)
    with pytest.raises(BundleError, match="lacks key.*origin"):
        load_walkable(tmp_path / "nokeys.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(BundleError, match="junk.npz"):
        load_walkable(tmp_path / "junk.npz")


def test_walkable_stage_rejects_unreadable_mesh(tmp_path):
    (tmp_path / "collision.ply").write_text("garbage")
    with pytest.raises(WalkableError) as e:
        run_stage(walkable.work(WalkableConfig(), plane_points(-1, 1, -1, 1), tmp_path / "collision.ply", PATH),
                  tmp_path / "out")
    assert e.value.reason == "bad_collision_mesh" and not (tmp_path / "out").exists()


def test_point_files_that_are_unreadable_or_misshapen_are_named_errors(tmp_path):
    good = tmp_path / "ground_points.npy"
    np.save(good, plane_points(-1, 1, -1, 1).astype(np.float32))
    assert walkable.load_points(good, "bad_ground_points").shape[1] == 3
    (tmp_path / "carved_points.npy").write_bytes(b"truncated")
    np.save(tmp_path / "flat.npy", np.zeros((5, 2), np.float32))
    for name in ("carved_points.npy", "flat.npy", "absent.npy"):
        with pytest.raises(WalkableError) as e:
            walkable.load_points(tmp_path / name, "bad_carved_points")
        assert e.value.reason == "bad_carved_points" and name in str(e.value)


def test_grid_iou_resamples_across_resolution_and_origin():
    a = WalkableGrid(np.ones((20, 20), np.uint8), (0.0, 0.0), 0.1)  # [0, 2]^2
    b = WalkableGrid(np.ones((10, 10), np.uint8), (1.0, 0.0), 0.2)  # [1, 3] x [0, 2]
    assert grid_iou(a, b) == pytest.approx(2.0 / 6.0, abs=1e-6)
    c = WalkableGrid(np.ones((40, 40), np.uint8), (0.0, 0.0), 0.05)  # same square, finer
    assert grid_iou(a, c) == pytest.approx(1.0)
    empty = WalkableGrid(np.zeros((5, 5), np.uint8), (0.0, 0.0), 0.1)
    assert grid_iou(empty, empty) == 1.0 and grid_iou(a, empty) == 0.0


def test_chamfer_distance_of_shifted_meshes():
    m = box(0, 0, 2.0, 2.0, 2.0)
    same = chamfer_distance(m, m.copy(), n_samples=20_000)
    assert same.symmetric < 0.02
    shifted = m.copy()
    shifted.apply_translation((0, 0, 0.3))
    ch = chamfer_distance(m, shifted, n_samples=20_000)
    # top/bottom faces are 0.3 m apart, side faces overlap except a 0.3 m strip
    assert 0.05 < ch.a_to_b < 0.3 and ch.symmetric == pytest.approx((ch.a_to_b + ch.b_to_a) / 2)


def test_obstacle_heights_are_relative_to_the_local_ground():
    gp = plane_points(-4, 4, -2, 2)
    gp[:, 2] = 0.5  # a raised platform (e.g. an alignment offset)
    bump = box(-2.0, 1.0, 0.6, 0.6, 0.05, z0=0.5)  # 5 cm above the local ground: walkable
    block = box(2.0, 1.0, 0.6, 0.6, 0.3, z0=0.5)  # 30 cm: an obstacle
    path = PATH + np.array([0, 0, 0.5])
    wm = walkable_map(gp, trimesh.util.concatenate([bump, block]), path, WalkableConfig())
    assert wm.lookup(np.array([-2.0]), np.array([1.0])).all()
    assert not wm.lookup(np.array([2.0]), np.array([1.0])).any()


def test_kerb_drop_blocks_like_an_obstacle():
    side = plane_points(-4, 4, -0.5, 2)  # sidewalk at z = 0 (the path is on it)
    road = plane_points(-4, 4, -3, -0.5)
    road[:, 2] = -0.12  # a 12 cm kerb drop at y = -0.5
    gp = np.concatenate([side, road])
    for conf in (WalkableConfig(), WalkableConfig(kerb=None, max_step_m=0.08)):  # kerb profile, local test
        wm = walkable_map(gp, None, PATH, conf)
        assert wm.lookup(np.array([0.0]), np.array([0.5])).all()
        assert not wm.lookup(np.array([0.0, 0.0]), np.array([-0.5, -2.0])).any()
    flat = walkable_map(gp, None, PATH, WalkableConfig(kerb=None, max_step_m=0))
    assert flat.lookup(np.array([0.0]), np.array([-2.0])).all()


def test_ground_grows_over_enclosed_unseen_holes_but_not_past_obstacles():
    pts = plane_points(-4, 4, -2, 2)
    hole = (np.abs(pts[:, 0] - 1.0) < 0.6) & (np.abs(pts[:, 1] - 1.0) < 0.5)  # occluded patch
    ob = box(-2.0, 1.2, 0.6, 0.6, 1.0)
    grown = walkable_map(pts[~hole], ob, PATH, WalkableConfig())
    plain = walkable_map(pts[~hole], ob, PATH, WalkableConfig(fill_holes=False))
    assert grown.lookup(np.array([1.0]), np.array([1.0])).all()
    assert not plain.lookup(np.array([1.0]), np.array([1.0])).any()
    assert not grown.lookup(np.array([-2.0]), np.array([1.2])).any()  # the obstacle still blocks


@pytest.mark.parametrize("map_res", [0.1, 0.05])
def test_map_cells_finer_than_the_ground_model_keep_a_path_that_clears_a_wall(map_res):
    """A walk 0.32 m from a wall face clears a 0.3 m robot; on 0.1 m cells its cell's centre
    (0.29 m from the face) does not, on 0.05 m cells it does. Either way every walkable cell's
    centre clears the face by more than the radius."""
    R = 0.3  # m: laid out for a 0.3 m map clearance (the default until 484c1ae)
    from vid2sim.factory.geometry.map_evidence import path_miss_causes
    from vid2sim.factory.geometry.walkable import physical_layer

    path = PATH + np.array([0.0, 0.08, 0.0])  # y = 0.08: 0.1 m cell centre y 0.05
    wall = box(0.0, -0.24 - 0.05, 2.0, 0.1, 1.0)  # face at y = -0.24, x in [-1, 1]
    conf = WalkableConfig(robot_radius_m=R, map_resolution_m=map_res)
    layer = physical_layer(plane_points(-4, 4, -2, 2), wall, path, conf)
    wm = layer.walkable
    assert wm.resolution == pytest.approx(map_res)
    rows, cols = np.nonzero(wm.grid)
    x, y = wm.cell_center(rows, cols)
    beside = (np.abs(x) < 0.95) & (y > -0.24)  # the path's side of the wall
    assert beside.any() and (y[beside] + 0.24).min() > 0.3
    on_wall = np.abs(path[:, 0]) < 0.9
    miss = path_miss_causes(wm, layer.evidence, path, conf.robot_radius_m)
    assert miss["obstacle_within_radius"] == 0.0
    assert miss["obstacle_clearance_min_m"] == pytest.approx(0.32, abs=0.01)
    if map_res == 0.1:
        assert not wm.lookup(path[on_wall, 0], path[on_wall, 1]).any()
        assert miss["obstacle_cell"] > 0.2
    else:
        assert wm.lookup(path[:, 0], path[:, 1]).all()
        assert miss["obstacle_cell"] == 0.0


def test_map_resolution_must_split_the_ground_cells_evenly():
    with pytest.raises(ValueError, match="map_resolution_m"):
        walkable_map(plane_points(-4, 4, -2, 2), None, PATH, WalkableConfig(map_resolution_m=0.03))


def test_overhead_surface_blocks_only_over_unseen_ground():
    """A branch 1.4-1.6 m up beside the walk (above the robot's 0.75 m box plus margin, below
    the 1.8 m ceiling) does not block where the ground under it was seen, and still blocks
    where it was not (the ground under it might hold anything). `overhead_clear_m=None` keeps
    the old rule: every surface up to 1.8 m blocks."""
    R = 0.3  # m: laid out for a 0.3 m map clearance (the default until 484c1ae)
    branch = box(0.0, 0.5, 1.0, 0.4, 0.2, z0=1.4)  # x [-0.5, 0.5], y [0.3, 0.7], 1.4-1.6 m up
    seen_all = plane_points(-4, 4, -2, 2)
    wm = walkable_map(seen_all, branch, PATH, WalkableConfig(robot_radius_m=R))
    assert wm.lookup(np.array([0.0, 0.0]), np.array([0.0, 0.5])).all()  # the walk and under it
    old = walkable_map(seen_all, branch, PATH,
                       WalkableConfig(robot_radius_m=R, overhead_clear_m=None))
    assert not old.lookup(np.array([0.0, 0.0]), np.array([0.0, 0.5])).any()
    # no ground seen under the branch (a 1 m wide strip y 0.2-1.2 at x -1..1 left out)
    x, y = seen_all[:, 0], seen_all[:, 1]
    hidden = seen_all[~((np.abs(x) < 1.0) & (y > 0.2) & (y < 1.2))]
    wm2 = walkable_map(hidden, branch, PATH,
                       WalkableConfig(robot_radius_m=R, fill_holes=False, close_radius_m=0.0))
    assert not wm2.lookup(np.array([0.0]), np.array([0.0])).any()  # within 0.3 m of the branch
    # geometry in the robot's band blocks whatever the ground evidence says
    post = box(0.0, 0.5, 0.1, 0.1, 1.6)
    wm3 = walkable_map(seen_all, post, PATH, WalkableConfig(robot_radius_m=R))
    assert not wm3.lookup(np.array([0.0]), np.array([0.5])).any()


def test_default_map_clears_the_walkers_body():
    """The map's clearance is the walker's body radius, the one the corridor check and the body
    carving use: what the video proves free. A post 0.27 m beside the walk (outside the body,
    inside a 0.3 m robot half-width) leaves the walk walkable; one 0.2 m beside it blocks it."""
    from vid2sim.factory.evaluation.corridor import CorridorConfig
    from vid2sim.factory.geometry.carving import CarveConfig

    radius = WalkableConfig().robot_radius_m
    assert radius == CorridorConfig().body_radius_m == CarveConfig().body_radius_m == 0.25
    ground = plane_points(-4, 4, -2, 2)
    for face_y, walkable_there in ((0.27, True), (0.2, False)):
        post = box(0.0, face_y + 0.05, 0.1, 0.1, 1.0)  # face toward the walk at y = face_y
        wm = walkable_map(ground, post, PATH, WalkableConfig())
        assert bool(wm.lookup(np.array([0.0]), np.array([0.0]))[0]) == walkable_there, face_y
