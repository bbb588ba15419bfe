"""GridPlanner on hand-made grids: shortest lengths, walls, clearance, snapping, sampling."""

import math

import numpy as np
import pytest

from vid2sim.envs.planning import GridPlanner, astar, inflate, path_length
from vid2sim.formats.walkable import WalkableGrid as Grid


def open_grid(h: int = 20, w: int = 30, res: float = 0.1, origin=(0.0, 0.0)) -> Grid:
    return Grid(np.ones((h, w), np.uint8), np.array(origin, float), res)


def test_straight_path_length_and_endpoints():
    p = GridPlanner(open_grid())
    path = p.plan((0.05, 0.05), (2.95, 0.05))
    assert path is not None and path.shape[1] == 2
    np.testing.assert_allclose(path[0], (0.05, 0.05))
    np.testing.assert_allclose(path[-1], (2.95, 0.05))
    assert path_length(path) == pytest.approx(2.9, abs=1e-9)


def test_diagonal_uses_octile_cost():
    p = GridPlanner(open_grid(20, 20))
    path = p.plan((0.05, 0.05), (1.95, 1.95))
    assert path_length(path) == pytest.approx(19 * 0.1 * math.sqrt(2), abs=1e-9)
    d = p.distance_field((0.05, 0.05))
    assert d[19, 19] == pytest.approx(19 * 0.1 * math.sqrt(2))


def test_wall_forces_detour_through_gap():
    g = np.ones((20, 20), np.uint8)
    g[:, 10] = 0  # wall along x = 1.0 .. 1.1
    g[18, 10] = 1  # one gap near the top (row 18 -> y in [1.8, 1.9])
    p = GridPlanner(Grid(g, np.zeros(2), 0.1))
    path = p.plan((0.55, 0.05), (1.55, 0.05))
    assert path is not None
    assert path_length(path) > 3.0  # straight line would be 1.0 m
    assert np.all([p.is_walkable(x, y) for x, y in path])
    xs_at_wall = path[(path[:, 0] > 1.0) & (path[:, 0] < 1.1)]
    assert np.all((xs_at_wall[:, 1] > 1.8) & (xs_at_wall[:, 1] < 1.9))


def test_no_path_when_separated_and_no_corner_cutting():
    g = np.ones((10, 10), np.uint8)
    g[:, 5] = 0
    p = GridPlanner(Grid(g, np.zeros(2), 0.1))
    assert p.plan((0.15, 0.15), (0.85, 0.15)) is None
    assert np.isinf(p.distance_field((0.15, 0.15))[0, 8])
    # diagonal touch only: two free cells meeting at a corner are not connected
    g2 = np.zeros((4, 4), np.uint8)
    g2[0, 0] = g2[1, 1] = 1
    p2 = GridPlanner(Grid(g2, np.zeros(2), 1.0), snap=0.0)
    assert p2.plan((0.5, 0.5), (1.5, 1.5)) is None


def test_clearance_inflation_blocks_narrow_gap():
    g = np.ones((30, 30), np.uint8)
    g[:, 15] = 0
    g[10:13, 15] = 1  # 0.3 m gap
    grid = Grid(g, np.zeros(2), 0.1)
    assert GridPlanner(grid).plan((0.5, 0.5), (2.5, 0.5)) is not None
    assert GridPlanner(grid, clearance=0.25, snap=0.0).plan((0.5, 0.5), (2.5, 0.5)) is None
    free = inflate(np.ones((5, 5), bool), 1.0)  # border counts as blocked
    assert free.sum() == 9 and not free[0].any()


def test_snapping_and_off_grid():
    g = np.ones((10, 10), np.uint8)
    g[0, 0] = 0
    p = GridPlanner(Grid(g, np.array([-1.0, 2.0]), 0.1), snap=0.15)
    assert not p.is_walkable(-0.95, 2.05) and p.is_walkable(-0.85, 2.05)
    assert p.plan((-0.95, 2.05), (-0.15, 2.85)) is not None  # snapped one cell
    assert p.plan((5.0, 5.0), (-0.15, 2.85)) is None  # off the grid
    assert not p.is_walkable(-1.05, 2.05)


def test_sample_free_is_reproducible_and_free():
    g = np.zeros((10, 10), np.uint8)
    g[2:5, 3:8] = 1
    p = GridPlanner(Grid(g, np.zeros(2), 0.5))
    a = [p.sample_free(np.random.default_rng(3)) for _ in range(2)]
    assert a[0] == a[1]
    rng = np.random.default_rng(0)
    assert all(p.is_free(*p.sample_free(rng)) for _ in range(50))
    with pytest.raises(ValueError, match="no free cell"):
        GridPlanner(Grid(np.zeros((3, 3), np.uint8), np.zeros(2), 0.1)).sample_free(rng)


def test_episode_ends_keep_end_clearance_and_avoid_narrow_spurs():
    from vid2sim.envs.config import EpisodeConfig
    from vid2sim.envs.episodes import end_cells, sample_episode
    g = np.zeros((60, 200), np.uint8)
    g[20:, :] = 1  # 20 m x 4 m open ground
    g[:20, 100:108] = 1  # a 0.8 m wide, 2 m deep spur: free at 0.3 m clearance, not at 0.45 m
    p = GridPlanner(Grid(g, np.zeros(2), 0.1), clearance=0.3)
    ends = end_cells(p, 0.45)
    assert p.free[:20].any() and not ends[:20].any() and ends[20:].any()
    assert not (ends & ~p.free).any()
    rng = np.random.default_rng(0)
    for _ in range(20):
        ep = sample_episode(p, rng, (5.0, 15.0), EpisodeConfig(), ends=ends)
        for x, y in (ep.start, ep.goal):
            assert ends[p.to_cell(x, y)]
    narrow = GridPlanner(Grid(g[:, 100:108], np.zeros(2), 0.1), clearance=0.3)
    assert np.array_equal(end_cells(narrow, 0.45), narrow.free)  # no such cell: the free ones


def test_far_end_restart_stays_on_end_cells():
    from vid2sim.envs.config import EpisodeConfig
    from vid2sim.envs.episodes import end_cells, sample_episode
    g = np.zeros((14, 100), np.uint8)
    g[:, :90] = 1  # a 9 m x 1.4 m corridor ...
    g[5:9, 90:] = 1  # ... ending in a 1 m, 0.4 m wide stub: the farthest free cells
    p = GridPlanner(Grid(g, np.zeros(2), 0.1), clearance=0.1)
    ends = end_cells(p, 0.5)
    assert p.free[:, 92:].any() and not ends[:, 90:].any()
    rng = np.random.default_rng(1)
    for _ in range(10):  # most random starts reach no cell 7 m away: restarted from the far end
        ep = sample_episode(p, rng, (7.0, 9.0), EpisodeConfig(), ends=ends)
        for x, y in (ep.start, ep.goal):
            assert ends[p.to_cell(x, y)]


def test_shortcut_kernel_equals_the_reference_loop():
    """The numba line-of-sight pruning keeps the same waypoints as the plain loop."""
    rng = np.random.default_rng(5)
    grid = np.ones((60, 90), np.uint8)
    grid[rng.random(grid.shape) < 0.04] = 0  # scattered blocked cells
    grid[10:50, 40] = 0  # a wall with gaps at the ends
    planner = GridPlanner(Grid(grid, np.zeros(2), 0.1), clearance=0.05)
    n_long = 0
    for _ in range(20):
        path = planner.plan(planner.sample_free(rng), planner.sample_free(rng))
        if path is None:
            continue
        cells = planner.to_world(*astar(planner.free, planner.snap_cell(*path[0]),
                                        planner.snap_cell(*path[-1])).T)
        np.testing.assert_array_equal(planner.shortcut(cells), planner.shortcut_reference(cells))
        n_long += len(cells) > 30
    assert n_long >= 5
    one = np.array([[1.0, 1.0]])
    np.testing.assert_array_equal(planner.shortcut(one), planner.shortcut_reference(one))


def _room(planner: GridPlanner, path: np.ndarray) -> np.ndarray:
    """Distance in metres from each waypoint [K, 2] to the nearest blocked cell centre [K]."""
    blocked = np.argwhere(planner.raw == 0)  # [B, 2] (row, col)
    centres = planner.to_world(blocked[:, 0], blocked[:, 1]) + planner.resolution / 2  # [B, 2]
    return np.min(np.linalg.norm(path[:, None, :] - centres[None], axis=2), axis=1)


def corridor_with_pillar() -> Grid:
    """A 3 m wide, 8 m long corridor (walls around) with a 0.4 m pillar against the lower wall."""
    g = np.zeros((32, 82), np.uint8)
    g[1:31, 1:81] = 1  # free 3.0 m x 8.0 m inside a one-cell wall
    g[1:5, 38:42] = 0  # pillar at x 3.8-4.2 m, y 0.1-0.5 m
    return Grid(g, np.zeros(2), 0.1)


def test_comfortable_route_keeps_its_distance_where_there_is_room():
    p = GridPlanner(corridor_with_pillar(), clearance=0.45, comfort=0.9)
    start, goal = (0.8, 0.7), (7.3, 0.7)  # both near the lower wall
    shortest = p.plan(start, goal)
    comfy = p.plan(start, goal, comfortable=True)
    assert path_length(comfy) > path_length(shortest)  # a longer way round ...
    assert path_length(comfy) < 1.5 * path_length(shortest)
    middle = (comfy[:, 0] > 2.0) & (comfy[:, 0] < 6.0)  # ... that keeps away from the pillar and walls
    assert _room(p, comfy[middle]).min() >= 0.85
    assert _room(p, shortest[(shortest[:, 0] > 2.0) & (shortest[:, 0] < 6.0)]).min() < 0.6
    assert np.all([p.is_free(x, y) for x, y in comfy])
    # without a comfort distance (or asked for the shortest) the plans are the same
    plain = GridPlanner(corridor_with_pillar(), clearance=0.45)
    np.testing.assert_allclose(plain.plan(start, goal, comfortable=True), shortest)


def test_comfortable_route_squeezes_through_a_narrow_gap():
    g = np.ones((40, 40), np.uint8)
    g[:, 20] = 0  # wall at x = 2.0 .. 2.1 with a 1.2 m gap (needs 2 x 0.45, not 2 x 0.9)
    g[14:26, 20] = 1
    p = GridPlanner(Grid(g, np.zeros(2), 0.1), clearance=0.45, comfort=0.9)
    route = p.plan((0.5, 2.0), (3.5, 2.0), comfortable=True)
    assert route is not None and np.all([p.is_free(x, y) for x, y in route])
    at_gap = route[(route[:, 0] > 1.95) & (route[:, 0] < 2.15)]
    assert np.all(np.abs(at_gap[:, 1] - 2.0) < 0.15)  # through the gap's middle
