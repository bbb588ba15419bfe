"""Approximate env frames (env_fast_frame.py / env_fast_batch.py) against the exact env frames."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vid2sim.splats.cpu import StaticScene
from vid2sim.splats.cpu.env_batch import SceneBatch
from vid2sim.splats.cpu.env_fast_batch import FastBatch
from vid2sim.splats.cpu.env_simready import SimReadyConfig, robot_cameras, sim_ready
from vid2sim.splats.cpu.synthetic import robot_camera, street_scene
from vid2sim.splats.types import RasterSettings

BG = (0.2, 0.3, 0.4)
ST = RasterSettings(64, 36, active_sh_degree=0)


@pytest.fixture(scope="module")
def scenes():
    return [StaticScene(street_scene(6000, length=30.0, seed=1).with_sh_degree(0)),
            StaticScene(street_scene(4000, length=20.0, seed=2).with_sh_degree(0))]


def _cams():
    poses = [dict(x=-10.0, yaw_deg=0.0), dict(x=0.0, yaw_deg=35.0), dict(x=5.0, y=-4.0, yaw_deg=80.0),
             dict(x=3.0, yaw_deg=-20.0)]
    return [robot_camera(64, 36, **p) for p in poses]


def _psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    mse = float(((a.clamp(0, 1) - b.clamp(0, 1)) ** 2).mean())
    return 10 * np.log10(1.0 / max(mse, 1e-12))


@pytest.mark.parametrize("t_stop", [1e-4, 0.02])
def test_fast_close_to_exact(scenes, t_stop):
    cams, ids = _cams(), [0, 1, 1, 0]
    exact = SceneBatch(scenes).render(cams, ids, settings=ST, background=BG)
    fast = FastBatch(scenes).render(cams, ids, settings=ST, background=BG, t_stop=t_stop)
    for i in range(len(cams)):
        assert float(exact.alpha[i].mean()) > 0.2
        assert _psnr(fast.rgb[i], exact.rgb[i]) > 40.0
        covered = exact.alpha[i] > 0.5
        err = (fast.depth[i] - exact.depth[i]).abs()[covered] / exact.depth[i][covered]
        assert float(err.median()) < 0.01
    assert (fast.stats[:, 2] > 0).all()


def test_fast_batch_equals_single_calls(scenes):
    cams, ids = _cams(), [0, 1, 1, 0]
    fb = FastBatch(scenes)
    out = fb.render(cams, ids, settings=ST, background=BG, n_workers=2)
    for i, (c, s) in enumerate(zip(cams, ids)):
        one = fb.render([c], [s], settings=ST, background=BG)
        torch.testing.assert_close(out.rgb[i], one.rgb[0], atol=0, rtol=0)
        torch.testing.assert_close(out.depth[i], one.depth[0], atol=0, rtol=0)


def test_tile_size_does_not_change_the_image(scenes):
    """16 px tiles (other window starts) give the 32 px tiles' image up to rounding; tiles
    above 32 px are refused (the SIMD composite's pixel state holds 32 x 32)."""
    cams, fb = _cams()[:2], FastBatch(scenes[:1])
    a = fb.render(cams, settings=ST, background=BG, tile_shift=5)
    b = fb.render(cams, settings=ST, background=BG, tile_shift=4)
    torch.testing.assert_close(a.rgb, b.rgb, atol=1e-4, rtol=0)
    assert float(a.alpha.mean()) > 0.2
    with pytest.raises(ValueError):
        fb.render(cams, settings=ST, tile_shift=6)


def test_opaque_stop_renormalises(scenes):
    """A large t_stop stops pixels early; they read alpha 1 and stay near the exact colour,
    much nearer than leaving the remaining transmittance to the background."""
    cams = _cams()[:2]
    exact = SceneBatch(scenes[:1]).render(cams, settings=ST, background=BG)
    fast = FastBatch(scenes[:1]).render(cams, settings=ST, background=BG, t_stop=0.3)
    stopped = fast.alpha == 1.0
    assert float(stopped.float().mean()) > 0.3
    err = (fast.rgb - exact.rgb).abs().amax(-1)[stopped]
    assert float(err.mean()) < 0.3 * 0.25


def test_sim_ready_baked_colours_render_fast():
    """A view-dependent (SH 3) scene: baking its mean colour beats dropping SH to the DC."""
    model = street_scene(5000, length=24.0, seed=5)
    rng = np.random.default_rng(3)
    train = robot_cameras(np.stack([rng.uniform(-10, 10, 48), rng.uniform(-1.5, 1.5, 48)], 1),
                          rng.uniform(-np.pi, np.pi, 48), width=64, height=36)
    test = robot_cameras(np.array([[-6.0, 0.5], [4.0, -0.5]]), np.array([0.2, 2.5]), width=64,
                         height=36)
    baked, _ = sim_ready(model, train, SimReadyConfig(keep_mass=1.0, bake_colour=True,
                                                      width=64, height=36))
    assert baked.sh_degree == 0 and baked.num <= model.num
    st3 = RasterSettings(64, 36, active_sh_degree=3)
    exact = SceneBatch([StaticScene(model)]).render(test, settings=st3).rgb
    fast_baked = FastBatch([StaticScene(baked)]).render(test, settings=ST).rgb
    fast_dc = FastBatch([StaticScene(model.with_sh_degree(0))]).render(test, settings=ST).rgb
    for i in range(len(test)):
        assert _psnr(fast_baked[i], exact[i]) > _psnr(fast_dc[i], exact[i])


def test_fast_rejects_mixed_sizes(scenes):
    with pytest.raises(ValueError, match="every camera"):
        FastBatch(scenes[:1]).render([robot_camera(64, 36), robot_camera(32, 18)])
