"""Held-out evaluation with the paper's protocol: test scenes x 25 trials, SR / SPL / Cost / SNS.

Each trial resets a `vid2sim/PointNav-v0` (or SocialNav) env on one test scene with a fixed seed
(trial k of every scene uses seed `seed + k`, so two policies see the same episodes), with
evaluation settings (no camera jitter, no augmentation) and 0 to 5 static obstacles. The metrics
are the envs' (`vid2sim.envs.metrics`); each mean comes with a 95 % percentile-bootstrap
confidence interval over episodes (1000 resamples, fixed seed).

Variants (the paper's): `--obstacles none|static|dynamic` (dynamic = SocialNav pedestrians),
`--variant rgb|depth|mesh-rgb` (depth oracle, mesh-RGB baseline). Policies: a training run
folder (its `final.zip` or `checkpoints/last.zip`), `random`, or `expert` (A* pure pursuit). A
trained policy's actions go through the action mapping it was trained with (`model.action_map`,
`vid2sim.training.actions`), so the env sees what the training envs saw.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Callable, Optional

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import SAC

import vid2sim.envs  # noqa: F401  (registers the env ids)
import vid2sim.training.privileged  # noqa: F401  (registers the privileged-observation env id)
from vid2sim.envs.config import EnvConfig, EpisodeConfig
from vid2sim.formats.episode_trace import read_trace, trace_path
from vid2sim.envs.expert import PurePursuitExpert
from vid2sim.envs.metrics import EpisodeRecord, outcomes, sns, sns_proximity, spl
from vid2sim.envs.obstacles import ObstacleConfig
from vid2sim.envs.recording import RecordEpisode
from vid2sim.ranges import checked
from vid2sim.registry import Registry
from vid2sim.training.actions import to_env
from vid2sim.training.ensemble import load_student
from vid2sim.training.run_files import policy_path

OBSTACLE_MODES = {"none": (0, 0), "static": (0, 5), "dynamic": (0, 5)}
METRICS = ("sr", "spl", "cost", "sns", "sns_proximity")


@checked
@dataclass
class EvalConfig:
    registry: str  # registry root
    policy: str  # run folder (SAC or distilled student), SAC .zip, student .pt, "random" or "expert"
    scene_ids: list[str] = field(default_factory=list)  # default: the split's held-out test scenes
    split_seed: int = 0  # split whose held-out test scenes are used
    trials: int = 25  # episodes per scene (the paper: 25)
    obstacles: str = "static"  # none | static | dynamic (SocialNav pedestrians)
    variant: str = "rgb"  # rgb | depth | mesh-rgb
    pedestrians: tuple[int, int] = (1, 4)  # SocialNav walkers per episode (inclusive range)
    max_steps: Optional[int] = None  # None: the env's 3000
    seed: int = 1000  # trial k of every scene uses seed + k
    checkout_root: Optional[str] = None  # where scenes are checked out (None: $VID2SIM_CHECKOUTS)
    env_id: Optional[str] = None  # default: vid2sim/PointNav-v0 (SocialNav-v0 for dynamic obstacles)
    record: int = 0  # MP4s of the first `record` trials of every scene (camera view + top-down map)
    record_dir: Optional[str] = None  # where the MP4s go (required when record > 0)
    env_kwargs: dict = field(default_factory=dict)  # extra env arguments; a run's own n_rays etc. are read
    # from its config.json (run_observation_kwargs), these override them


@dataclass
class Interval:
    mean: float
    low: float
    high: float


@dataclass
class EvalReport:
    config: dict
    episodes: int
    metrics: dict[str, Interval]
    per_scene: dict[str, dict[str, float]]
    records: list[dict]
    videos: list[str] = field(default_factory=list)  # MP4 paths (EvalConfig.record)

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2)

    @classmethod
    def from_json(cls, text: str) -> "EvalReport":
        """The report `to_json` wrote."""
        data = json.loads(text)
        data["metrics"] = {k: Interval(**v) for k, v in data["metrics"].items()}
        return cls(**data)

    def outcomes(self) -> dict[str, int]:
        """Episodes per outcome (`envs/metrics.py` `outcome`: time-outs split into pinned and free)."""
        return outcomes([EpisodeRecord.from_row(r) for r in self.records])


# ------------------------------------------------------------------ policies
Policy = Callable[[gym.Env, dict], np.ndarray]


class ObservationMismatch(ValueError):
    """A policy whose observation does not match the evaluation env's."""


def check_observation(env: gym.Env, shapes: dict[str, tuple], policy: str) -> None:
    """Raise `ObservationMismatch` (named) when the env's observation differs from the policy's."""
    space = env.observation_space
    have = {k: tuple(s.shape) for k, s in space.spaces.items()} if hasattr(space, "spaces") else {"": space.shape}
    want = {k: tuple(v) for k, v in shapes.items()}
    if have != want:
        raise ObservationMismatch(f"observation_mismatch: policy {policy} expects {want}, the env gives {have} "
                                  "(task, variant or observation arguments differ from its training)")


# env arguments that shape the observation (a run trained with them is evaluated with them)
OBSERVATION_KWARGS = ("n_rays", "fov_deg", "max_range", "ray_height", "camera")


def run_observation_kwargs(policy: str) -> dict:
    """The observation-shaping env arguments a run was trained with (its config.json), {} for other policies."""
    if policy in ("random", "expert"):
        return {}
    ckpt = policy_path(policy)
    for folder in (ckpt.parent, ckpt.parent.parent):  # RUN/final.zip or RUN/checkpoints/step_N.zip
        if (folder / "config.json").is_file():
            kwargs = json.loads((folder / "config.json").read_text()).get("env_kwargs", {})
            return {k: v for k, v in kwargs.items() if k in OBSERVATION_KWARGS}
    return {}


def load_policy(policy: str, seed: int) -> tuple[Policy, Callable[[gym.Env], None]]:
    """(act(env, obs) -> action, on_reset(env)) for a run folder, 'random' or 'expert'."""
    if policy == "random":
        rng = np.random.default_rng(seed)
        return (lambda env, obs: rng.uniform(-1, 1, 2).astype(np.float32)), (lambda env: None)
    if policy == "expert":
        expert = PurePursuitExpert()
        return (lambda env, obs: expert.act(env)), expert.reset
    path = policy_path(policy)
    if path.suffix == ".pt":
        student = load_student(path)
        checked: set[int] = set()  # envs whose observation space was compared once

        def act_student(env: gym.Env, obs: dict) -> np.ndarray:
            if id(env) not in checked:
                check_observation(env, {"image": student.image_shape, "vector": student.vector_shape}, policy)
                checked.add(id(env))
            with torch.no_grad():
                return student(torch.from_numpy(obs["image"][None]), torch.from_numpy(obs["vector"][None]))[0].numpy()
        return act_student, (lambda env: None)
    model = SAC.load(path, device="cpu")
    mapping = getattr(model, "action_map", "clamp")  # the training envs' action mapping (saved with the model)
    return (lambda env, obs: to_env(model.predict(obs, deterministic=True)[0], mapping)), (lambda env: None)


# ------------------------------------------------------------------ episodes
def eval_env_config(config: EvalConfig) -> tuple[str, EnvConfig]:
    """Env id and evaluation config: no jitter or augmentation, the obstacle mode's counts."""
    if config.obstacles not in OBSTACLE_MODES:
        raise ValueError(f"obstacles must be one of {', '.join(OBSTACLE_MODES)}, got {config.obstacles!r}")
    task = "SocialNav" if config.obstacles == "dynamic" else "PointNav"
    lo, hi = OBSTACLE_MODES[config.obstacles]
    obstacles = replace(ObstacleConfig(), min_count=lo, max_count=hi)
    episode = replace(EpisodeConfig(), pedestrians=config.pedestrians)
    env_conf = EnvConfig(variant=config.variant, training=False, episode=episode, obstacles=obstacles)
    if config.max_steps:
        env_conf = replace(env_conf, reward=replace(env_conf.reward, max_steps=config.max_steps))
    return config.env_id or f"vid2sim/{task}-v0", env_conf


def run_episode(env: gym.Env, act: Policy, on_reset: Callable, seed: int, scene_id: str) -> EpisodeRecord:
    obs, _ = env.reset(seed=seed, options={"scene_id": scene_id})
    on_reset(env)
    while True:
        obs, _, terminated, truncated, info = env.step(act(env, obs))
        if terminated or truncated:
            return info["nav_episode"]


def with_recording(env: gym.Env, config: EvalConfig) -> gym.Env:
    """`RecordEpisode` on the first `config.record` trials of every scene (named SCENE-trialK.mp4)."""
    if not config.record:
        return env
    if not config.record_dir:
        raise ValueError("record > 0 needs record_dir")
    return RecordEpisode(env, config.record_dir, episode_trigger=lambda k: k % config.trials < config.record)


def name_videos(paths: list[Path], scenes: list[str], trials: int) -> list[str]:
    """Renames RecordEpisode's `episode-K.mp4` (K counts all trials) to `SCENE-trialT.mp4`, and its
    trace to `SCENE-trialT.trace.json`."""
    out = []
    for p in paths:
        k = int(p.stem.rsplit("-", 1)[1])
        target = p.with_name(f"{scenes[k // trials]}-trial{k % trials}.mp4")
        p.replace(target)
        if trace_path(p).is_file():  # the episode's trace goes with its video
            trace = read_trace(trace_path(p))
            trace.video = target.name
            trace.write(trace_path(target))
            trace_path(p).unlink()
        out.append(str(target))
    return out


def held_out_scenes(config: EvalConfig) -> list[str]:
    if config.scene_ids:
        return list(config.scene_ids)
    return list(Registry(config.registry).split(seed=config.split_seed).test)


# ------------------------------------------------------------------ statistics
def episode_values(records: list[EpisodeRecord]) -> dict[str, np.ndarray]:
    return {"sr": np.array([float(r.success) for r in records]), "spl": np.array([spl(r) for r in records]),
            "cost": np.array([float(r.collision_events) for r in records]),
            "sns": np.array([sns(r) for r in records]), "sns_proximity": np.array([sns_proximity(r) for r in records])}


def bootstrap_means(values: np.ndarray, n: int = 1000, seed: int = 0) -> np.ndarray:
    """Means of n resamples (with replacement) of the episodes' values [E] -> [n]."""
    rng = np.random.default_rng(seed)
    return values[rng.integers(0, len(values), (n, len(values)))].mean(axis=1)


def bootstrap_ci(values: np.ndarray, n: int = 1000, level: float = 0.95, seed: int = 0) -> Interval:
    """Mean with a percentile-bootstrap interval over episodes."""
    means = bootstrap_means(values, n, seed)
    lo, hi = np.quantile(means, [(1 - level) / 2, 1 - (1 - level) / 2])
    return Interval(float(values.mean()), float(lo), float(hi))


def summarize(records: list[EpisodeRecord], scenes: list[str]) -> tuple[dict[str, Interval], dict]:
    values = episode_values(records)
    metrics = {k: bootstrap_ci(v) for k, v in values.items()}
    per_scene = {}
    for sid in sorted(set(scenes)):
        idx = [i for i, s in enumerate(scenes) if s == sid]
        per_scene[sid] = {k: float(v[idx].mean()) for k, v in values.items()}
    return metrics, per_scene


def make_eval_env(config: EvalConfig, scenes: list[str]) -> gym.Env:
    """The evaluation env over `scenes` (`eval_env_config`; the policy's observation arguments and
    `config.env_kwargs` on top)."""
    env_id, env_conf = eval_env_config(config)
    return gym.make(env_id, registry=config.registry, scenes=scenes, config=env_conf,
                    checkout_root=config.checkout_root, render_mode="rgb_array" if config.record else None,
                    **{**run_observation_kwargs(config.policy), **config.env_kwargs})


def evaluate(config: EvalConfig, progress: Optional[Callable[[int, int], None]] = None) -> EvalReport:
    """Run `trials` episodes on every test scene and aggregate the metrics with CIs."""
    scenes = held_out_scenes(config)
    if not scenes:
        raise ValueError("no test scenes: the registry split has an empty test set")
    env = with_recording(make_eval_env(config, scenes), config)
    act, on_reset = load_policy(config.policy, config.seed)
    records, scene_of = [], []
    total = len(scenes) * config.trials
    try:
        for sid in scenes:
            for k in range(config.trials):
                records.append(run_episode(env, act, on_reset, config.seed + k, sid))
                scene_of.append(sid)
                if progress:
                    progress(len(records), total)
    finally:
        env.close()
    metrics, per_scene = summarize(records, scene_of)
    rows = [{"scene_id": s, **asdict(r)} for s, r in zip(scene_of, records)]
    videos = name_videos(getattr(env, "paths", []), scenes, config.trials)
    return EvalReport(asdict(config), len(records), metrics, per_scene, rows, videos)
