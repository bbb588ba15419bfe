"""The physical layer agrees with itself: where the walkable map lets the envs put the robot, the
collision mesh the envs hand to pybullet has nothing in the robot's body band.

Scene: the ring scene of tests/test_meshing_scene.py with a 0.2 m low box added, rendered with
splat-like depth and normal noise and fused by the factory's meshing (build_meshes), then
`physical_layer`. The map is eroded as the envs plan (EpisodeConfig.clearance minus what the
factory inflated), the body band is the envs' robot box (RobotConfig: ground_clearance to
ground_clearance + height above z = 0)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from tests.test_meshing_scene import full_scene, ring_views
from tests.test_meshing_splat_noise import splat_like
from vid2sim.envs.config import EpisodeConfig, RobotConfig
from vid2sim.envs.planning import GridPlanner
from vid2sim.factory.geometry.meshing import MeshingConfig, build_meshes
from vid2sim.factory.geometry.raycast import mesh_arrays
from vid2sim.factory.geometry.surface_sampling import points_by_spacing
from vid2sim.factory.geometry.walkable import PhysicalLayer, WalkableConfig, physical_layer

LOW_BOX = ((0.0, -1.8), (0.4, 0.4), 0.2)  # centre, size, height: clutter below a 0.25 m step


def low_box() -> trimesh.Trimesh:
    (cx, cy), (sx, sy), h = LOW_BOX
    b = trimesh.creation.box(extents=(sx, sy, h))
    b.apply_translation((cx, cy, h / 2))
    return b


@pytest.fixture(scope="module")
def fused():
    views, path = ring_views(full_scene([low_box()]), n=12)
    rng = np.random.default_rng(0)
    return build_meshes([splat_like(v, rng) for v in views], MeshingConfig()), path


def body_clearance(grid_layer: PhysicalLayer, mesh: tuple, conf: WalkableConfig) -> np.ndarray:
    """Horizontal distance [N] from each cell centre the envs may put the robot on to the
    nearest collision-mesh point inside the robot's body band (inf: none)."""
    robot, episode = RobotConfig(), EpisodeConfig()
    planner = GridPlanner(grid_layer.walkable, clearance=episode.clearance - conf.robot_radius_m)
    rows, cols = np.nonzero(planner.free)
    assert len(rows) > 1000  # the map is not trivially empty
    pts = points_by_spacing(*mesh_arrays(mesh), 0.02)  # [P, 3]
    lo, hi = robot.ground_clearance, robot.ground_clearance + robot.height
    band = pts[(pts[:, 2] >= lo) & (pts[:, 2] <= hi)]
    if len(band) == 0:
        return np.full(len(rows), np.inf)
    return cKDTree(band[:, :2]).query(planner.to_world(rows, cols))[0]


@pytest.mark.parametrize("step", [0.1, 0.25])
def test_no_walkable_cell_has_collision_geometry_in_the_body_band(fused, step):
    res, path = fused
    conf = WalkableConfig(obstacle_min_z_m=step)  # 0.25: a noise-raised step, as on real clips
    layer = physical_layer(res.ground_points, res.collision, path, conf)
    assert layer.step_m == pytest.approx(step, abs=0.02)
    d = body_clearance(layer, (layer.vertices, layer.faces), conf)
    assert d.min() > RobotConfig().width / 2, d.min()  # the robot's sides touch nothing


def test_untrimmed_mesh_disagrees_with_its_map(fused):
    """The old layer (fused mesh shipped as is, low geometry only ignored by the map) puts the
    low box beside walkable cells while pybullet still collides with it."""
    res, path = fused
    conf = WalkableConfig(obstacle_min_z_m=0.25, trim_collision=False)
    layer = physical_layer(res.ground_points, res.collision, path, conf)
    d = body_clearance(layer, mesh_arrays(res.collision), conf)
    assert d.min() < 0.1  # walkable cells beside (or on) the low box, which pybullet hits


def test_step_drops_low_clutter_and_keeps_obstacles(fused):
    res, path = fused
    layer = physical_layer(res.ground_points, res.collision, path, WalkableConfig(obstacle_min_z_m=0.25))
    (cx, cy), (sx, _), _ = LOW_BOX
    v = layer.vertices
    near_box = (np.abs(v[:, 0] - cx) < sx) & (np.abs(v[:, 1] - cy) < sx)
    assert not near_box.any() and layer.dropped_faces > 0
    # the 0.6 m box and the 1 m box stay: their centres are blocked and their walls in the mesh
    assert not layer.walkable.lookup(np.array([-1.5, 1.5]), np.array([0.5, -0.5])).any()
    assert np.count_nonzero(v[:, 2] > 0.5) > 100
    # with base_radius_m their lowest part (below the step) stays too (off by default: on the
    # demo street it cost 11 points of walked path and no completeness)
    based = physical_layer(res.ground_points, res.collision, path,
                           WalkableConfig(obstacle_min_z_m=0.25, base_radius_m=0.1))
    v = based.vertices
    base = (v[:, 2] < 0.15) & (np.abs(v[:, 0] - 1.5) < 0.6) & (np.abs(v[:, 1] + 0.5) < 1.0)
    assert np.count_nonzero(base) > 10 and len(based.faces) > len(layer.faces)
    # with the default 0.1 m step the 0.2 m box is an obstacle
    low = physical_layer(res.ground_points, res.collision, path, WalkableConfig())
    assert not low.walkable.lookup(np.array([cx]), np.array([cy])).any()


def test_inflation_uses_exact_distances_to_the_surface():
    from vid2sim.factory.geometry.walkable import near_points

    origin, res = np.array([0.0, 0.0]), 0.1
    pt = np.array([[1.02, 1.0]])  # inside cell (row 10, col 10), off its centre (1.05, 1.05)
    blocked = near_points(pt, origin, (21, 21), res, 0.3)
    # cell centres: (1.35, 1.05) is 0.334 away -> free; (0.75, 1.05) is 0.275 away -> blocked
    assert not blocked[10, 13] and blocked[10, 7]
    centres = np.stack(np.nonzero(blocked), 1)[:, ::-1] * res + 0.05  # [N, 2] x, y
    assert np.linalg.norm(centres - pt, axis=1).max() <= 0.3 + 1e-9


def test_expert_route_keeps_the_same_distance_from_obstacles_on_a_pre_inflated_map():
    """A factory map is already shrunk by its robot radius, so the planner's clearance there is
    smaller; the env's own obstacles are not in the map and must get that radius added back."""
    from vid2sim.envs.actors import EpisodeActors
    from vid2sim.envs.obstacles import Placement, make_obstacle
    from vid2sim.formats.walkable import WalkableGrid

    grid = WalkableGrid(np.ones((60, 200), np.uint8), (0.0, -3.0), 0.1)  # 20 m x 6 m, open
    cone = Placement(make_obstacle("trash_bin", np.random.default_rng(0)), (10.0, 0.0))
    start, goal = (2.0, 0.0), (18.0, 0.0)

    def gap(pre: float, clearance: float) -> float:
        route = EpisodeActors._route_planner(grid, clearance, [cone], pre).plan(start, goal)
        return float(np.linalg.norm(route - np.array(cone.xy), axis=1).min())

    gt_like = gap(0.0, 0.45)  # a GT map: the planner keeps the whole 0.45 m clearance
    factory = gap(0.3, 0.15)  # a factory map inflated by 0.3 m: the planner adds only 0.15
    assert factory == pytest.approx(gt_like, abs=0.1)
    assert gap(0.0, 0.15) < factory - 0.2  # without the fix the route passes 0.3 m closer
