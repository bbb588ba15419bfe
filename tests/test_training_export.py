"""Exported policy (ONNX via onnxruntime, torch.export program) == the trained SB3 actor."""

from __future__ import annotations

import numpy as np
import pytest

from vid2sim.training.actions import to_env
from vid2sim.training.config import SACConfig, TrainConfig
from vid2sim.training.export import NavPolicy, export_policy
from vid2sim.training.sac import build_model, env_specs, make_vec_env


def small_model(tmp_path_factory, action_map: str = "clamp"):
    sac = SACConfig(learning_starts=20, batch_size=4, buffer_size=200, image_dim=32, vector_dim=16, net_arch=(32, 32))
    config = TrainConfig(run_dir=str(tmp_path_factory.mktemp("run")), total_steps=40, env_id="tests/GoalSeek-v0",
                         env_module="tests.training_envs", n_envs=1, n_actors=0, sac=sac, action_map=action_map)
    env = make_vec_env(env_specs(config), 0)
    model = build_model(config, env)
    model.learn(24)
    return model, env


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    return small_model(tmp_path_factory)


def test_exported_actions_equal_trained(trained, tmp_path):
    model, env = trained
    out = export_policy(model, tmp_path / "export")
    onnx, prog = NavPolicy(out, "onnx"), NavPolicy(out, "torch")
    obs = env.reset()
    for _ in range(5):
        expected, _ = model.predict(obs, deterministic=True)
        np.testing.assert_allclose(onnx.act_stacked(obs["image"], obs["vector"]), expected, atol=1e-5)
        np.testing.assert_allclose(prog.act_stacked(obs["image"], obs["vector"]), expected, atol=1e-5)
        obs, *_ = env.step(expected)
    batch = {k: np.repeat(v, 3, axis=0) for k, v in obs.items()}
    assert onnx.act_stacked(batch["image"], batch["vector"]).shape == (3, 2)


def test_step_api_keeps_history_and_clamps(trained, tmp_path):
    model, _ = trained
    policy = NavPolicy(export_policy(model, tmp_path / "export"), "onnx")
    frame = np.zeros((36, 64, 3), np.uint8)
    speed, steering = policy.step(frame, 5.0, 0.3)
    assert -1 <= speed <= 1 and -1 <= steering <= 1
    policy.step(np.full((36, 64, 3), 200, np.uint8), 4.0, 0.2)
    assert policy.frames.shape == (6, 3, 36, 64) and policy.frames[-1].max() == 200 and policy.frames[0].max() == 0
    assert np.allclose(policy.vectors[-1], [4.0, 0.2 / np.pi])
    # extreme inputs still give actions inside the clamp
    big = policy.act_stacked(np.full((1, 6, 3, 36, 64), 255, np.uint8), np.full((1, 6, 2), 1e6, np.float32))
    assert np.all(np.abs(big) <= 1.0)
    policy.reset()
    assert policy.frames is None


def test_export_bakes_in_the_full_speed_map(tmp_path_factory, tmp_path):
    model, env = small_model(tmp_path_factory, "full")
    model.save(tmp_path / "model.zip")  # the mapping travels with the saved model
    out = export_policy(tmp_path / "model.zip", tmp_path / "export")
    onnx, prog = NavPolicy(out, "onnx"), NavPolicy(out, "torch")
    assert onnx.meta.action_map == "full"
    obs = env.reset()
    for _ in range(5):
        raw, _ = model.predict(obs, deterministic=True)  # the policy's own space
        expected = to_env(raw, "full")  # what the training envs executed
        np.testing.assert_allclose(onnx.act_stacked(obs["image"], obs["vector"]), expected, atol=1e-5)
        np.testing.assert_allclose(prog.act_stacked(obs["image"], obs["vector"]), expected, atol=1e-5)
        obs, *_ = env.step(raw)  # the vec env wraps ActionMapping itself
    big = onnx.act_stacked(np.full((2, 6, 3, 36, 64), 255, np.uint8), np.full((2, 6, 2), -1e6, np.float32))
    assert np.all(big[:, 0] >= 0.0) and np.all(big[:, 0] <= 1.0) and np.all(np.abs(big[:, 1]) <= 1.0)
