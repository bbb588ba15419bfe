"""Typed configs for training runs (saved in every run folder).

Each checks its numeric fields whenever it is built, loaded included (`vid2sim.ranges`, `@checked`)."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, Optional

from vid2sim.ranges import checked
from vid2sim.training.student import StudentConfig

METHODS = ("sac", "distill")


@checked
@dataclass
class SACConfig:
    """SAC hyper-parameters; the defaults are the paper's preset (supplementary, SAC table)."""

    learning_rate: float = 3e-4  # Adam step size of actor, critic and entropy coefficient
    batch_size: int = 256  # transitions per gradient step
    tau: float = 0.005  # soft target-network update rate
    gamma: float = 0.99  # discount
    learning_starts: int = 10_000  # env steps of warm-up actions before the first update
    ent_coef: str = "auto"  # SB3: "auto" (learned, starts at 1.0), "auto_X" (learned, starts at X) or "X" (fixed)
    use_sde: bool = True  # generalised state-dependent exploration (gSDE) instead of Gaussian noise
    sde_sample_freq: int = 64  # env steps between gSDE noise-matrix resamples
    use_sde_at_warmup: bool = True  # warm-up actions from gSDE instead of uniform random
    train_freq: int = 1  # vector-env steps between updates
    gradient_steps: int = 1  # gradient steps per update
    buffer_size: int = 1_000_000  # upper bound; the real capacity is sized from free memory
    memory_fraction: float = 0.5  # of the available RAM the replay buffer may take
    image_dim: int = 256  # NavCNN image features
    vector_dim: int = 64  # NavCNN goal-vector features
    net_arch: tuple[int, ...] = (256, 256)  # hidden sizes of the actor and critic MLPs
    warmup: str = "random"  # actions during learning_starts: "random" (SB3; gSDE samples with use_sde_at_warmup)
    # or "expert": scripted A* demonstrations fill the replay buffer first (small-budget presets)
    bc_weight: float = 0.0  # with warmup="expert": behaviour-cloning actor steps on those demonstrations
    bc_pretrain_steps: int = 0  # with warmup="expert": gradient steps of BC (actor) + TD (critic) on the
    # demonstrations alone, once, before SAC's own actions are used (avoids starting from a random actor)


EVICTIONS = ("oldest", "even")  # what the distillation dataset drops over its cap (training/distill.py)


@checked
@dataclass
class DistillConfig:
    """Teacher-student distillation (DAgger, `training/distill.py`): rounds of collection and fitting."""

    steps_per_round: int = 4000  # env steps collected per round, all envs together (rounds = total_steps / this)
    beta0: float = 1.0  # probability that the teacher drives an episode in round 0 (1: behaviour cloning)
    beta_decay: float = 0.5  # the teacher's share of episodes is multiplied by this every round
    min_beta: float = 0.0  # floor of the teacher's share
    updates_per_round: int = 400  # AdamW steps on the aggregated dataset after each round (more overfit)
    batch_size: int = 128  # samples per Adam step
    learning_rate: float = 3e-4  # Adam step size
    # decoupled weight decay (AdamW) of the student's weights per unit learning rate (0.5: held-out SR 0.63
    # against 0.55 without, 3 seeds, docs/studies/pixel_distillation.md)
    weight_decay: float = 0.5
    # weight of the auxiliary clearance loss (MSE to the teacher's privileged readings over the view) when
    # the student has a clearance head (student.clearance_rays > 0)
    clearance_weight: float = 1.0
    steer_weight: float = 0.0  # a label counts 1 + this x |its steering| in the action loss (hard turns matter)
    # weight of the auxiliary depth loss (MSE to the frame's nearest depth per cell, / 5 m) when the student has
    # a depth head (student.depth_target)
    depth_weight: float = 1.0
    # weight of the route loss (MSE in m to the teacher's route ahead) when the student has a route head
    # (student.waypoints)
    waypoint_weight: float = 1.0
    # exponential moving average of the student's weights per learner step (0: off, the last weights are the
    # student); with it the average drives the student's episodes and is the final student. 0.999: held-out
    # SR 0.75 against 0.70 without, 3 seeds, un-augmented envs (docs/studies/pixel_distillation.md)
    ema_decay: float = 0.999
    shift_pad: int = 4  # random-shift augmentation, pixels at the student's input size (0: off)
    # probability that a learner sample is seen in a mirror (frames flipped left to right, steering and the
    # goal's heading negated; training/distill.py `Batch.mirrored`); 0: off. 0.5: held-out SR 0.832 against
    # 0.792 without at 128k env steps, 3 seeds, every seed ahead (docs/studies/pixel_distillation.md)
    mirror: float = 0.5
    # states before a contact's onset (in collection, whoever drives) flagged hard in the round's data (0: none)
    hard_steps: int = 10
    # share of each learner batch drawn from the flagged states (0: uniform batches, the recipe at the bar)
    hard_fraction: float = 0.0
    # share of each env's episodes whose scene is drawn in proportion to the student's recent failure rate
    # there, the rest uniform over the env's scenes (training/scene_priority.py; 0: uniform, the default)
    scene_priority: float = 0.0
    max_samples: int = 150_000  # dataset cap in labelled states
    eviction: str = "oldest"  # over the cap: "oldest" drops whole rounds, "even" thins every round alike
    drop_stuck: bool = True  # drop the teacher's blocked-pose recovery labels (full lock, history-dependent)
    # m the teacher's route keeps from blocked cells where there is room (the training envs'
    # EpisodeConfig.expert_comfort, envs/planning.py; 0: the shortest route, which grazes the 0.45 m
    # clearance in every bend): a student that strays from a route down the middle still has room
    teacher_comfort: float = 0.8
    # m off its path at which the teacher re-plans from the robot's position (training/wrappers.py
    # `TeacherLabels`; 0: at every state, so a label depends on the state alone; inf: never). 0: the
    # recipe of every student at the bar (0.3 gave the same held-out SR at 64k env steps, 3 seeds)
    teacher_replan: float = 0.0
    # m ahead on its route the teacher's pure pursuit aims (envs/expert.py `ExpertConfig.lookahead`): the
    # steering gain falls with its square, so a longer one labels small offsets from the route with gentler turns
    teacher_lookahead: float = 1.0
    # the training envs' per-episode image augmentation (exposure, tint, fog, rain, snow; envs/augment.py).
    # Off: held-out SR 0.70 against 0.63 with it, 3 seeds (docs/studies/pixel_distillation.md); the
    # evaluation protocol renders without it. Env arguments given (`env_kwargs["augment"]`) win.
    augment: bool = False
    train_max_steps: int = 500  # episode limit while collecting (truncation); evaluation keeps the env's 3000
    # torch and numba threads of the learner and its in-process envs (0: the libraries' defaults, one per
    # core). 1: the fit costs 1.2-1.5x and the collection 1.0-1.4x fewer CPU-seconds than on two threads,
    # the collection no slower (benchmarks/distill_cost.py)
    threads: int = 1
    student: StudentConfig = field(default_factory=StudentConfig)

    def __post_init__(self) -> None:
        if isinstance(self.student, dict):
            self.student = StudentConfig(**self.student)
        if self.eviction not in EVICTIONS:
            raise ValueError(f"DistillConfig.eviction: {self.eviction!r} is not one of {EVICTIONS}")
        if not 0.0 <= self.mirror <= 1.0:
            raise ValueError(f"DistillConfig.mirror: {self.mirror} is not a probability in [0, 1]")
        if not 0.0 <= self.scene_priority <= 1.0:
            raise ValueError(f"DistillConfig.scene_priority: {self.scene_priority} is not a share in [0, 1]")


@checked
@dataclass
class TrainConfig:
    """One training run: which scenes, how many envs and actors, the budget, where to write."""

    run_dir: str  # run folder (config, scenes, checkpoints, TensorBoard)
    total_steps: int  # env-step budget of the run
    env_id: str = "vid2sim/PointNav-v0"  # Gymnasium id of the training envs
    env_module: Optional[str] = "vid2sim.envs"  # imported so the env id is registered
    env_kwargs: dict[str, Any] = field(default_factory=dict)  # extra env arguments (variant, training, ...)
    registry: Optional[str] = None  # registry root the scenes come from
    split_seed: int = 0  # seed of the registry's train/test split
    train_scenes: Optional[int] = None  # size of the nested train subset; None = the whole train pool
    scene_ids: list[str] = field(default_factory=list)  # filled from the split when empty
    n_envs: int = 4  # parallel environments
    n_actors: int = 2  # 0 = DummyVecEnv in-process (no Ray)
    seed: int = 0  # seed of the envs (env i: seed + i), the networks and the learner
    checkpoint_every: int = 10_000  # env steps between SAC checkpoints
    save_replay_buffer: bool = False  # SAC: also save the replay buffer with each checkpoint (resume exactly)
    stuck_steps: Optional[int] = None  # training only: end blocked episodes as failures (training/wrappers.py)
    action_map: str = "clamp"  # policy -> env actions (training/actions.py): "clamp" (envs' contract) or "full"
    sac: SACConfig = field(default_factory=SACConfig)
    method: str = "sac"  # "sac" (training/sac.py) or "distill" (pixel student from the A* teacher, training/distill.py)
    distill: DistillConfig = field(default_factory=DistillConfig)

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "TrainConfig":
        known = {f.name for f in fields(cls)}
        d = {k: v for k, v in d.items() if k in known}
        sac = dict(d.pop("sac", {}))
        if "net_arch" in sac:
            sac["net_arch"] = tuple(sac["net_arch"])
        distill = dict(d.pop("distill", {}))
        # runs recorded before these settings: the shortest route, plain Adam, augmented images, the last weights
        if distill:
            distill.setdefault("teacher_comfort", 0.0)
            distill.setdefault("weight_decay", 0.0)
            distill.setdefault("augment", True)
            distill.setdefault("ema_decay", 0.0)
        return cls(**d, sac=SACConfig(**sac), distill=DistillConfig(**distill))

    def save(self, path: Path) -> None:
        path.write_text(json.dumps(self.to_dict(), indent=2))

    @classmethod
    def load(cls, path: Path) -> "TrainConfig":
        return cls.from_dict(json.loads(Path(path).read_text()))
