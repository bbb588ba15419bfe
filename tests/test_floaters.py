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
