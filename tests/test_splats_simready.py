"""Sim-ready splats: measured significance and pruning by carried blend weight."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vid2sim.splats.cpu import StaticScene
from vid2sim.splats.cpu.env_simready import (SimReadyConfig, keep_by_mass, robot_cameras,
                                         significance, sim_ready)
from vid2sim.splats.cpu.synthetic import street_scene
from vid2sim.splats.types import RasterSettings


@pytest.fixture(scope="module")
def street():
    return street_scene(6000, length=30.0, seed=1)


def _views(n, seed):
    rng = np.random.default_rng(seed)
    xy = np.stack([rng.uniform(-12, 12, n), rng.uniform(-1.5, 1.5, n)], 1)
    return robot_cameras(xy, rng.uniform(-np.pi, np.pi, n), width=64, height=36)


def test_significance_is_the_blend_weight(street):
    """Summed over splats, significance equals the summed alpha of the views."""
    st = RasterSettings(64, 36, active_sh_degree=0)
    scene = StaticScene(street)
    cams = _views(6, seed=0)
    sig = significance(scene, cams, st)
    total_alpha = sum(float(scene.render(c, st).alpha.double().sum()) for c in cams)
    assert sig.shape == (street.num,) and (sig >= 0).all()
    assert abs(sig.sum() - total_alpha) < 1e-3 * total_alpha


def test_keep_by_mass():
    sig = np.array([0.0, 5.0, 1.0, 3.0, 1.0])
    assert keep_by_mass(sig, 0.5).tolist() == [False, True, False, False, False]
    assert keep_by_mass(sig, 0.8).tolist() == [False, True, False, True, False]
    assert keep_by_mass(sig, 1.0).tolist() == [False, True, True, True, True]


def test_sim_ready_keeps_the_image(street):
    """Pruned on some views, close to exact on other views."""
    st = RasterSettings(64, 36, active_sh_degree=0)
    small, _ = sim_ready(street, _views(64, seed=1), SimReadyConfig(keep_mass=0.999, width=64,
                                                                    height=36))
    assert small.num < 0.95 * street.num
    full, pruned = StaticScene(street), StaticScene(small)
    for c in _views(4, seed=2):
        a, b = full.render(c, st).rgb, pruned.render(c, st).rgb
        mse = float(((a - b) ** 2).mean())
        assert 10 * np.log10(1.0 / max(mse, 1e-12)) > 35.0
    assert torch.isfinite(small.means).all()


def test_fit_recovers_what_pruning_loses(street):
    """A hard prune, then a short fit to exact renders of the pruning views: closer to exact
    on other views than the prune alone."""
    st = RasterSettings(64, 36, active_sh_degree=0)
    train, test = _views(48, seed=3), _views(4, seed=4)
    conf = dict(keep_mass=0.9, width=64, height=36, bake_colour=True)
    pruned, _ = sim_ready(street, train, SimReadyConfig(**conf))
    fitted, _ = sim_ready(street, train, SimReadyConfig(**conf, fit_iterations=150))
    assert fitted.num == pruned.num < 0.9 * street.num
    full = StaticScene(street)

    def psnr(model):
        scene = StaticScene(model)
        errs = [float(((scene.render(c, st).rgb - full.render(c, st).rgb) ** 2).mean()) for c in test]
        return 10 * np.log10(1.0 / np.mean(errs))

    assert psnr(fitted) > psnr(pruned) + 1.0
