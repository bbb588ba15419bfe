"""Batched env frames (env_frame.py / env_batch.py) equal single StaticScene renders."""

from __future__ import annotations

import pytest
import torch

from vid2sim.splats.cpu import StaticScene
from vid2sim.splats.cpu.env_batch import SceneBatch, render_many
from vid2sim.splats.cpu.synthetic import robot_camera, street_scene
from vid2sim.splats.reference import rasterize as torch_rasterize
from vid2sim.splats.render import finish
from vid2sim.splats.types import RasterSettings

BG = (0.2, 0.3, 0.4)


@pytest.fixture(scope="module")
def scenes():
    return [StaticScene(street_scene(6000, length=30.0, seed=1)),
            StaticScene(street_scene(4000, length=20.0, seed=2).with_sh_degree(1))]


def _cams():
    poses = [dict(x=-10.0, yaw_deg=0.0), dict(x=0.0, yaw_deg=35.0), dict(x=5.0, y=-4.0, yaw_deg=80.0),
             dict(x=3.0, yaw_deg=-20.0)]
    return [robot_camera(64, 36, **p) for p in poses]


@pytest.mark.parametrize("degree,cov,workers", [(0, None, 1), (3, 0.01, 2), (1, None, 3)])
def test_batch_equals_single_renders(scenes, degree, cov, workers):
    cams = _cams()
    ids = [0, 1, 1, 0]
    st = RasterSettings(64, 36, active_sh_degree=degree, cov_cull_alpha=cov)
    out = render_many(scenes, cams, ids, settings=st, background=BG, n_workers=workers)
    assert out.rgb.shape == (4, 36, 64, 3) and out.blends.shape == (4, 36, 64)
    for i, (c, s) in enumerate(zip(cams, ids)):
        ref = scenes[s].render(c, st, background=BG)
        assert ref.alpha.mean() > 0.2
        torch.testing.assert_close(out.rgb[i], ref.rgb, atol=1e-6, rtol=0)
        torch.testing.assert_close(out.alpha[i], ref.alpha, atol=0, rtol=0)
        torch.testing.assert_close(out.depth[i], ref.depth, atol=1e-6, rtol=1e-6)
        assert out.stats[i, 2] == int(out.blends[i].sum())


def test_blend_cap_limits_blends(scenes):
    cams = _cams()
    st = RasterSettings(64, 36, active_sh_degree=0)
    batch = SceneBatch(scenes[:1])
    exact = batch.render(cams, settings=st, background=BG)
    capped = batch.render(cams, settings=st, background=BG, blend_cap=4)
    assert int(capped.blends.max()) <= 4 < int(exact.blends.max())
    assert float(capped.alpha.mean()) <= float(exact.alpha.mean())


def test_batch_rejects_mixed_sizes(scenes):
    cams = [robot_camera(64, 36), robot_camera(32, 18)]
    with pytest.raises(ValueError, match="every camera"):
        SceneBatch(scenes[:1]).render(cams)


def test_batch_matches_torch_reference():
    """The env frame kernel against the plain-torch reference (small scene and image)."""
    model = street_scene(1500, length=12.0, seed=3)
    cams = [robot_camera(32, 18, x=x, yaw_deg=y) for x, y in ((-3.0, 0.0), (0.0, 30.0))]
    st = RasterSettings(32, 18, active_sh_degree=3)
    out = render_many([StaticScene(model)], cams, settings=st, background=BG)
    for i, c in enumerate(cams):
        with torch.no_grad():
            ref = finish(torch_rasterize(model.means, model.quats, model.log_scales,
                                         model.opacity_logits, model.sh, c, st), BG)
        assert float(ref.alpha.mean()) > 0.2
        torch.testing.assert_close(out.rgb[i], ref.rgb.float(), atol=2e-4, rtol=1e-4)
        torch.testing.assert_close(out.alpha[i], ref.alpha.float(), atol=2e-4, rtol=1e-4)
        torch.testing.assert_close(out.depth[i], ref.depth.float(), atol=1e-3, rtol=1e-4)
