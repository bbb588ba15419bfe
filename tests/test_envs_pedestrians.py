"""Pedestrians: A* walking on a real GridPlanner, speeds, re-planning, pybullet capsules, drawing."""

from __future__ import annotations

import numpy as np
import pybullet as pb
import pytest

from vid2sim.envs.pedestrians import HEIGHT_RANGE, SPEED_RANGE, Crowd
from vid2sim.envs.planning import GridPlanner
from vid2sim.formats.walkable import WalkableGrid

K = np.array([[64.0, 0.0, 64.0], [0.0, 64.0, 36.0], [0.0, 0.0, 1.0]])


def _plaza() -> GridPlanner:
    """12 x 12 m walkable square (0.1 m cells) with a 4 x 4 m block in the middle."""
    grid = np.ones((120, 120), np.uint8)
    grid[40:80, 40:80] = 0
    return GridPlanner(WalkableGrid(grid, np.array([0.0, 0.0]), 0.1))


@pytest.fixture()
def client():
    cid = pb.connect(pb.DIRECT)
    yield cid
    pb.disconnect(cid)


def _walk(seed: int, client: int, steps: int = 150, dt: float = 0.2) -> tuple[Crowd, np.ndarray]:
    crowd = Crowd(_plaza(), 4, np.random.default_rng(seed), client, avoid=[(1.0, 1.0)])
    traj = [crowd.positions]
    for _ in range(steps):
        crowd.step(dt)
        traj.append(crowd.positions)
    return crowd, np.stack(traj)  # [T, P, 2]


def test_people_walk_walkable_paths_at_walking_speed_and_replan(client: int) -> None:
    crowd, traj = _walk(0, client)
    planner = crowd.planner
    assert all(planner.is_walkable(x, y) for x, y in traj.reshape(-1, 2))
    assert (np.hypot(*(traj[0] - [1.0, 1.0]).T) >= 2.0).all()  # spawned away from `avoid`
    step = np.linalg.norm(np.diff(traj, axis=0), axis=-1)  # [T-1, P]
    assert step.max() <= SPEED_RANGE[1] * 0.2 + 1e-9
    moving = step[step > 1e-6]
    assert np.median(moving) >= SPEED_RANGE[0] * 0.2 * 0.7  # diagonal cells shorten a few steps
    assert crowd.goals_reached >= 4  # 30 s on a 12 m plaza: everyone arrives and re-plans
    speeds = [w.speed for w in crowd.walkers]
    assert all(SPEED_RANGE[0] <= s <= SPEED_RANGE[1] for s in speeds)
    assert all(HEIGHT_RANGE[0] <= w.height <= HEIGHT_RANGE[1] for w in crowd.walkers)


def test_same_seed_same_crowd(client: int) -> None:
    _, a = _walk(3, client, steps=30)
    _, b = _walk(3, client, steps=30)
    _, c = _walk(4, client, steps=30)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


def test_capsules_follow_the_people_and_collide(client: int) -> None:
    crowd, _ = _walk(1, client, steps=10)
    for xy, body in zip(crowd.positions, crowd.body_ids):
        pos = pb.getBasePositionAndOrientation(body, physicsClientId=client)[0]
        assert np.allclose(pos[:2], xy)
        hit = pb.rayTest([xy[0] - 2.0, xy[1], 1.0], [xy[0] + 2.0, xy[1], 1.0],
                         physicsClientId=client)[0]
        assert hit[0] in crowd.body_ids
    n = pb.getNumBodies(physicsClientId=client)
    crowd.remove()
    assert pb.getNumBodies(physicsClientId=client) == n - 4
    assert crowd.positions.shape == (0, 2)


def test_person_is_drawn_to_scale_and_limbs_swing(client: int) -> None:
    crowd = Crowd(_plaza(), 1, np.random.default_rng(2), client)
    w = crowd.walkers[0]
    # camera 4 m behind the person along -x, 1 m up, looking along +x
    eye = np.array([w.xy[0] - 4.0, w.xy[1], 1.0])
    R = np.array([[0, -1, 0], [0, 0, -1], [1, 0, 0]], np.float64)
    w2c = np.eye(4)
    w2c[:3, :3], w2c[:3, 3] = R, -R @ eye
    w.yaw = np.pi / 2  # walking across the view: legs swing sideways in the image
    _, depth = crowd.draw(K, w2c, 128, 72)
    rows = np.nonzero(np.isfinite(depth).any(1))[0]
    assert 3.6 < depth[np.isfinite(depth)].min() < 4.0
    top_z = 1.0 - (rows[0] - 36) * 4.0 / 64.0  # approx. world height of the top row at 4 m
    assert abs(top_z - w.height) < 0.2
    w.phase = np.pi / 2
    rgb_a, _ = crowd.draw(K, w2c, 128, 72)
    w.phase = -np.pi / 2
    rgb_b, _ = crowd.draw(K, w2c, 128, 72)
    assert (rgb_a != rgb_b).any()


def test_people_yield_to_the_robot_then_walk_on(client: int) -> None:
    crowd = Crowd(_plaza(), 1, np.random.default_rng(5), client)
    w = crowd.walkers[0]
    crowd.step(0.2)  # walking: yaw now points along its path
    ahead = w.xy + 0.6 * np.array([np.cos(w.yaw), np.sin(w.yaw)])
    before = w.xy.copy()
    for _ in range(5):  # 1 s with the robot 0.6 m ahead: waits
        crowd.step(0.2, robot_xy=ahead)
    assert np.array_equal(w.xy, before)
    for _ in range(8):  # after MAX_WAIT it walks on
        crowd.step(0.2, robot_xy=ahead)
    assert not np.array_equal(w.xy, before)
    behind = w.xy - 0.6 * np.array([np.cos(w.yaw), np.sin(w.yaw)])
    before = w.xy.copy()
    crowd.step(0.2, robot_xy=behind)  # a robot behind does not stop anyone
    assert not np.array_equal(w.xy, before)


def test_vectorised_mesh_matches_the_per_part_reference(client: int) -> None:
    crowd, _ = _walk(6, client, steps=7)
    verts, faces, colors = crowd.mesh_arrays()
    ref = np.concatenate([v for w in crowd.walkers for v in w.world_vertices()])  # [V, 3]
    assert np.allclose(verts, ref, atol=1e-5)
    assert faces.max() == len(verts) - 1 and len(colors) == len(faces)


def test_path_point_equals_numpy_interp() -> None:
    """The numba path point is `np.interp` per axis (ends clamped, repeated waypoints kept)."""
    from vid2sim.envs.pedestrians import _path_point

    rng = np.random.default_rng(2)
    path = np.cumsum(rng.normal(0, 1, (12, 2)), axis=0)
    path[5] = path[4]  # a zero-length segment
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    for s in [-1.0, 0.0, *rng.uniform(0, arc[-1], 50), *arc, arc[-1] + 2.0]:
        x, y = _path_point(path, arc, float(s))
        assert np.isclose(x, np.interp(s, arc, path[:, 0]), rtol=0, atol=1e-12)
        assert np.isclose(y, np.interp(s, arc, path[:, 1]), rtol=0, atol=1e-12)
