"""SAC with the paper preset on a real Dict-observation env: run folder, checkpoints, resume, logs."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3 import SAC

from vid2sim.training.config import SACConfig, TrainConfig
from vid2sim.training.policy import NavCNN
from vid2sim.training.sac import replay_capacity, train, transition_bytes

OBS = gym.spaces.Dict({"image": gym.spaces.Box(0, 255, (6, 3, 72, 128), np.uint8),
                       "vector": gym.spaces.Box(-np.inf, np.inf, (6, 2), np.float32)})
ACT = gym.spaces.Box(-1, 1, (2,), np.float32)


def test_paper_preset():
    sac = SACConfig()
    assert (sac.tau, sac.gamma, sac.batch_size, sac.learning_rate, sac.learning_starts) == \
        (0.005, 0.99, 256, 3e-4, 10_000)
    assert sac.use_sde and sac.use_sde_at_warmup and sac.sde_sample_freq == 64


def test_replay_buffer_sized_from_memory():
    per = transition_bytes(OBS, ACT)
    assert per == 2 * (6 * 3 * 72 * 128 + 12 * 4) + 8 + 12
    with pytest.warns(UserWarning, match="capped"):
        assert replay_capacity(OBS, ACT, 1_000_000, 0.5, available=2 * 2**30) == 2**30 // per
    assert replay_capacity(OBS, ACT, 100, 0.5, available=2 * 2**30) == 100


def test_nav_cnn_shapes_and_no_randomness():
    net = NavCNN(OBS)
    obs = {"image": torch.randint(0, 255, (2, 6, 3, 72, 128), dtype=torch.uint8).float(),
           "vector": torch.randn(2, 6, 2)}
    a, b = net(obs), net(obs)
    assert a.shape == (2, 256 + 64)
    assert torch.equal(a, b)  # no augmentation inside the policy


def small_config(run_dir, total: int) -> TrainConfig:
    sac = SACConfig(learning_starts=30, batch_size=8, buffer_size=400, image_dim=32, vector_dim=16, net_arch=(32, 32))
    return TrainConfig(run_dir=str(run_dir), total_steps=total, env_id="tests/GoalSeek-v0",
                       env_module="tests.training_envs", n_envs=2, n_actors=0, checkpoint_every=30, sac=sac)


def test_train_checkpoint_resume_and_logs(tmp_path):
    run = tmp_path / "run"
    first = train(small_config(run, 60), progress_bar=False, log_every=20)
    assert first.num_timesteps == 60
    for name in ("config.json", "scenes.json", "code_version.txt", "final.zip", "checkpoints/last.zip"):
        assert (run / name).exists(), name
    assert json.loads((run / "checkpoints/last.json").read_text())["num_timesteps"] == 60
    assert TrainConfig.load(run / "config.json").sac.net_arch == (32, 32)
    assert "env_steps_per_s" in first.history[-1]
    saved = SAC.load(run / "final.zip", device="cpu")
    obs = {k: np.stack([s.sample()] * 1) for k, s in saved.observation_space.spaces.items()}
    assert saved.predict(obs, deterministic=True)[0].shape == (1, 2)

    second = train(small_config(run, 80), resume=True, progress_bar=False, log_every=20)
    assert second.num_timesteps == 80
    events = list((run / "tb").rglob("events.out.tfevents.*"))
    assert events
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    acc = EventAccumulator(str(events[0].parent))
    acc.Reload()
    assert "time/env_steps_per_s" in acc.Tags()["scalars"]
