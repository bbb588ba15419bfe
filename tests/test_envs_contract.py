"""NavEnv's step/reset contract on real registry scenes.

After an episode ended (terminated or truncated) `step()` raises `EpisodeEndedError` until
`reset()`; a `reset()` that raises (a scene whose every start touches the collision mesh)
leaves the env without an episode but usable: `step()` raises `ResetNeededError` and a reset
on a good scene starts a normal episode.
"""

from __future__ import annotations


import gymnasium
import numpy as np
import pytest
import trimesh

import vid2sim.envs  # noqa: F401  (registers the env ids)
from tests.street_bundles import renamed_copy, street_bundle
from vid2sim.envs.config import FastRenderConfig, RewardConfig
from vid2sim.envs.nav_env import EpisodeEndedError, NavEnv, ResetNeededError
from vid2sim.envs.scenes import SceneError
from vid2sim.registry import Registry

GOOD, BLOCKED = "synthetic-street-s11", "blocked-street"
FAST = FastRenderConfig(views=256)  # the default set, measured on fewer views (test time)


@pytest.fixture(scope="module")
def registry(tmp_path_factory):
    """The synthetic street's GT bundle, and a copy whose collision mesh has a slab through the
    robot's height band over the whole walkable map (every start touches it)."""
    root = tmp_path_factory.mktemp("envs_contract")
    bundle = street_bundle(root)
    reg = Registry(root / "registry")
    reg.add(bundle)
    reg.add(_blocked_copy(bundle, root / "blocked"))
    return reg, root / "checkouts"


def _blocked_copy(bundle, out):
    renamed_copy(bundle, out, BLOCKED)
    with np.load(out / "walkable.npz") as z:
        shape, origin, res = z["grid"].shape, z["origin"], float(z["resolution"])
    extent = np.array(shape[::-1], float) * res
    centre = origin + extent / 2
    slab = trimesh.creation.box(extents=[extent[0] + 4, extent[1] + 4, 0.2])
    slab.apply_translation([centre[0], centre[1], 0.45])  # inside the box's 0.15-0.75 m band
    slab.export(out / "collision.ply")
    return out


def make(registry, scenes=GOOD, **kw):
    reg, co = registry
    return gymnasium.make("vid2sim/PointNav-v0", registry=reg.root, scenes=scenes, checkout_root=co,
                          fast=FAST, **kw)


def test_step_after_success_raises_until_reset(registry):
    # a goal radius wider than the map: the first step is a success
    env = make(registry, reward=RewardConfig(success_radius=1e4))
    env.reset(seed=0)
    _, r, terminated, truncated, info = env.step(np.array([0.5, 0.0], np.float32))
    assert terminated and not truncated and info["end"] == "success" and r > 9
    for _ in range(3):
        with pytest.raises(EpisodeEndedError, match="reset"):
            env.step(np.array([0.5, 0.0], np.float32))
    assert issubclass(EpisodeEndedError, RuntimeError)
    obs, info = env.reset(seed=1)  # a new episode steps again
    assert info["steps"] == 0
    _, _, terminated, _, info = env.step(np.array([0.5, 0.0], np.float32))
    assert terminated and info["steps"] == 1
    env.close()


def test_step_after_truncation_raises(registry):
    env = make(registry, reward=RewardConfig(max_steps=2))
    env.reset(seed=0)
    out = [env.step(np.zeros(2, np.float32)) for _ in range(2)]
    assert not out[0][3] and out[1][3] and out[1][4]["end"] == "timeout"
    with pytest.raises(EpisodeEndedError):
        env.step(np.zeros(2, np.float32))
    env.reset(seed=0)
    assert not env.step(np.zeros(2, np.float32))[3]  # step 1 of a fresh episode
    env.close()


def test_failed_first_reset_leaves_env_usable(registry):
    reg, co = registry
    env = NavEnv(reg.root, [BLOCKED, GOOD], checkout_root=co, fast=FAST)
    with pytest.raises(ResetNeededError, match=r"call reset\(\)") as before:
        env.step(np.zeros(2, np.float32))
    assert isinstance(before.value, RuntimeError) and not isinstance(before.value, EpisodeEndedError)
    with pytest.raises(SceneError, match="no_free_start"):
        env.reset(seed=0, options={"scene_id": BLOCKED})
    for _ in range(2):
        with pytest.raises(ResetNeededError, match=r"call reset\(\)"):
            env.step(np.zeros(2, np.float32))
    assert env.render() is None
    obs, info = env.reset(seed=0, options={"scene_id": GOOD})
    assert info["scene_id"] == GOOD and obs["image"].shape[0] == 6
    _, _, terminated, truncated, info = env.step(np.array([0.3, 0.0], np.float32))
    assert info["steps"] == 1 and info["scene_id"] == GOOD
    env.close()


def test_failed_reset_after_an_episode_drops_the_old_one(registry):
    """A reset that raises mid-way must not let step() carry on the previous episode."""
    reg, co = registry
    env = NavEnv(reg.root, [GOOD, BLOCKED], checkout_root=co, fast=FAST)
    env.reset(seed=0, options={"scene_id": GOOD})
    env.step(np.array([0.3, 0.0], np.float32))
    with pytest.raises(SceneError, match="no_free_start"):
        env.reset(seed=0, options={"scene_id": BLOCKED})
    with pytest.raises(ResetNeededError):
        env.step(np.zeros(2, np.float32))
    _, info = env.reset(seed=3, options={"scene_id": GOOD})
    assert info["steps"] == 0
    assert env.step(np.array([0.3, 0.0], np.float32))[4]["steps"] == 1
    env.close()


def test_wrapped_env_after_failed_reset(registry):
    """Through gymnasium.make (order enforcing + passive checker): the same named error."""
    env = make(registry, scenes=[BLOCKED, GOOD])
    with pytest.raises(SceneError):
        env.reset(seed=0, options={"scene_id": BLOCKED})
    with pytest.raises(ResetNeededError):
        env.step(np.zeros(2, np.float32))
    env.reset(seed=0, options={"scene_id": GOOD})
    env.step(np.zeros(2, np.float32))
    env.close()
