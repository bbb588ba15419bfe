"""Typed configs for training runs (saved in every run folder)."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, Optional


@dataclass
class SACConfig:
    """SAC hyper-parameters; the defaults are the paper's preset (supplementary, SAC table)."""

    learning_rate: float = 3e-4
    batch_size: int = 256
    tau: float = 0.005
    gamma: float = 0.99
    learning_starts: int = 10_000
    ent_coef: str = "auto"  # SB3: "auto" (learned, starts at 1.0), "auto_X" (learned, starts at X) or "X" (fixed)
    use_sde: bool = True
    sde_sample_freq: int = 64
    use_sde_at_warmup: bool = True
    train_freq: int = 1
    gradient_steps: int = 1
    buffer_size: int = 1_000_000  # upper bound; the real capacity is sized from free memory
    memory_fraction: float = 0.5  # of the available RAM the replay buffer may take
    image_dim: int = 256
    vector_dim: int = 64
    net_arch: tuple[int, ...] = (256, 256)
    warmup: str = "random"  # actions during learning_starts: "random" (SB3; gSDE samples with use_sde_at_warmup)
    # or "expert": scripted A* demonstrations fill the replay buffer first (small-budget presets)
    bc_weight: float = 0.0  # with warmup="expert": behaviour-cloning actor steps on those demonstrations
    bc_pretrain_steps: int = 0  # with warmup="expert": gradient steps of BC (actor) + TD (critic) on the
    # demonstrations alone, once, before SAC's own actions are used (avoids starting from a random actor)


@dataclass
class TrainConfig:
    """One training run: which scenes, how many envs and actors, the budget, where to write."""

    run_dir: str
    total_steps: int
    env_id: str = "vid2sim/PointNav-v0"
    env_module: Optional[str] = "vid2sim.envs"  # imported so the env id is registered
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    registry: Optional[str] = None
    split_seed: int = 0
    train_scenes: Optional[int] = None  # size of the nested train subset; None = the whole train pool
    scene_ids: list[str] = field(default_factory=list)  # filled from the split when empty
    n_envs: int = 4
    n_actors: int = 2  # 0 = DummyVecEnv in-process (no Ray)
    seed: int = 0
    checkpoint_every: int = 10_000  # env steps
    save_replay_buffer: bool = False
    stuck_steps: Optional[int] = None  # training only: end blocked episodes as failures (training/wrappers.py)
    action_map: str = "clamp"  # policy -> env actions (training/actions.py): "clamp" (envs' contract) or "full"
    sac: SACConfig = field(default_factory=SACConfig)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "TrainConfig":
        known = {f.name for f in fields(cls)}
        d = {k: v for k, v in d.items() if k in known}
        sac = dict(d.pop("sac", {}))
        if "net_arch" in sac:
            sac["net_arch"] = tuple(sac["net_arch"])
        return cls(**d, sac=SACConfig(**sac))

    def save(self, path: Path) -> None:
        path.write_text(json.dumps(self.to_dict(), indent=2))

    @classmethod
    def load(cls, path: Path) -> "TrainConfig":
        return cls.from_dict(json.loads(Path(path).read_text()))
