"""FastView (one env camera to uint8 rgb + depth in one call) against FastBatch + view_outputs."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vid2sim.envs.rendering import EMPTY_ALPHA, view_outputs
from vid2sim.splats.cpu import StaticScene, StaticSceneConfig
from vid2sim.splats.cpu.env_fast_batch import FastBatch
from vid2sim.splats.cpu.env_fast_view import FastView, finish_u8, finish_u8_reference
from vid2sim.splats.cpu.project import camera_arrays
from vid2sim.splats.cpu.synthetic import robot_camera, street_scene
from vid2sim.splats.types import RasterSettings

W, H = 64, 36


@pytest.fixture(scope="module")
def batch():
    model = street_scene(6000, length=30.0, seed=1).with_sh_degree(0)
    return FastBatch([StaticScene(model, StaticSceneConfig(cell_size=64, per_splat_outputs=False))])


@pytest.mark.parametrize("t_stop,bg", [(0.05, (0.0, 0.0, 0.0)), (1e-4, (0.2, 0.3, 0.4))])
def test_fast_view_equals_batch_render_and_view_outputs(batch, t_stop, bg):
    st = RasterSettings(W, H, near=0.05, far=100.0, cov_cull_alpha=0.01)
    fv = FastView(batch, W, H, 0.05, 100.0, 0.01, t_stop, EMPTY_ALPHA, bg)
    poses = [dict(x=-10.0, yaw_deg=0.0), dict(x=0.0, yaw_deg=35.0), dict(x=5.0, y=-4.0, yaw_deg=80.0),
             dict(x=3.0, yaw_deg=-20.0), dict(x=0.0, yaw_deg=180.0)]
    covered = 0
    for p in poses:
        cam = robot_camera(W, H, **p)
        out = batch.render([cam], settings=st, t_stop=t_stop, background=bg, n_workers=1)
        rgb_ref, depth_ref = view_outputs(out.rgb[0], out.depth[0], out.alpha[0])
        view, _, k = camera_arrays(cam)
        rgb, depth = fv.draw(view, *k)
        np.testing.assert_array_equal(rgb, rgb_ref)
        np.testing.assert_array_equal(depth, depth_ref)
        covered += int(np.isfinite(depth).sum())
    assert covered > len(poses) * W * H // 4  # the poses see the street


def test_finish_u8_equals_reference():
    rng = np.random.default_rng(0)
    alpha = rng.uniform(-0.1, 1.0, (H, W)).astype(np.float32).clip(0.0, 1.0)  # zeros included
    color = (rng.uniform(-0.05, 1.1, (H, W, 3)) * alpha[..., None]).astype(np.float32)
    depth_acc = (rng.uniform(0.1, 30.0, (H, W)) * alpha).astype(np.float32)
    bg = np.array([0.2, 0.5, 1.0], np.float32)
    rgb, depth = np.empty((H, W, 3), np.uint8), np.empty((H, W), np.float32)
    finish_u8(color, alpha, depth_acc, bg, np.float32(EMPTY_ALPHA), rgb, depth)
    rgb_ref, depth_ref = finish_u8_reference(color, alpha, depth_acc, bg, EMPTY_ALPHA)
    np.testing.assert_array_equal(rgb, rgb_ref)
    np.testing.assert_array_equal(depth, depth_ref)
    assert np.isinf(depth).any() and np.isfinite(depth).any()
    ref_t = view_outputs(torch.from_numpy(color + (1 - alpha)[..., None] * bg),
                         torch.from_numpy(np.where(alpha > 0, depth_acc / np.maximum(alpha, 1e-6), 0)
                                          .astype(np.float32)), torch.from_numpy(alpha))
    np.testing.assert_array_equal(rgb, ref_t[0])  # the envs' own conversion
