"""Kerb drops from ground height profiles across the walk (geometry/kerbs.py), on noisy sparse
ground like a splat reconstruction's (per-cell heights +-0.04 m, 30 % of the cells unseen)."""

from __future__ import annotations

import numpy as np
import pytest

from vid2sim.factory.geometry.kerbs import KerbConfig, kerb_cells, path_coordinates
from vid2sim.factory.geometry.walkable import WalkableConfig, walkable_map

RES = 0.1
ORIGIN = np.array([-5.0, -3.0])
SHAPE = (60, 100)  # y in [-3, 3), x in [-5, 5)
PATH = np.array([[x, 0.0] for x in np.linspace(-4.0, 4.0, 17)])  # walks along +x at y = 0


def centres() -> tuple[np.ndarray, np.ndarray]:
    rows, cols = np.mgrid[0:SHAPE[0], 0:SHAPE[1]]
    return ORIGIN[0] + (cols + 0.5) * RES, ORIGIN[1] + (rows + 0.5) * RES


def noisy_ground(drop_m: float, edge_y: float = -1.0, sigma: float = 0.04, seed: int = 0
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(per-cell height z [H, W], seen [H, W]): flat at 0, dropping by drop_m (negative: a
    rise) for y < edge_y; Gaussian noise, 30 % of the cells unseen."""
    rng = np.random.default_rng(seed)
    _, Y = centres()
    z = np.where(Y < edge_y, -drop_m, 0.0) + sigma * rng.standard_normal(SHAPE)
    return z, rng.random(SHAPE) > 0.3


def test_path_coordinates_left_is_positive_and_s_grows_along_the_walk():
    s, d = path_coordinates(np.array([[-2.0, 1.0], [2.0, -0.5]]), PATH)
    assert d == pytest.approx([1.0, -0.5], abs=1e-6)
    assert s[1] - s[0] == pytest.approx(4.0, abs=0.06)


def test_a_kerb_drop_beside_the_walk_is_found_at_its_edge_through_noise():
    z, seen = noisy_ground(0.12)
    out = kerb_cells(z, seen, ORIGIN, RES, PATH, 0.25, KerbConfig())
    X, Y = centres()
    inner = np.abs(X) < 3.5  # along the walk (the profile segments cover it)
    assert out[inner & (Y < -1.2)].mean() > 0.99  # the road side is below the kerb
    assert not out[inner & (Y > -0.8)].any()  # the sidewalk, both sides of the walk, is not


@pytest.mark.parametrize("drop", [0.0, 0.04, -0.12])
def test_flat_ground_small_drops_and_rises_are_not_kerbs(drop):
    z, seen = noisy_ground(drop)
    assert not kerb_cells(z, seen, ORIGIN, RES, PATH, 0.25, KerbConfig()).any()


def test_walkable_map_spans_the_sidewalk_to_a_noisy_kerb_and_not_the_road():
    R = 0.3  # m: laid out for a 0.3 m map clearance (the default until 484c1ae)
    rng = np.random.default_rng(1)
    x, y = np.meshgrid(np.arange(-4.5, 4.5, 0.1) + 0.05, np.arange(-2.5, 2.0, 0.1) + 0.05)
    z = np.where(y < -1.0, -0.12, 0.0) + 0.04 * rng.standard_normal(x.shape)
    keep = rng.random(x.shape) > 0.3
    gp = np.stack([x[keep], y[keep], z[keep]], 1)
    path = np.column_stack([PATH, np.full(len(PATH), 1.5)])
    wm = walkable_map(gp, None, path, WalkableConfig(robot_radius_m=R))
    xs = np.linspace(-3, 3, 13)
    assert wm.lookup(xs, np.full_like(xs, -0.6)).all()  # 0.4 m inside the kerb: walkable
    assert not wm.lookup(xs, np.full_like(xs, -1.5)).any()  # the road
    # the local step test (off by default) fires on the noise next to the kerb instead
    local = walkable_map(gp, None, path, WalkableConfig(robot_radius_m=R, kerb=None, max_step_m=0.08))
    assert not local.lookup(xs, np.full_like(xs, -0.6)).any()


def test_unseen_ground_between_the_walk_and_a_kerb_grows_when_enclosed():
    """An unseen patch against the kerb whose road side is unseen too: seen ground and the
    ground beyond the kerb enclose it (fill_to_obstacles), plain hole filling does not."""
    x, y = np.meshgrid(np.arange(-4.5, 4.5, 0.05) + 0.025, np.arange(-3.0, 2.0, 0.05) + 0.025)
    z = np.where(y < -1.0, -0.12, 0.0)
    patch = (x > 0.5) & (x < 1.5) & (y < -0.4)  # unseen sidewalk + road, out to the border
    gp = np.stack([x[~patch], y[~patch], z[~patch]], 1)
    path = np.column_stack([PATH, np.full(len(PATH), 1.5)])
    grown = walkable_map(gp, None, path, WalkableConfig(fill_to_obstacles=True))
    plain = walkable_map(gp, None, path, WalkableConfig(fill_to_obstacles=False))
    assert grown.lookup(np.array([1.0]), np.array([-0.55])).all()
    assert not plain.lookup(np.array([1.0]), np.array([-0.55])).any()
    assert not grown.lookup(np.array([1.0, 1.0]), np.array([-0.9, -1.5])).any()  # kerb, road


def test_a_kerb_behind_a_band_without_ground_is_found_where_the_road_is_seen_again():
    """A planter hides the sidewalk's outer part and the kerb from a forward-looking camera:
    no ground between 0.5 m and 1.7 m from the walk, the kerb at 1.5 m. The drop is found
    across the band (max_gap_m), at the first seen road bins; with adjoining bins only
    (max_gap_m = 0) it is not found at all."""
    z, seen = noisy_ground(0.12, edge_y=-1.5)
    _, Y = centres()
    seen &= ~((Y < -0.5) & (Y > -1.7))
    X = centres()[0]
    inner = np.abs(X) < 3.5
    out = kerb_cells(z, seen, ORIGIN, RES, PATH, 0.25, KerbConfig())
    assert KerbConfig().max_gap_m >= 1.2
    assert out[inner & (Y < -1.9)].mean() > 0.99  # the road beyond the band
    assert not out[inner & (Y > -1.4)].any()  # the seen sidewalk and most of the band
    assert not kerb_cells(z, seen, ORIGIN, RES, PATH, 0.25, KerbConfig(max_gap_m=0.0)).any()
