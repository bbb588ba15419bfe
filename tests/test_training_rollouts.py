"""RayVecEnv against SB3's DummyVecEnv on real envs, and a killed actor (real Ray runtime)."""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest
import ray
from stable_baselines3.common.vec_env import DummyVecEnv

from tests.conftest import PROJECT_ROOT
from vid2sim.training.rollouts import EnvSpec, init_ray, RayVecEnv, RayVecEnvConfig, partition, specs_for_scenes


@pytest.fixture(scope="module")
def ray_runtime():
    path = os.pathsep.join([str(PROJECT_ROOT), os.environ.get("PYTHONPATH", "")])
    init_ray(num_cpus=2, runtime_env={"env_vars": {"PYTHONPATH": path}})
    yield
    ray.shutdown()


def goal_specs(n: int, horizons: tuple[int, ...] = (5, 7, 60, 9)) -> list[EnvSpec]:
    return [EnvSpec("tests/GoalSeek-v0", {"max_episode_steps": horizons[i % len(horizons)]}, seed=10 + i,
                    module="tests.training_envs") for i in range(n)]


def assert_obs_equal(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])


def test_partition_and_scene_specs():
    assert partition(5, 2) == [[0, 1, 2], [3, 4]]
    assert partition(2, 4) == [[0], [1]]
    specs = specs_for_scenes("vid2sim/PointNav-v0", ["a", "b"], 3, {"registry": "/r"}, seed=4)
    assert [s.kwargs["scenes"] for s in specs] == ["a", "b", "a"]
    assert [s.seed for s in specs] == [4, 5, 6]


def test_matches_dummy_vec_env_on_boundary_steps(ray_runtime):
    """Same seeds and actions: identical obs, rewards, dones, terminal_observation, TimeLimit.truncated."""
    specs = goal_specs(4)
    ray_env = RayVecEnv(specs, RayVecEnvConfig(n_actors=2, num_cpus_per_actor=0.5))
    dummy = DummyVecEnv([s.make for s in specs])
    dummy.seed(0), ray_env.seed(0)
    for i, s in enumerate(specs):
        dummy._seeds[i] = ray_env._seeds[i] = s.seed
    assert_obs_equal(ray_env.reset(), dummy.reset())
    rng = np.random.default_rng(0)
    saw_truncation = saw_termination = False
    for _ in range(25):
        actions = rng.uniform(-1, 1, (4, 2)).astype(np.float32)
        ro, rr, rd, ri = ray_env.step(actions)
        do, dr, dd, di = dummy.step(actions)
        assert_obs_equal(ro, do)
        np.testing.assert_allclose(rr, dr)
        np.testing.assert_array_equal(rd, dd)
        assert all(o.flags.writeable for o in ro.values())
        for a, b in zip(ri, di):
            assert a["TimeLimit.truncated"] == b["TimeLimit.truncated"]
            assert ("terminal_observation" in a) == ("terminal_observation" in b)
            if "terminal_observation" in a:
                assert_obs_equal(a["terminal_observation"], b["terminal_observation"])
                assert a["terminal_observation"]["image"].flags.writeable
                saw_truncation |= a["TimeLimit.truncated"]
                saw_termination |= not a["TimeLimit.truncated"]
    assert saw_truncation, "no time-limit boundary was crossed"
    assert ray_env.get_attr("spec")[2].max_episode_steps == 60
    assert ray_env.env_method("render", indices=[1, 3])[0].shape == (36, 64, 3)
    ray_env.close()


def test_killed_actor_is_restarted_and_stepping_goes_on(ray_runtime):
    specs = goal_specs(4, horizons=(1000,))
    env = RayVecEnv(specs, RayVecEnvConfig(n_actors=2, num_cpus_per_actor=0.5))
    obs = env.reset()
    env.set_attr("arena", 7.0, indices=[1])
    env.env_method("set_dt", 0.1, indices=[0, 1, 2])
    env.env_method("set_dt", 0.3, indices=[0])  # the latest call per env is replayed
    actions = np.zeros((4, 2), np.float32)
    env.step(actions)
    pids = env.actor_pids()
    os.kill(pids[0], signal.SIGKILL)
    time.sleep(0.5)
    obs, rewards, dones, infos = env.step(actions)
    assert dones.tolist() == [True, True, False, False]
    for i in (0, 1):
        assert infos[i]["actor_restarted"] and infos[i]["TimeLimit.truncated"]
        assert infos[i]["terminal_observation"]["image"].shape == (6, 3, 36, 64)
        assert obs["vector"][i, :-1].sum() == 0  # fresh episode: only the first stacked step is filled
    assert env.restarts == 1
    new_pids = env.actor_pids()
    assert new_pids[0] != pids[0] and new_pids[1] == pids[1]
    assert env.get_attr("arena") == [4.0, 7.0, 4.0, 4.0]  # settings survive the replacement
    assert env.get_attr("dt") == [0.3, 0.1, 0.1, 0.2]
    for _ in range(5):
        obs, rewards, dones, infos = env.step(actions)
    assert not any(info.get("actor_restarted") for info in infos)
    env.close()
