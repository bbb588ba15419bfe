"""Policy -> env action mappings: round trip, the wrapped env, expert demonstrations, evaluation."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3 import SAC

from vid2sim.training.actions import ActionMapping, affine, from_env, to_env
from vid2sim.training.config import SACConfig, TrainConfig
from vid2sim.training.evaluate import EvalConfig, evaluate, load_policy
from vid2sim.training.privileged import PRIVILEGED_ID
from vid2sim.training.sac import train
from vid2sim.training.wrappers import ExpertActions

SCENE = "synthetic-street-s1"


@pytest.fixture(scope="module")
def street_registry(tmp_path_factory):
    from benchmarks.street_registry import build
    return build(tmp_path_factory.mktemp("streets"), [1]).root


def test_full_map_covers_the_speed_range_and_round_trips():
    policy = np.stack(np.meshgrid(np.linspace(-1, 1, 9), np.linspace(-1, 1, 5)), -1).reshape(-1, 2)  # [45, 2]
    env = to_env(policy, "full")
    assert env[:, 0].min() == pytest.approx(0.0) and env[:, 0].max() == pytest.approx(1.0)
    np.testing.assert_allclose(env[:, 0], (policy[:, 0] + 1) / 2)  # only p = -1 stops
    np.testing.assert_allclose(env[:, 1], policy[:, 1])  # steering untouched
    np.testing.assert_allclose(from_env(env, "full"), policy, atol=1e-6)
    np.testing.assert_allclose(to_env(policy, "clamp"), policy)  # the envs' own contract
    np.testing.assert_allclose(from_env(policy, "clamp"), policy)
    assert from_env(np.array([-0.4, 0.2]), "full")[0] == -1.0  # an env "stop" is the policy's -1
    scale, offset = affine("full")
    np.testing.assert_allclose(policy * scale + offset, env)  # what export.py bakes in
    with pytest.raises(ValueError):
        to_env(policy, "reverse")


def test_wrapped_env_drives_at_the_mapped_speed(street_registry, tmp_path):
    def travelled(env: gym.Env, speed: float) -> float:
        env.reset(seed=3)
        x0, y0, _ = env.unwrapped.robot_pose()
        for _ in range(3):
            env.step(np.array([speed, 0.0], np.float32))
        x1, y1, _ = env.unwrapped.robot_pose()
        return float(np.hypot(x1 - x0, y1 - y0))

    make = dict(registry=str(street_registry), scenes=SCENE, training=False, checkout_root=str(tmp_path))
    plain, full = gym.make(PRIVILEGED_ID, **make), ActionMapping(gym.make(PRIVILEGED_ID, **make), "full")
    assert travelled(plain, -0.5) == 0.0 and travelled(full, -1.0) == 0.0  # stop
    assert travelled(full, -0.5) > 0.0  # the clamped half of the range moves under "full"
    assert travelled(full, 0.0) == pytest.approx(travelled(plain, 0.5), abs=1e-6)
    assert travelled(full, 1.0) == pytest.approx(travelled(plain, 1.0), abs=1e-6)


def test_expert_action_is_mapped_back_into_the_policy_space(street_registry, tmp_path):
    env = ActionMapping(ExpertActions(gym.make(PRIVILEGED_ID, registry=str(street_registry), scenes=SCENE,
                                               training=False, checkout_root=str(tmp_path))), "full")
    env.reset(seed=0)
    for _ in range(5):
        raw = env.env.expert_action()  # the expert in the envs' contract: speed in [0.3, 1]
        mapped = env.get_wrapper_attr("expert_action")()  # what SB3's env_method returns
        np.testing.assert_allclose(mapped, [2 * raw[0] - 1, raw[1]], atol=1e-6)
        env.step(mapped)  # and it drives the expert's speed again


def demo_run(registry, run_dir, action_map: str, n_rays: int = 11) -> SAC:
    """80 env steps (60 of expert warm-up, 20 of SAC + BC), replay buffer saved."""
    sac = SACConfig(learning_starts=60, batch_size=16, buffer_size=200, net_arch=(16, 16), use_sde=False,
                    warmup="expert", bc_weight=1.0)
    config = TrainConfig(run_dir=str(run_dir), total_steps=80, env_id=PRIVILEGED_ID,
                         env_module="vid2sim.training.privileged", registry=str(registry),
                         scene_ids=[SCENE], env_kwargs={"training": True, "n_rays": n_rays}, n_envs=2, n_actors=0,
                         stuck_steps=10, save_replay_buffer=True, checkpoint_every=80, action_map=action_map, sac=sac)
    train(config, progress_bar=False, log_every=40)
    model = SAC.load(run_dir / "final.zip", device="cpu")
    model.load_replay_buffer(run_dir / "checkpoints" / "replay.pkl")
    return model


def test_expert_demonstrations_under_the_full_map(street_registry, tmp_path):
    full = demo_run(street_registry, tmp_path / "full", "full", n_rays=7)
    clamp = demo_run(street_registry, tmp_path / "c", "clamp", n_rays=7)
    assert full.action_map == "full" and TrainConfig.load(tmp_path / "full" / "config.json").action_map == "full"
    assert clamp.action_map == "clamp"
    demos = full.replay_buffer.actions[:30].reshape(-1, 2)  # [60, 2] warm-up rows, policy space
    expert = clamp.replay_buffer.actions[:30].reshape(-1, 2)  # the same episodes in the envs' contract
    assert expert[:, 0].min() >= 0.3 - 1e-6  # pure pursuit: speed in [0.3, 1]
    np.testing.assert_allclose(demos, from_env(expert, "full"), atol=1e-5)  # stored as 2 s - 1
    np.testing.assert_allclose(to_env(demos, "full"), expert, atol=1e-5)
    assert (demos[:, 0] < expert[:, 0] - 0.05).any()
    assert full.replay_buffer.rewards[:30].mean() > 0  # they drive towards the goal

    act, _ = load_policy(str(tmp_path / "full"), seed=0)  # evaluation applies the model's mapping
    obs = full.observation_space.sample()
    expected = to_env(full.predict(obs, deterministic=True)[0], "full")
    np.testing.assert_allclose(act(None, obs), expected, atol=1e-6)
    assert 0.0 <= act(None, obs)[0] <= 1.0

    ckpt = str(tmp_path / "full" / "checkpoints" / "last.zip")
    report = evaluate(EvalConfig(registry=str(street_registry), policy=ckpt, scene_ids=[SCENE], trials=1,
                                 max_steps=5, env_id=PRIVILEGED_ID, checkout_root=str(tmp_path / "co")))
    assert report.episodes == 1 and report.config["env_kwargs"] == {}  # 7 rays read from the run's config
