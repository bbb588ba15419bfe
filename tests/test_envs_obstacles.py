"""Procedural obstacles: metric sizes, real pybullet bodies, drawing, corridor placement, scenarios."""

from __future__ import annotations

import math

import numpy as np
import pybullet as pb
import pytest

from vid2sim.envs.obstacles import (EXTRA_KINDS, OBSTACLE_KINDS, ObstacleConfig, ObstacleSet, Placement,
                                    falling_bin, make_obstacle, occupancy, place_on_corridor,
                                    roadworks)

K = np.array([[64.0, 0.0, 64.0], [0.0, 64.0, 36.0], [0.0, 0.0, 1.0]])
# camera 0.6 m above the origin looking along +x (OpenCV axes: rows = camera x, y, z in world)
W2C = np.array([[0, -1, 0, 0], [0, 0, -1, 0.6], [1, 0, 0, 0], [0, 0, 0, 1]], dtype=np.float64)
HEIGHTS = {"traffic_cone": (0.5, 0.75), "trash_bin": (0.9, 1.13), "pole": (2.5, 3.5),
           "traffic_light": (2.8, 3.4), "barrier": (0.95, 1.0), "planter": (0.6, 1.3)}


@pytest.fixture()
def client():
    cid = pb.connect(pb.DIRECT)
    pb.setGravity(0, 0, -9.81, physicsClientId=cid)
    pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=cid),
                       physicsClientId=cid)
    yield cid
    pb.disconnect(cid)


@pytest.mark.parametrize("kind", OBSTACLE_KINDS + EXTRA_KINDS)
def test_meshes_are_metric_and_coloured(kind: str) -> None:
    for seed in range(5):
        m = make_obstacle(kind, np.random.default_rng(seed))
        lo, hi = HEIGHTS[kind]
        assert lo - 1e-6 <= m.height <= hi + 1e-6
        assert abs(m.vertices[:, 2].min()) < 1e-6  # base on the ground
        assert 0.03 < m.radius < 1.1
        assert m.face_colors.shape == m.faces.shape and m.faces.max() < len(m.vertices)
        assert all(p.is_watertight for p in m.parts)
    with pytest.raises(ValueError, match="unknown obstacle kind"):
        make_obstacle("sofa", np.random.default_rng(0))


def test_obstacle_is_a_pybullet_collision_body(client: int) -> None:
    rng = np.random.default_rng(0)
    obs = ObstacleSet(client, [Placement(make_obstacle("trash_bin", rng), (3.0, 0.0))])
    hit = pb.rayTest([0, 0, 0.5], [6, 0, 0.5], physicsClientId=client)[0]
    assert hit[0] == obs.body_ids[0]
    assert 2.6 < hit[3][0] < 2.8  # the bin's near side at x = 3 - r
    # a ball rolled at it stops against it instead of passing through
    ball = pb.createMultiBody(1.0, pb.createCollisionShape(pb.GEOM_SPHERE, radius=0.2,
                                                           physicsClientId=client),
                              basePosition=[1.0, 0.0, 0.2], physicsClientId=client)
    pb.resetBaseVelocity(ball, [4.0, 0, 0], physicsClientId=client)
    for _ in range(240):
        pb.stepSimulation(physicsClientId=client)
    assert pb.getBasePositionAndOrientation(ball, physicsClientId=client)[0][0] < 2.8
    assert np.allclose(obs.positions, [[3.0, 0.0]], atol=1e-6)
    n = pb.getNumBodies(physicsClientId=client)
    obs.remove()
    assert pb.getNumBodies(physicsClientId=client) == n - 1


def test_traffic_light_collides_per_part_not_as_one_hull(client: int) -> None:
    obs = ObstacleSet(client, [Placement(make_obstacle("traffic_light", np.random.default_rng(1)),
                                         (3.0, 0.0))])
    pole_hit = pb.rayTest([0, 0, 1.0], [6, 0, 1.0], physicsClientId=client)[0]
    beside_pole = pb.rayTest([0, 0.3, 1.0], [6, 0.3, 1.0], physicsClientId=client)[0]
    assert pole_hit[0] == obs.body_ids[0] and beside_pole[0] == -1


def test_draw_puts_the_cone_where_it_stands(client: int) -> None:
    cone = make_obstacle("traffic_cone", np.random.default_rng(2))
    obs = ObstacleSet(client, [Placement(cone, (3.0, 0.0))])
    rgb, depth = obs.draw(K, W2C, 128, 72)
    col = depth[:, 64]
    hit = np.isfinite(col)
    assert hit.any() and not np.isfinite(depth[:, :40]).any()  # drawn in the middle only
    assert 2.7 < col[hit].min() < 3.0
    orange = (rgb[..., 0] > rgb[..., 2] + 60).sum()
    assert orange > 20


def test_placement_on_corridor_is_reproducible_and_near_the_path() -> None:
    path = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0]])
    counts = set()
    for seed in range(30):
        a = place_on_corridor(path, np.random.default_rng(seed))
        b = place_on_corridor(path, np.random.default_rng(seed))
        assert [p.xy for p in a] == [p.xy for p in b]
        counts.add(len(a))
        for p in a:
            x, y = p.xy
            lateral = min(abs(y) if x <= 10 else np.inf, abs(x - 10) if y >= 0 else np.inf)
            assert lateral <= 0.6 + 1e-9
            assert min(math.hypot(x, y), math.hypot(x - 10, y - 10)) >= 1.5 - 1e-9
    assert counts == {0, 1, 2, 3, 4, 5}
    none = place_on_corridor(path, np.random.default_rng(0), ObstacleConfig(min_count=5),
                             is_walkable=lambda x, y: False)
    assert none == []


def test_planters_only_where_named_long_side_along_the_path(client: int) -> None:
    path = np.array([[0.0, 0.0], [20.0, 0.0]])
    default = [p.mesh.kind for s in range(30) for p in place_on_corridor(path, np.random.default_rng(s))]
    assert "planter" not in default and set(default) <= set(OBSTACLE_KINDS)
    conf = ObstacleConfig(min_count=3, max_count=3, kinds=("planter",))
    placed = place_on_corridor(path, np.random.default_rng(0), conf)
    assert [p.mesh.kind for p in placed] == ["planter"] * 3
    for p in placed:
        v = p.mesh.vertices
        assert np.ptp(v[:, 0]) > np.ptp(v[:, 1])  # long side along local x ...
        assert abs(p.yaw) <= 0.3 + 1e-9  # ... which points along the path
    first = placed[0]
    obs = ObstacleSet(client, [first])
    x, y = first.xy
    hit = pb.rayTest([x - 3, y, 0.3], [x + 3, y, 0.3], physicsClientId=client)[0]
    assert hit[0] == obs.body_ids[0] and hit[3][0] < x - 0.4  # the box, end-on, from 0.45 m ahead of its centre


def test_obstacle_config_names_a_bad_kind_or_count() -> None:
    with pytest.raises(ValueError, match="unknown kind.*sofa"):
        ObstacleConfig(kinds=("pole", "sofa"))
    with pytest.raises(ValueError, match="no kind given"):
        ObstacleConfig(kinds=())
    with pytest.raises(ValueError, match="min_count 4 > max_count 2"):
        ObstacleConfig(min_count=4, max_count=2)


@pytest.mark.parametrize("seed", [2, 4])  # the bin stands left of the path, then right
def test_falling_bin_tips_over_into_the_corridor_when_the_robot_comes(seed: int) -> None:
    cid = pb.connect(pb.DIRECT)  # like the env: no gravity set, nobody steps the simulation
    pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=cid),
                       physicsClientId=cid)
    path = np.array([[0.0, 0.0], [10.0, 0.0]])
    place = falling_bin(path, np.random.default_rng(seed), s=5.0, trigger_distance=3.0)
    assert place.dynamic and abs(place.xy[1]) == pytest.approx(0.8)
    obs = ObstacleSet(cid, [place])
    for _ in range(50):  # robot still far away: the bin stands
        obs.step(0.02, (0.0, 0.0))
    assert obs.pose(0)[2, 2] == pytest.approx(1.0)
    for _ in range(150):  # 3 s with the robot 2.5 m away
        obs.step(0.02, (2.5, 0.0))
    T = obs.pose(0)
    up = T[:3, 2]
    assert up[2] < 0.3  # lying on its side
    top = T[:3, 3] + up * place.mesh.height
    assert np.sign(top[1]) != np.sign(place.xy[1]) and abs(top[1]) < 0.5  # across the path
    v, _, _ = obs.mesh_arrays()
    assert v[:, 2].min() > -0.05  # resting on the ground plane
    pb.disconnect(cid)


def test_roadworks_narrow_the_corridor_but_leave_the_path_open() -> None:
    path = np.array([[0.0, 0.0], [12.0, 0.0]])
    zone = roadworks(path, np.random.default_rng(4), s=6.0)
    kinds = [p.mesh.kind for p in zone]
    assert kinds.count("barrier") >= 2 and kinds.count("traffic_cone") == 2
    occ = occupancy(zone, origin=(-1.0, -2.0), resolution=0.1, shape=(40, 140))
    centre_row = 20  # y = 0.05
    assert not occ[centre_row].any()
    assert occ.sum(0)[60:80].min() > 0  # the barriers cover the zone's side
    sides = {np.sign(p.xy[1]) for p in zone}
    assert len(sides) == 1


def test_a_thin_pole_between_cell_centres_still_occupies_cells() -> None:
    pole = make_obstacle("pole", np.random.default_rng(3))  # radius 0.043 m (poles: 0.04-0.07)
    assert pole.radius < 0.05
    # at (0.1, 0.1): the corner of four 0.1 m cells, no cell centre within its radius
    occ = occupancy([Placement(pole, (0.1, 0.1))], origin=(-1.0, -1.0), resolution=0.1, shape=(20, 20))
    assert occ.sum() >= 4 and occ[10:12, 10:12].all()
