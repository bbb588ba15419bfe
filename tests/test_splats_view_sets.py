"""View sets: a masked fast render, the measured per-view sets, their cell masks and their file."""

from __future__ import annotations

import numpy as np
import pytest

from vid2sim.envs.rendering import EMPTY_ALPHA
from vid2sim.splats.cpu import StaticScene, StaticSceneConfig
from vid2sim.splats.cpu.env_fast_batch import FastBatch
from vid2sim.splats.cpu.env_fast_frame import P_CUT, P_O
from vid2sim.splats.cpu.env_fast_view import FastView
from vid2sim.splats.cpu.env_simready import SimReadyConfig, sim_ready, sim_ready_views
from vid2sim.splats.cpu.env_view_sets import MIN_VIEWS, CellMasks, ViewSets, camera_pose
from vid2sim.splats.cpu.project import camera_arrays
from vid2sim.splats.cpu.synthetic import robot_camera, street_scene
from vid2sim.splats.types import RasterSettings

W, H = 64, 36
POSES = [dict(x=-10.0, yaw_deg=0.0), dict(x=0.0, yaw_deg=35.0), dict(x=5.0, y=-4.0, yaw_deg=80.0),
         dict(x=0.0, yaw_deg=180.0)]


@pytest.fixture(scope="module")
def model():
    return street_scene(6000, length=30.0, seed=1).with_sh_degree(0)


@pytest.fixture(scope="module")
def scene(model):
    return StaticScene(model, StaticSceneConfig(cell_size=64, per_splat_outputs=False))


def _view(batch: FastBatch) -> FastView:
    return FastView(batch, W, H, 0.05, 100.0, 0.01, 0.05, EMPTY_ALPHA)


def test_masked_render_equals_render_without_the_masked_splats(scene):
    """A cell mask draws what the full batch draws with the masked-out splats made transparent
    (the same blends in the same order; a splat's projection may round in the last bit, as it
    sits in another lane of the vectorised chunk), and a mask of every row equals no mask."""
    batch = FastBatch([scene])
    rng = np.random.default_rng(0)
    C = len(scene.centers)
    mask = rng.integers(0, 2 ** 63, C, dtype=np.int64).astype(np.uint64)  # about half the rows
    mask[rng.random(C) < 0.1] = 0  # whole cells off
    sizes = np.diff(scene.cell_start)
    every = np.array([(1 << int(n)) - 1 if n < 64 else 2 ** 64 - 1 for n in sizes], np.uint64)
    mask &= every
    kept = np.concatenate([(mask[c] >> np.arange(n, dtype=np.uint64)) & np.uint64(1)
                           for c, n in enumerate(sizes)])
    rows = np.nonzero(kept == 0)[0]  # the rows the mask drops
    hidden = FastBatch([scene])
    hidden.packed[P_O, rows] = 0.0
    hidden.packed[P_CUT, rows] = 0.0
    drawn = 0
    for p in POSES:
        view, _, k = camera_arrays(robot_camera(W, H, **p))
        rgb, depth = _view(batch).draw(view, *k, cell_mask=mask)
        rgb_ref, depth_ref = _view(hidden).draw(view, *k)
        assert np.abs(rgb.astype(int) - rgb_ref).max() <= 1
        np.testing.assert_allclose(depth, depth_ref, rtol=1e-5)
        full_rgb, full_depth = _view(batch).draw(view, *k)
        rgb_all, depth_all = _view(batch).draw(view, *k, cell_mask=every)  # bit path, every bit
        np.testing.assert_array_equal(rgb_all, full_rgb)
        np.testing.assert_array_equal(depth_all, full_depth)
        drawn += int((rgb != full_rgb).any())
    assert drawn > 0  # the mask changed what was drawn


def test_each_views_own_set_is_measured_in_the_same_pass(model):
    cams = [robot_camera(W, H, **p) for p in POSES]
    conf = SimReadyConfig(keep_mass=0.99, width=W, height=H, view_keep_mass=0.9)
    small, sig, sets = sim_ready_views(model, cams, conf, RasterSettings(W, H))
    small_ref, sig_ref = sim_ready(model, cams, conf, RasterSettings(W, H))
    assert small.num == small_ref.num and np.array_equal(sig, sig_ref)
    assert sets.shape == (len(cams), (small.num + 7) // 8)
    own = np.unpackbits(sets, axis=1, count=small.num).astype(bool)  # [V, K]
    assert own.any(1).all()
    # a view's set is a fraction of the splats: less than every splat any view needs
    assert own.sum(1).max() < own.any(0).sum()
    none = sim_ready_views(model, cams, SimReadyConfig(keep_mass=0.99, width=W, height=H),
                           RasterSettings(W, H))[2]
    assert len(none) == 0


def test_cell_masks_keep_exactly_the_sets_and_unite_the_near_views(model, scene, tmp_path):
    rng = np.random.default_rng(1)
    N = model.num
    cams = [robot_camera(W, H, x=float(x), yaw_deg=float(a))
            for x, a in zip(rng.uniform(-5, 5, 12), rng.uniform(-20, 20, 12))]
    sets = [np.sort(rng.choice(N, 500, replace=False)) for _ in cams]
    member = np.zeros((len(cams), N), bool)
    for v, idx in enumerate(sets):
        member[v, idx] = True
    views = ViewSets.from_cameras(cams, np.packbits(member, axis=1), N)
    back = ViewSets.load(views.save(tmp_path / "views.npz"))
    assert back.num == N and np.array_equal(back.sets, views.sets)
    assert np.array_equal(back.centres, views.centres) and np.array_equal(back.forwards, views.forwards)
    masks = CellMasks(back, scene, radius=3.0, heading_deg=15.0)
    starts = scene.cell_start
    for v, idx in enumerate(sets):  # the bits name the set's splats, through the cell order
        bits = np.unpackbits(masks.masks[v].view(np.uint8), bitorder="little").reshape(-1, 64)
        cell, j = np.nonzero(bits)
        assert np.array_equal(np.sort(scene.index[starts[cell] + j]), idx)
    w2c = camera_arrays(cams[0])[0]
    near = masks.near(w2c)
    c, f = camera_pose(w2c)
    want = [v for v in range(len(cams)) if np.linalg.norm(views.centres[v] - c) <= 3.0
            and views.forwards[v] @ f >= np.cos(np.radians(15.0))]
    assert list(near) == want and 0 in want
    union = masks.mask(w2c)
    if len(want) >= MIN_VIEWS:
        np.testing.assert_array_equal(union, np.bitwise_or.reduce(masks.masks[want], axis=0))
    far = camera_arrays(robot_camera(W, H, x=100.0, yaw_deg=0.0))[0]
    assert masks.mask(far) is None  # no measured view near: every splat
    with pytest.raises(ValueError, match="culling cells of up to 64"):
        CellMasks(back, StaticScene(model, StaticSceneConfig(cell_size=128)), 1.0, 30.0)
    with pytest.raises(ValueError, match="measured on"):
        CellMasks(ViewSets.from_cameras(cams[:1], np.packbits(member[:1, :N - 1], axis=1), N - 1),
                  scene, 1.0, 30.0)
    with pytest.raises(ValueError, match="sets of shape"):
        ViewSets.from_cameras(cams, np.packbits(member, axis=1)[:3], N)
