"""The envs' default fast render path against the exact render on a small real scene.

The synthetic street's ground-truth bundle (1 s clip, 20k splats): the scripted expert drives a
PointNav episode with the default fast path (the sim-ready set of `FastRenderConfig()`), and at
every other step's camera pose the fast splat image is compared with the exact one. The
defaults promise >= 32 dB mean and >= 26 dB worst PSNR (docs/envs.md); this checks both.
"""

from __future__ import annotations

from pathlib import Path

import gymnasium
import numpy as np
import pytest

import vid2sim.envs  # noqa: F401  (registers the env ids)
from tests.street_bundles import street_bundle
from vid2sim.envs import simready
from vid2sim.envs.config import FastRenderConfig
from vid2sim.envs.expert import PurePursuitExpert
from vid2sim.envs.rendering import FastSplatView, SplatView
from vid2sim.registry import Registry

MEAN_DB, WORST_DB = 32.0, 26.0


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(((a.astype(np.float64) - b.astype(np.float64)) ** 2).mean())
    return 99.0 if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)


@pytest.fixture(scope="module")
def registry(tmp_path_factory):
    root = tmp_path_factory.mktemp("fastfid")
    reg = Registry(root / "registry")
    reg.add(street_bundle(root))
    return reg


def _env(registry: Registry, fast: FastRenderConfig) -> gymnasium.Env:
    simready._CACHE.clear()
    return gymnasium.make("vid2sim/PointNav-v0", registry=registry.root, scenes="synthetic-street-s11",
                          checkout_root=Path(registry.root).parent / "checkouts", fidelity="fast", fast=fast)


@pytest.fixture(scope="module")
def env(registry):
    e = _env(registry, FastRenderConfig())
    yield e
    e.close()


@pytest.fixture(scope="module")
def env_view_sets(registry):
    e = _env(registry, FastRenderConfig(view_keep_mass=0.98))
    yield e
    e.close()


def test_default_fast_path_agrees_with_exact(env):
    assert env.unwrapped.config.fast == FastRenderConfig()  # the default path
    _check_against_exact(env)


def test_view_sets_keep_the_fast_paths_fidelity(env_view_sets):
    """With view sets each frame draws part of the sim-ready set, within the same bars; the
    sets are written beside the set's PLY and read back by a later process."""
    env = env_view_sets
    _check_against_exact(env)
    u = env.unwrapped
    sets = u.world.view.sim.views
    assert sets is not None and len(sets.masks) >= 1024
    drawn = [sets.mask(u.last_world_to_cam)]
    assert drawn[0] is not None  # the expert's camera has measured views near it
    kept = sum(bin(int(w)).count("1") for w in drawn[0])
    assert kept < u.world.view.sim.model.num
    files = sorted((u.world.assets.bundle_dir.parent / "simready").glob("simready-*.views.npz"))
    assert len(files) == 1
    simready._CACHE.clear()  # a new process: the set and its view sets come from disk
    again = simready.sim_ready_set(u.world.assets.content_key(), u.world.assets.splats,
                                   u.world.assets.walkable, u.config.camera, u.config.fast,
                                   cache_dir=files[0].parent)
    np.testing.assert_array_equal(again.views.masks, sets.masks)


def _check_against_exact(env: gymnasium.Env) -> None:
    u = env.unwrapped
    env.reset(seed=3)
    view = u.world.view
    assert isinstance(view, FastSplatView)
    exact = SplatView(u.world.assets.splats, u.config.camera)
    expert, quality, steps = PurePursuitExpert(), [], 0
    expert.reset(env)
    while steps < 40:
        _, _, term, trunc, _ = env.step(expert.act(env))
        steps += 1
        if steps % 2 == 0:
            w2c = u.last_world_to_cam
            fast_rgb, fast_depth = view.draw(w2c)
            exact_rgb, exact_depth = exact.draw(w2c)
            quality.append(_psnr(fast_rgb, exact_rgb))
            both = np.isfinite(fast_depth) & np.isfinite(exact_depth)
            assert both.mean() > 0.3
            rel = np.abs(fast_depth[both] - exact_depth[both]) / exact_depth[both]
            assert float(np.median(rel)) < 0.02
        if term or trunc:
            env.reset(seed=3 + steps)
            expert.reset(env)
    assert view.sim.model.num < u.world.assets.splats.num  # pruned: not the exact set
    assert np.mean(quality) >= MEAN_DB, quality
    assert min(quality) >= WORST_DB, quality
