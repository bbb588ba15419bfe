"""Floaters: small collision-mesh components that nothing holds up are dropped by the physical
layer; small obstacles standing on the ground and large overhangs are kept."""

from __future__ import annotations

import numpy as np
import trimesh

from tests.test_walkable_map import PATH, box, plane_points
from vid2sim.factory.geometry.floaters import face_components
from vid2sim.factory.geometry.walkable import WalkableConfig, physical_layer

BLOB = (1.0, 0.3)  # 0.2 x 0.2 x 0.15 m lump 0.25 m above the pavement, beside the walk
BOLLARD = (2.5, 0.55)  # 0.12 x 0.12 x 0.9 m pole standing on the ground
AWNING = (-2.0, -1.4)  # 2 x 0.8 x 0.1 m slab 0.5 m up, nothing under it


def scene() -> trimesh.Trimesh:
    return trimesh.util.concatenate([
        box(*BLOB, 0.2, 0.2, 0.15, z0=0.25),
        box(*BOLLARD, 0.12, 0.12, 0.9),
        box(*AWNING, 2.0, 0.8, 0.1, z0=0.5),
    ])


def near(v: np.ndarray, xy: tuple[float, float], r: float = 0.3) -> bool:
    return bool((np.linalg.norm(v[:, :2] - np.asarray(xy), axis=1) < r).any())


def test_face_components_split_disjoint_boxes():
    m = scene()
    assert len(np.unique(face_components(np.asarray(m.vertices), np.asarray(m.faces)))) == 3


def test_floating_blob_dropped_standing_pole_and_large_overhang_kept():
    gp = plane_points(-4, 4, -2, 2)
    conf = WalkableConfig(floater_max_area_m2=1.0)
    layer = physical_layer(gp, scene(), PATH, conf)
    assert not near(layer.vertices, BLOB)
    assert near(layer.vertices, BOLLARD, 0.1) and near(layer.vertices, AWNING, 1.1)
    off = physical_layer(gp, scene(), PATH, WalkableConfig())  # rule disabled: the blob stays
    assert near(off.vertices, BLOB)
    wm, wm_off = layer.walkable, off.walkable
    r, c = wm.world_to_cell(np.array([BLOB[0]]), np.array([0.0]))
    assert wm.grid[r[0], c[0]] == 1  # the walk beside the blob is walkable again ...
    r, c = wm_off.world_to_cell(np.array([BLOB[0]]), np.array([0.0]))
    assert wm_off.grid[r[0], c[0]] == 0  # ... and was blocked by it


def test_blob_resting_on_the_ground_is_kept():
    gp = plane_points(-4, 4, -2, 2)
    lump = box(*BLOB, 0.2, 0.2, 0.3, z0=0.0)  # same size, standing: a real small obstacle
    layer = physical_layer(gp, lump, PATH, WalkableConfig(floater_max_area_m2=1.0))
    assert near(layer.vertices, BLOB)


def test_piece_split_off_a_standing_obstacle_is_kept():
    gp = plane_points(-4, 4, -2, 2)
    planter = box(*BLOB, 0.2, 0.2, 0.2)  # stands on the ground up to 0.2 m ...
    piece = box(BLOB[0], BLOB[1], 0.2, 0.2, 0.2, z0=0.23)  # ... its upper face split off 3 cm above
    layer = physical_layer(gp, trimesh.util.concatenate([planter, piece]), PATH,
                           WalkableConfig(floater_max_area_m2=1.0))
    assert (layer.vertices[:, 2] > 0.4).any()  # the split-off piece is still there


def mound(cx: float, cy: float, peak: float, sigma: float = 0.3, half: float = 0.5,
          step: float = 0.05) -> trimesh.Trimesh:
    """A smooth bump of the pavement (a height field peaking at `peak`): a noise lump."""
    g = np.arange(-half, half + 1e-9, step)
    x, y = np.meshgrid(g, g)  # [n, n]
    z = peak * np.exp(-(x ** 2 + y ** 2) / sigma ** 2)
    n = len(g)
    v = np.stack([x.ravel() + cx, y.ravel() + cy, z.ravel()], axis=1)
    i = np.arange(n * n).reshape(n, n)[:-1, :-1].ravel()
    f = np.concatenate([np.stack([i, i + 1, i + n], 1), np.stack([i + 1, i + n + 1, i + n], 1)])
    return trimesh.Trimesh(v, f, process=False)


def test_what_the_trim_leaves_of_a_lump_goes_with_it():
    """Wavy ground (+-3 cm, 1.6 m period: the step is 6 x the measured noise, ~0.2 m) and a
    pavement lump peaking one noise sigma above the step beside the walk: the trim drops its
    faces below the step and leaves its cap, which blocks the walk; the lump-top rule drops the
    cap too. A post and a 0.45 m block that the trim also cut (their bottom faces) and a thin
    plate above the step that it did not cut are kept. On exact ground (noise 0) the rule keeps
    even a lump."""
    gp = plane_points(-4, 4, -2, 2)
    gp[:, 2] = 0.03 * np.sin(2 * np.pi * gp[:, 0] / 1.6)  # every object sits where it is 0
    lump, post, block, plate = (0.8, -0.35), (-1.6, 0.7), (2.4, -0.8), (-2.4, -0.9)
    step = physical_layer(gp, box(*post, 0.1, 0.1, 0.6), PATH, WalkableConfig()).step_m
    noise = step / WalkableConfig().noise_k
    assert 0.15 < step < 0.25
    mesh = trimesh.util.concatenate([mound(*lump, peak=step + noise), box(*post, 0.1, 0.1, 0.6),
                                     box(*block, 0.3, 0.3, 0.45),
                                     box(*plate, 0.3, 0.3, 0.02, z0=step + 0.02)])
    before = physical_layer(gp, mesh, PATH, WalkableConfig(lump_noise_k=0.0, min_piece_area_m2=0.0))
    assert near(before.vertices, lump, 0.2)
    assert not before.walkable.lookup(np.array([0.8]), np.array([0.0])).any()  # the cap blocks
    layer = physical_layer(gp, mesh, PATH, WalkableConfig())
    assert not near(layer.vertices, lump, 0.5)
    assert layer.walkable.lookup(np.array([0.8]), np.array([0.0])).all()
    for kept in (post, block, plate):
        assert near(layer.vertices, kept, 0.25), kept
    exact = physical_layer(plane_points(-4, 4, -2, 2), mound(*lump, peak=0.18), PATH, WalkableConfig())
    assert near(exact.vertices, lump, 0.2)


def test_small_piece_left_after_the_trim_is_dropped():
    """A 0.06 m^2 chip 0.2 m up beside the walk blocks it unless the small-piece rule drops it;
    a 0.1 x 0.1 x 0.4 m post (0.18 m^2) is kept."""
    gp = plane_points(-4, 4, -2, 2)
    chip, post = (0.5, 0.25), (-1.0, 0.5)
    mesh = trimesh.util.concatenate([box(*chip, 0.1, 0.1, 0.1, z0=0.2), box(*post, 0.1, 0.1, 0.4)])
    off = physical_layer(gp, mesh, PATH, WalkableConfig(min_piece_area_m2=0.0))
    assert near(off.vertices, chip, 0.1)
    assert not off.walkable.lookup(np.array([chip[0]]), np.array([0.0])).any()
    layer = physical_layer(gp, mesh, PATH, WalkableConfig())
    assert not near(layer.vertices, chip, 0.1) and near(layer.vertices, post, 0.1)
    assert layer.walkable.lookup(np.array([chip[0]]), np.array([0.0])).all()


def test_piece_the_carving_cut_is_dropped():
    """A 0.4 m^2 lump 0.28 m beside the walk with carved depth (the part of it the walker's body
    swept, removed by the meshing's carving) next to it is a phantom: dropped, and the walk is
    walkable again. A bollard without carved depth, and a large slab with carved depth beside it
    (real facades are large), are kept."""
    R = 0.3  # m: laid out for a 0.3 m map clearance (the default until 484c1ae)
    gp = plane_points(-4, 4, -2, 2)
    lump, bollard, slab = (1.0, 0.4), (-1.0, -0.4), (2.6, 0.45)
    mesh = trimesh.util.concatenate([box(*lump, 0.25, 0.25, 0.3, z0=0.15),
                                     box(*bollard, 0.12, 0.12, 0.9), box(*slab, 1.2, 0.2, 1.5)])
    rng = np.random.default_rng(0)
    carved = np.concatenate([
        np.stack([rng.uniform(0.9, 1.1, 30), rng.uniform(0.15, 0.25, 30), rng.uniform(0.2, 0.4, 30)], 1),
        np.stack([rng.uniform(2.2, 3.0, 30), rng.uniform(0.2, 0.3, 30), rng.uniform(0.3, 1.0, 30)], 1)])
    off = physical_layer(gp, mesh, PATH, WalkableConfig(robot_radius_m=R))  # no carved points
    assert near(off.vertices, lump, 0.2)
    assert not off.walkable.lookup(np.array([lump[0]]), np.array([0.0])).any()
    layer = physical_layer(gp, mesh, PATH, WalkableConfig(robot_radius_m=R), carved_points=carved)
    assert not near(layer.vertices, lump, 0.2)
    assert layer.walkable.lookup(np.array([lump[0]]), np.array([0.0])).all()
    assert near(layer.vertices, bollard, 0.1) and near(layer.vertices, slab, 0.7)
    few = physical_layer(gp, mesh, PATH, WalkableConfig(robot_radius_m=R, cut_min_points=31),
                         carved_points=carved)
    assert near(few.vertices, lump, 0.2)  # fewer carved points than the rule asks for: kept
