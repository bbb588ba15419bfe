"""SAC training on many scenes at once (stable-baselines3), with a readable outer loop.

`train(config)` does, in order:
  1. resolve the scene ids (the registry split's nested train subset) and write the run folder
     (config.json, scenes.json, code_version.txt);
  2. build the vectorised envs (Ray actors, or in-process for `n_actors=0`);
  3. size a uint8 replay buffer from free memory and build SAC with the paper's preset;
  4. learn for the budget, logging to TensorBoard (returns, env steps/s, nav metrics),
     checkpointing every `checkpoint_every` env steps, with a rich progress bar;
  5. save `final.zip`. `resume=True` continues from `checkpoints/last.zip`.
"""

from __future__ import annotations

import json
import time
import warnings
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

import gymnasium as gym
import numpy as np
import psutil
import torch as th
import torch.nn.functional as F
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.utils import polyak_update
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv

from vid2sim.envs.metrics import EpisodeRecord, sns, spl
from vid2sim.registry import Registry
from vid2sim.training.actions import check_map
from vid2sim.training.config import TrainConfig
from vid2sim.training.policy import NavCNN
from vid2sim.training.rollouts import EnvSpec, RayVecEnv, RayVecEnvConfig, specs_for_scenes
from vid2sim.versioning import code_version

NAV_METRIC_KEYS = ("is_success", "success", "spl", "cost", "sns")


def nav_metrics(info: dict) -> dict[str, float]:
    """Metrics of a finished episode: the envs' `EpisodeRecord` (moved to info["nav_episode"]) or flat keys."""
    record = info.get("nav_episode")
    if isinstance(record, EpisodeRecord):
        return {"success": float(record.success), "spl": spl(record), "cost": float(record.collision_events),
                "sns": sns(record)}
    return {k: float(info[k]) for k in NAV_METRIC_KEYS if k in info}


# ------------------------------------------------------------------ scenes and run folder
def resolve_scenes(config: TrainConfig) -> list[str]:
    """The configured scene ids, else the registry split's nested train subset of `train_scenes`."""
    if config.scene_ids:
        return list(config.scene_ids)
    if not config.registry:
        return []
    reg = Registry(config.registry)
    sizes = (config.train_scenes,) if config.train_scenes else ()
    split = reg.split(seed=config.split_seed, train_sizes=sizes)
    return list(split.train_subsets[config.train_scenes] if config.train_scenes else split.train)


def write_run_folder(config: TrainConfig) -> Path:
    run = Path(config.run_dir)
    (run / "checkpoints").mkdir(parents=True, exist_ok=True)
    config.save(run / "config.json")
    (run / "scenes.json").write_text(json.dumps({"registry": config.registry, "split_seed": config.split_seed,
                                                 "train_scenes": config.train_scenes,
                                                 "scene_ids": config.scene_ids}, indent=2))
    (run / "code_version.txt").write_text(code_version() + "\n")
    return run


def env_specs(config: TrainConfig) -> list[EnvSpec]:
    base, expert = dict(config.env_kwargs), config.sac.warmup == "expert"
    if config.registry:
        base.setdefault("registry", config.registry)
        base.setdefault("checkout_root", str(Path(config.run_dir) / "scenes"))  # bundles checked out per run
    if config.scene_ids:
        return specs_for_scenes(config.env_id, config.scene_ids, config.n_envs, base, config.seed,
                                config.env_module, stuck_steps=config.stuck_steps, expert=expert,
                                action_map=config.action_map)
    return [EnvSpec(config.env_id, base, config.seed + i, config.env_module, config.stuck_steps, expert,
                    config.action_map) for i in range(config.n_envs)]


def make_vec_env(specs: list[EnvSpec], n_actors: int) -> VecEnv:
    """Ray actors (`n_actors >= 1`, needs `ray.init`) or SB3's in-process DummyVecEnv (`0`)."""
    if n_actors <= 0:
        env = DummyVecEnv([s.make for s in specs])
        env.seed(specs[0].seed)
        return env
    return RayVecEnv(specs, RayVecEnvConfig(n_actors=n_actors, num_cpus_per_actor=1.0))


# ------------------------------------------------------------------ replay buffer
def transition_bytes(obs_space: gym.Space, action_space: gym.Space) -> int:
    """Bytes one stored transition takes (obs + next_obs in their own dtypes, action, reward, done)."""
    spaces = obs_space.spaces.values() if isinstance(obs_space, gym.spaces.Dict) else [obs_space]
    obs = sum(int(np.prod(s.shape)) * np.dtype(s.dtype).itemsize for s in spaces)
    return 2 * obs + int(np.prod(action_space.shape)) * 4 + 4 * 3


def replay_capacity(obs_space: gym.Space, action_space: gym.Space, requested: int, memory_fraction: float,
                    available: Optional[int] = None) -> int:
    """Requested capacity, capped to `memory_fraction` of the available RAM (warns when capped)."""
    available = psutil.virtual_memory().available if available is None else available
    fit = int(memory_fraction * available) // transition_bytes(obs_space, action_space)
    if fit < requested:
        warnings.warn(f"replay buffer capped at {fit} transitions ({memory_fraction:.0%} of "
                      f"{available / 2**30:.1f} GiB free); {requested} requested", stacklevel=2)
    return max(1, min(requested, fit))


# ------------------------------------------------------------------ model
class WarmupSAC(SAC):
    """SAC whose warm-up steps (`learning_starts`) can take the scripted expert's actions.

    With `warmup_expert`, every env must expose `expert_action()` (`ExpertActions` wrapper): the
    replay buffer starts with demonstrations (successes, the +10 reward) instead of uniform random
    actions. After the warm-up SAC explores with its own policy as usual; saved runs load with `SAC.load`.
    `pretrain_steps` > 0: before its first own action, the actor is fitted to the demonstrations (BC)
    while the critic learns their TD targets, so SAC starts from an expert-like actor, not a random one.
    """

    warmup_expert: bool = False
    bc_weight: float = 0.0  # > 0: behaviour-cloning actor steps on the warm-up demonstrations
    action_map: str = "clamp"  # policy -> env action mapping of the training envs (training/actions.py)
    pretrain_steps: int = 0  # > 0: that many BC actor + TD critic steps on the demonstrations before SAC acts
    pretrained: bool = False

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        if self.warmup_expert and self.pretrain_steps and not self.pretrained:
            self.bc_steps(self.pretrain_steps, batch_size, actor_rl=False)
            self.pretrained = True
        if self.warmup_expert and self.bc_weight > 0:
            self.bc_steps(gradient_steps, batch_size)
        else:
            super().train(gradient_steps, batch_size)

    def demo_batch(self, batch_size: int):
        """Warm-up demonstrations: buffer rows [0, learning_starts / n_envs) while it has not wrapped."""
        rows = min(self.learning_starts // self.n_envs, self.replay_buffer.size())
        return self.replay_buffer._get_samples(np.random.randint(0, rows, batch_size))

    def bc_steps(self, gradient_steps: int, batch_size: int, actor_rl: bool = True) -> None:
        """SAC updates with a TD3+BC-style actor loss: soft policy loss / mean |Q| + bc_weight x MSE to the
        expert's actions on a demonstration batch (keeps the actor near the expert while the critic learns).
        `actor_rl=False` (pre-training on the demonstrations): the actor minimises the MSE alone and the
        entropy coefficient stays put; the critic learns the same TD targets."""
        self.policy.set_training_mode(True)
        auto_ent = self.ent_coef_optimizer is not None  # False: a fixed ent_coef (SB3's ent_coef_tensor)
        self._update_learning_rate([self.actor.optimizer, self.critic.optimizer]
                                   + ([self.ent_coef_optimizer] if auto_ent else []))
        for _ in range(gradient_steps):
            data = self.replay_buffer.sample(batch_size)
            actions_pi, log_prob = self.actor.action_log_prob(data.observations)
            log_prob = log_prob.reshape(-1, 1)
            if auto_ent:
                ent_coef = th.exp(self.log_ent_coef.detach())
                if actor_rl:
                    ent_loss = -(self.log_ent_coef * (log_prob + self.target_entropy).detach()).mean()
                    self.ent_coef_optimizer.zero_grad()
                    ent_loss.backward()
                    self.ent_coef_optimizer.step()
            else:
                ent_coef = self.ent_coef_tensor
            with th.no_grad():
                next_actions, next_log_prob = self.actor.action_log_prob(data.next_observations)
                next_q = th.min(th.cat(self.critic_target(data.next_observations, next_actions), dim=1), dim=1,
                                keepdim=True)[0] - ent_coef * next_log_prob.reshape(-1, 1)
                target_q = data.rewards + (1 - data.dones) * self.gamma * next_q
            critic_loss = 0.5 * sum(F.mse_loss(q, target_q) for q in self.critic(data.observations, data.actions))
            self.critic.optimizer.zero_grad()
            critic_loss.backward()
            self.critic.optimizer.step()
            demo = self.demo_batch(batch_size)
            bc = F.mse_loss(self.actor(demo.observations, deterministic=True), demo.actions)
            if actor_rl:
                min_q = th.min(th.cat(self.critic(data.observations, actions_pi), dim=1), dim=1, keepdim=True)[0]
                actor_loss = (ent_coef * log_prob - min_q).mean() / min_q.abs().mean().detach().clamp(min=1.0) \
                    + self.bc_weight * bc
            else:
                actor_loss = bc
            self.actor.optimizer.zero_grad()
            actor_loss.backward()
            self.actor.optimizer.step()
            polyak_update(self.critic.parameters(), self.critic_target.parameters(), self.tau)
        self._n_updates += gradient_steps
        self.logger.record("train/bc_loss", bc.item())
        self.logger.record("train/critic_loss", critic_loss.item())

    def _sample_action(self, learning_starts: int, action_noise=None, n_envs: int = 1):
        if self.warmup_expert and self.num_timesteps < learning_starts:
            actions = np.asarray(self.env.env_method("expert_action"), np.float32)  # [n_envs, 2]
            return actions, self.policy.scale_action(actions)
        return super()._sample_action(learning_starts, action_noise, n_envs)


def policy_kwargs(config: TrainConfig, obs_space: gym.Space) -> dict[str, Any]:
    sac = config.sac
    kwargs: dict[str, Any] = {"net_arch": list(sac.net_arch)}
    if isinstance(obs_space, gym.spaces.Dict) and "image" in obs_space.spaces:
        kwargs.update(features_extractor_class=NavCNN, normalize_images=False,
                      features_extractor_kwargs={"image_dim": sac.image_dim, "vector_dim": sac.vector_dim})
    return kwargs


def ent_coef(value: str) -> str | float:
    """SB3's ent_coef argument: "auto" / "auto_X" stay strings, a number is a fixed coefficient."""
    return value if str(value).startswith("auto") else float(value)


def build_model(config: TrainConfig, env: VecEnv) -> SAC:
    sac = config.sac
    capacity = replay_capacity(env.observation_space, env.action_space, sac.buffer_size, sac.memory_fraction)
    policy = "MultiInputPolicy" if isinstance(env.observation_space, gym.spaces.Dict) else "MlpPolicy"
    model = WarmupSAC(policy, env, learning_rate=sac.learning_rate, buffer_size=capacity,
                      batch_size=sac.batch_size, tau=sac.tau, gamma=sac.gamma, ent_coef=ent_coef(sac.ent_coef),
                      learning_starts=sac.learning_starts, train_freq=sac.train_freq,
                      gradient_steps=sac.gradient_steps, use_sde=sac.use_sde, sde_sample_freq=sac.sde_sample_freq,
                      use_sde_at_warmup=sac.use_sde_at_warmup,
                      policy_kwargs=policy_kwargs(config, env.observation_space),
                      tensorboard_log=str(Path(config.run_dir) / "tb"), seed=config.seed, device="cpu", verbose=0)
    model.warmup_expert, model.bc_weight = sac.warmup == "expert", sac.bc_weight
    model.pretrain_steps, model.pretrained = sac.bc_pretrain_steps, False
    model.action_map = check_map(config.action_map)  # saved in the zip: eval and export map the same way
    return model


# ------------------------------------------------------------------ callbacks
class NavLogger(BaseCallback):
    """Episode returns, lengths and nav metrics from the env infos, plus env steps per second."""

    def __init__(self, window: int = 100, log_every: int = 1000):
        super().__init__()
        self.window, self.log_every = window, log_every
        self.episodes: deque[dict[str, float]] = deque(maxlen=window)
        self.history: list[dict[str, float]] = []

    def _on_training_start(self) -> None:
        n = self.training_env.num_envs
        self.returns, self.lengths = np.zeros(n), np.zeros(n, dtype=int)
        self.t0, self.steps0, self.last_log = time.perf_counter(), self.num_timesteps, self.num_timesteps

    def _on_step(self) -> bool:
        rewards, dones, infos = self.locals["rewards"], self.locals["dones"], self.locals["infos"]
        self.returns += rewards
        self.lengths += 1
        for i in np.flatnonzero(dones):
            ep = {"return": float(self.returns[i]), "length": float(self.lengths[i])}
            ep.update(nav_metrics(infos[i]))
            self.episodes.append(ep)
            self.returns[i], self.lengths[i] = 0.0, 0
        if self.num_timesteps - self.last_log >= self.log_every:
            self._log()
        return True

    def _log(self) -> None:
        sps = (self.num_timesteps - self.steps0) / max(time.perf_counter() - self.t0, 1e-9)
        row = {"step": float(self.num_timesteps), "env_steps_per_s": sps, "episodes": float(len(self.episodes))}
        self.logger.record("time/env_steps_per_s", sps)
        if self.episodes:
            for key in sorted({k for ep in self.episodes for k in ep}):
                value = float(np.mean([ep[key] for ep in self.episodes if key in ep]))
                row[f"ep_{key}"] = value
                self.logger.record(f"rollout/ep_{key}_mean" if key in ("return", "length") else f"nav/{key}", value)
        self.history.append(row)
        self.logger.dump(self.num_timesteps)
        self.last_log = self.num_timesteps

    def _on_training_end(self) -> None:
        self._log()


class Checkpointer(BaseCallback):
    """`checkpoints/last.zip` (+ `step_N.zip`) every `every` env steps; optional replay buffer."""

    def __init__(self, run_dir: Path, every: int, save_replay: bool):
        super().__init__()
        self.dir, self.every, self.save_replay = Path(run_dir) / "checkpoints", every, save_replay
        self.next_at = every

    def _on_training_start(self) -> None:
        self.next_at = (self.num_timesteps // self.every + 1) * self.every

    def _on_step(self) -> bool:
        if self.num_timesteps >= self.next_at:
            self.save()
            self.next_at += self.every
        return True

    def save(self) -> None:
        self.model.save(self.dir / f"step_{self.num_timesteps}.zip")
        self.model.save(self.dir / "last.zip")
        if self.save_replay:
            self.model.save_replay_buffer(self.dir / "replay.pkl")
        (self.dir / "last.json").write_text(json.dumps({"num_timesteps": self.num_timesteps}))


# ------------------------------------------------------------------ the loop
@dataclass
class TrainResult:
    run_dir: Path
    num_timesteps: int
    history: list[dict[str, float]]
    wall_s: float


def load_for_resume(run: Path, env: VecEnv) -> SAC:
    model = WarmupSAC.load(run / "checkpoints" / "last.zip", env=env, device="cpu")
    replay = run / "checkpoints" / "replay.pkl"
    if replay.exists():
        model.load_replay_buffer(replay)
    return model


def train(config: TrainConfig, resume: bool = False, progress_bar: bool = True, log_every: int = 1000) -> TrainResult:
    """Train (or resume) one SAC run; see the module docstring for the steps."""
    config.scene_ids = resolve_scenes(config)
    run = write_run_folder(config)
    env = make_vec_env(env_specs(config), config.n_actors)
    try:
        model = load_for_resume(run, env) if resume else build_model(config, env)
        done = model.num_timesteps
        logger = NavLogger(log_every=log_every)
        ckpt = Checkpointer(run, config.checkpoint_every, config.save_replay_buffer)
        t0 = time.perf_counter()
        model.learn(total_timesteps=max(0, config.total_steps - done), callback=CallbackList([logger, ckpt]),
                    reset_num_timesteps=not resume, progress_bar=progress_bar, tb_log_name="sac")
        ckpt.save()
        model.save(run / "final.zip")
        return TrainResult(run, model.num_timesteps, logger.history, time.perf_counter() - t0)
    finally:
        env.close()
