"""Teacher-student distillation (DAgger) of the pixel policy from the scripted A* expert.

The student (`training/student.py`) sees exactly the deployable observation: camera frames and
the goal vector. The teacher (`envs/expert.py`, pure pursuit on the episode's A* path around the
obstacles, with its walkable-map arc check) sees the map and the path; its route keeps
`teacher_comfort` m from blocked cells where there is room (the training envs'
`EpisodeConfig.expert_comfort`), so the labels steer a student that strayed back towards the
middle before it touches a facade or a pole. `train_distill(config)`
does, in order:
  1. resolve the scene ids (the registry split's nested train subset) and write the run folder
     (config.json, scenes.json, code_version.txt, student.json);
  2. build the envs with `TeacherLabels` (the teacher labels every state, whoever drives) on Ray
     actors (`n_actors >= 1`) or in-process; the scenes are dealt to the envs in groups;
  3. for each round k: collect `steps_per_round` env steps; each episode is driven by the
     teacher with probability beta_k = max(min_beta, beta0 * beta_decay^k), else by the student
     (DAgger: beta_0 = 1 is behaviour cloning); every visited state goes into the dataset with
     the teacher's label, except the teacher's blocked-pose recovery labels (`drop_stuck`); the states
     of the `hard_steps` steps before each contact's onset are flagged hard; with `scene_priority` > 0 a
     share of each env's episodes go to its scenes in proportion to the student's recent failure rate
     there (`training/scene_priority.py`);
  4. fit the student on the aggregated dataset: `updates_per_round` AdamW steps of MSE to the
     labels (optionally weighted towards hard turns, `steer_weight`, or with a share of each batch
     drawn from the states that led into a contact, `hard_fraction`), on batches with random-shift
     augmentation (DrQ) and optionally mirrored samples (`mirror`: the flipped frames with the
     steering and the goal's heading negated), warm-started from the last round;
     a student with a clearance head (`StudentConfig.clearance_rays` K > 0) also regresses the
     teacher's privileged clearance over the view (K ray ranges, `TeacherLabels`), an auxiliary
     target that asks the encoder to see how far away what it faces is (`clearance_weight`); one with
     a route head (`StudentConfig.waypoints` K > 0) regresses the teacher's route ahead (K points,
     `TeacherLabels`; `waypoint_weight`), which it can also drive by (`StudentConfig.drive_waypoints`);
  5. write the round's data shard (data/round_K.npz, written once) and checkpoints/last.pt (student,
     optimizer, round, history), log to TensorBoard (tb/) and to the returned history.
With `ema_decay` > 0 an exponential moving average of the student's weights (updated after every
learner step) drives the student's episodes and is the final student: the last weights of a round
move with its batches, the average does not.
Resume (`resume=True`) reloads the shards and checkpoints/last.pt and goes on at the next round.
The final student is RUN/student.pt; `vid2sim eval policy --policy RUN` and `export_policy` read it.

`imitation`'s DAgger is not used: its releases pin gymnasium ~0.29 and stable-baselines3 ~2.2,
older than this project's gymnasium 1.4 / SB3 2.9 (and its trainer drives one env in-process).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Optional, Sequence, Union

import numpy as np
import torch
import torch.nn.functional as F
from stable_baselines3.common.vec_env import VecEnv
from torch.optim.swa_utils import AveragedModel
from torch.utils.tensorboard import SummaryWriter

from vid2sim.threads import thread_pools
from vid2sim.training.config import EVICTIONS, DistillConfig, TrainConfig
from vid2sim.training.rollouts import EnvSpec
from vid2sim.training.sac import TrainResult, make_vec_env, resolve_scenes, write_run_folder
from vid2sim.training.scene_priority import ScenePriority
from vid2sim.training.student import StudentPolicy, random_shift, two_hot

STUDENT_NAME = "student.pt"


class DistillError(ValueError):
    """A distillation run that cannot start (named reason first)."""


DEPTH_GRID = (9, 16)  # blocks of the 72 x 128 frame the teacher's depth target is stored in (8 x 8 px each)
# the auxiliary targets' Batch fields: what their per-state shape holds, and the error when rounds differ
AUX_TARGETS = {"clearance": ("clearance rays", "clearance_mismatch"), "depth": ("depth targets", "depth_mismatch"),
               "waypoints": ("route points", "waypoint_mismatch")}


@dataclass
class Batch:
    """Labelled states of one round: preprocessed frames, goal vectors, teacher actions and (with
    the auxiliary targets) the teacher's clearance readings, the frame's blocked depth and the
    teacher's route ahead. Methods go over every field (`by_name`), so a new field needs only its
    declaration, its default in `__post_init__` and, if it has one, its mirror."""

    frames: np.ndarray  # uint8 [N, frames, C, h, w]
    vectors: np.ndarray  # float32 [N, 6, 2]
    actions: np.ndarray  # float32 [N, 2]
    clearance: Optional[np.ndarray] = None  # float32 [N, K] in [0, 1]; [N, 0] without the target
    depth: Optional[np.ndarray] = None  # uint8 [N, 9, 16] nearest depth / 5 m x 255; [N, 0, 0] without
    # bool [N]: the state is one of the `DistillConfig.hard_steps` states before a contact began (the
    # learner draws `hard_fraction` of each batch from these); all False in shards written before it
    hard: Optional[np.ndarray] = None
    # float32 [N, K, 2]: the teacher's route ahead in the robot's frame (m); [N, 0, 2] without the target
    waypoints: Optional[np.ndarray] = None

    def __post_init__(self) -> None:
        if self.clearance is None:
            self.clearance = np.zeros((len(self.actions), 0), np.float32)
        if self.depth is None:
            self.depth = np.zeros((len(self.actions), 0, 0), np.uint8)
        if self.hard is None:
            self.hard = np.zeros(len(self.actions), bool)
        if self.waypoints is None:
            self.waypoints = np.zeros((len(self.actions), 0, 2), np.float32)

    def by_name(self) -> dict[str, np.ndarray]:
        """Every field by name, in field order."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def save(self, path: Path) -> None:
        np.savez(path, **self.by_name())

    @classmethod
    def load(cls, path: Path) -> "Batch":
        with np.load(path) as z:  # shards written before the auxiliary targets and the hard flags have none
            return cls(**{f.name: z[f.name] if f.name in z else None for f in fields(cls)})

    def take(self, idx: np.ndarray) -> "Batch":
        """Rows idx of every field."""
        return Batch(**{k: a[idx] for k, a in self.by_name().items()})

    def mirrored(self, rows: np.ndarray) -> "Batch":
        """A copy in which the states `rows` (bool [N]) are seen in a mirror (`mirror_rows`)."""
        return Batch(**{k: a.copy() for k, a in self.by_name().items()}).mirror_rows(rows)

    def mirror_rows(self, rows: np.ndarray) -> "Batch":
        """The states `rows` (bool [N]) seen in a mirror, in place -> self: frames, clearance rays and
        depth cells flipped left to right, the goal's heading, the teacher's steering and its route's
        lateral offsets negated
        (the camera's principal point is the image centre, so a mirrored frame is the view of the
        mirrored street from the mirrored pose, and its label is the mirrored label)."""
        self.frames[rows] = self.frames[rows][..., ::-1]  # [n, F, C, h, w] flipped along w
        self.vectors[rows, :, 1] *= -1.0  # heading to the goal / pi
        self.actions[rows, 1] *= -1.0  # steering (+ turns left)
        self.clearance[rows] = self.clearance[rows][:, ::-1]  # rays ordered across the view
        self.depth[rows] = self.depth[rows][..., ::-1]  # [n, 9, 16] cells flipped along the columns
        self.waypoints[rows, :, 1] *= -1.0  # y (left) of each route point
        return self


class Dataset:
    """The aggregated DAgger dataset, capped at `max_samples` labelled states.

    Over the cap, `eviction="oldest"` drops whole rounds, oldest first (the teacher-driven early
    rounds go first); `"even"` thins every round to the same fraction, evenly spaced in time, so
    each round keeps a share proportional to its size (what a reservoir keeps, without chance)."""

    def __init__(self, max_samples: int, eviction: str = "oldest") -> None:
        if eviction not in EVICTIONS:
            raise DistillError(f"bad_eviction: eviction must be one of {EVICTIONS}, got {eviction!r}")
        self.max_samples, self.eviction = max_samples, eviction
        self.parts: list[Batch] = []
        self.seen: list[int] = []  # rows each part had when added

    def add(self, batch: Batch) -> None:
        if len(batch.actions):
            self.parts.append(batch)
            self.seen.append(len(batch.actions))
        if self.eviction == "even":
            self._thin_evenly()
            return
        while len(self.parts) > 1 and len(self) - len(self.parts[0].actions) >= self.max_samples:
            self.parts.pop(0)
            self.seen.pop(0)

    def _thin_evenly(self) -> None:
        if len(self) <= self.max_samples:
            return
        keep = apportion(self.max_samples, self.seen)
        self.parts = [thin(p, k) for p, k in zip(self.parts, keep)]

    def __len__(self) -> int:
        return sum(len(p.actions) for p in self.parts)

    def rows(self) -> int:
        """How many labelled states the learner samples from: the newest ones, at most the cap."""
        return min(len(self), self.max_samples)

    def gather(self, idx: np.ndarray) -> Batch:
        """Rows idx [B] (0 <= idx < rows(), in time order) copied out of the parts, without
        concatenating the whole dataset (150k states of 2 frames are ~2 GB)."""
        if not self.parts:
            raise DistillError("no_labels: the dataset is empty (every label of the rounds so far was dropped)")
        starts = np.cumsum([0] + [len(p.actions) for p in self.parts])  # [P + 1]
        rows = np.asarray(idx, np.int64) + (len(self) - self.rows())  # [B] rows of the concatenation
        part = np.searchsorted(starts, rows, side="right") - 1  # [B]
        out = Batch(**{k: np.empty((len(rows), *a.shape[1:]), a.dtype) for k, a in self.parts[0].by_name().items()})
        for j in np.unique(part):
            hit = part == j
            local = rows[hit] - starts[j]
            src = self.parts[j]
            for name, (what, error) in AUX_TARGETS.items():
                have, want = getattr(src, name).shape[1:], getattr(out, name).shape[1:]
                if have != want:
                    raise DistillError(f"{error}: round data with {what} {have} and {want} cannot be mixed")
            for k, a in src.by_name().items():
                getattr(out, k)[hit] = a[local]
        return out

    def hard_rows(self) -> np.ndarray:
        """Indices [H] (into 0 .. rows()) of the sampled states flagged hard (`Batch.hard`)."""
        if not self.parts:
            return np.zeros(0, np.int64)
        flags = np.concatenate([p.hard for p in self.parts])[len(self) - self.rows():]  # [rows()]
        return np.flatnonzero(flags)

    def arrays(self) -> Batch:
        """The whole sampled range as one Batch (a copy; for inspection and tests)."""
        return self.gather(np.arange(self.rows()))


def apportion(total: int, sizes: Sequence[int]) -> list[int]:
    """`total` split in proportion to `sizes` (largest remainders round up; sums to `total`)."""
    exact = np.asarray(sizes, np.float64) * total / max(sum(sizes), 1)
    share = np.floor(exact).astype(np.int64)
    share[np.argsort(share - exact, kind="stable")[: total - int(share.sum())]] += 1
    return share.tolist()


def thin(batch: Batch, keep: int) -> Batch:
    """`keep` rows of `batch`, evenly spaced over it."""
    n = len(batch.actions)
    if keep >= n:
        return batch
    idx = np.linspace(0, n - 1, keep).round().astype(np.int64) if keep > 0 else np.zeros(0, np.int64)
    return batch.take(idx)


# ------------------------------------------------------------------ set-up
def beta(config: TrainConfig, round_index: int) -> float:
    d = config.distill
    return max(d.min_beta, d.beta0 * d.beta_decay ** round_index)


def scene_groups(scene_ids: Sequence[str], n_envs: int) -> list[list[str]]:
    """Scenes dealt to `n_envs` envs: env i gets scenes i, i + n, i + 2n, ... (all scenes used when
    there are more scenes than envs; with fewer, they repeat round-robin)."""
    if not scene_ids:
        raise DistillError("no_scenes: the run has no training scenes (empty registry split?)")
    if len(scene_ids) <= n_envs:
        return [[scene_ids[i % len(scene_ids)]] for i in range(n_envs)]
    return [list(scene_ids[i::n_envs]) for i in range(n_envs)]


def env_specs(config: TrainConfig) -> list[EnvSpec]:
    base = dict(config.env_kwargs)
    base.setdefault("registry", config.registry)
    base.setdefault("checkout_root", str(Path(config.run_dir) / "scenes"))
    if config.distill.train_max_steps:
        base.setdefault("max_episode_steps", config.distill.train_max_steps)
    episode = base.get("episode", {})
    if config.distill.teacher_comfort > 0 and isinstance(episode, dict):  # env arguments given win
        base["episode"] = {"expert_comfort": config.distill.teacher_comfort, **episode}
    augment = base.get("augment", {})
    if isinstance(augment, dict):
        base["augment"] = {"enabled": config.distill.augment, **augment}
    rays = config.distill.student.clearance_rays
    grid = DEPTH_GRID if config.distill.student.depth_target else None
    return [EnvSpec(config.env_id, {**base, "scenes": group}, config.seed + i, config.env_module,
                    config.stuck_steps, teacher=True, teacher_clearance_rays=rays, teacher_depth_grid=grid,
                    teacher_replan=config.distill.teacher_replan, teacher_lookahead=config.distill.teacher_lookahead,
                    teacher_waypoints=config.distill.student.waypoints)
            for i, group in enumerate(scene_groups(config.scene_ids, config.n_envs))]


# ------------------------------------------------------------------ collection
@dataclass
class RoundStats:
    steps: int = 0
    labels: int = 0
    dropped_stuck: int = 0
    hard: int = 0  # labelled states flagged hard (before a contact began)
    # per driver ("teacher", "student"): the round's finished episodes as (scene id, success)
    episodes: dict[str, list[tuple[str, bool]]] = field(default_factory=lambda: {"teacher": [], "student": []})
    wall_s: float = 0.0

    def success_rate(self, driver: str) -> Optional[float]:
        """Success rate of the round's finished episodes driven by `driver` (None: none finished)."""
        ends = self.episodes[driver]
        return float(np.mean([success for _, success in ends])) if ends else None


class Collector:
    """Steps a VecEnv of `TeacherLabels` envs, choosing the driver per episode; keeps the labelled states."""

    def __init__(self, env: VecEnv, student: StudentPolicy, seed: int) -> None:
        self.env, self.student = env, student
        self.rng = np.random.default_rng(seed)
        self.obs = env.reset()
        self.labels = [dict(info) for info in env.reset_infos]
        self.teacher_drives = np.ones(env.num_envs, bool)
        self.episode_steps = np.zeros(env.num_envs, np.int64)  # steps of each env's current episode so far
        self.in_contact = np.zeros(env.num_envs, bool)  # the env's last step ended in contact

    def _check_labels(self) -> None:
        missing = [i for i, info in enumerate(self.labels) if "teacher_action" not in info]
        if missing:
            raise DistillError(f"teacher_unavailable: envs {missing} returned no teacher label")

    def collect(self, n_steps: int, beta_k: float, drop_stuck: bool,
                hard_steps: int = 0) -> tuple[Batch, RoundStats]:
        """`n_steps` env steps (all envs together) -> their labelled states and the round's figures; with
        `hard_steps` > 0 the states of the last `hard_steps` steps (of this round and episode) before each
        contact's onset are flagged hard (`Batch.hard`)."""
        stats, t0 = RoundStats(), time.perf_counter()
        self._check_labels()
        self.teacher_drives = self.rng.random(self.env.num_envs) < beta_k  # a new round redraws the drivers
        frames, vectors, actions, clearance, depth, keeps, hard, route = [], [], [], [], [], [], [], []
        for t in range(max(1, n_steps // self.env.num_envs)):
            teacher = np.stack([np.asarray(info["teacher_action"], np.float32) for info in self.labels])
            seen = np.stack([np.asarray(info.get("teacher_clearance", ()), np.float32) for info in self.labels])
            near = np.stack([np.asarray(info.get("teacher_depth", np.zeros((0, 0))), np.uint8) for info in self.labels])
            ahead = np.stack([np.asarray(info.get("teacher_waypoints", np.zeros((0, 2))), np.float32)
                              for info in self.labels])
            stuck = np.array([bool(info.get("teacher_stuck", False)) for info in self.labels])
            with torch.no_grad():
                image = torch.from_numpy(self.obs["image"])
                pre = self.student.preprocess(image)
                student = self.student.act(pre, torch.from_numpy(self.obs["vector"])).numpy()
            keep = ~stuck if drop_stuck else np.ones(len(stuck), bool)
            frames.append(pre.numpy().astype(np.uint8)[keep])
            vectors.append(self.obs["vector"][keep].astype(np.float32))
            actions.append(teacher[keep])
            clearance.append(seen[keep])  # [n, K]; [n, 0] without the target
            depth.append(near[keep])  # [n, 9, 16]; [n, 0, 0] without the target
            route.append(ahead[keep])  # [n, K, 2]; [n, 0, 2] without the target
            stats.dropped_stuck += int((~keep).sum())
            keeps.append(keep)
            hard.append(np.zeros(self.env.num_envs, bool))  # [n_envs], set back in time below
            act = np.where(self.teacher_drives[:, None], teacher, student).astype(np.float32)
            self.obs, _, dones, infos = self.env.step(act)
            stats.steps += self.env.num_envs
            self.episode_steps += 1
            for i, info in enumerate(infos):
                contact = bool(info.get("collided", False))
                if hard_steps > 0 and contact and not self.in_contact[i]:  # this step's state led into a contact
                    back = int(min(hard_steps, self.episode_steps[i], t + 1))
                    for step_flags in hard[t + 1 - back:t + 1]:
                        step_flags[i] = True
                self.in_contact[i] = contact and not dones[i]
                if dones[i]:
                    self.episode_steps[i] = 0
                    driver = "teacher" if self.teacher_drives[i] else "student"
                    stats.episodes[driver].append((str(info.get("scene_id", "")), info.get("end") == "success"))
                    self.teacher_drives[i] = self.rng.random() < beta_k
                    self.labels[i] = dict(self.env.reset_infos[i])
                else:
                    self.labels[i] = info
            self._check_labels()
        flags = np.concatenate([h[k] for h, k in zip(hard, keeps)])  # [N] the kept states' flags
        batch = Batch(*(np.concatenate(a) for a in (frames, vectors, actions, clearance, depth)), flags,
                      np.concatenate(route))
        stats.labels, stats.hard, stats.wall_s = len(batch.actions), int(flags.sum()), time.perf_counter() - t0
        return batch, stats


# ------------------------------------------------------------------ learning
def action_loss(predicted: torch.Tensor, labels: torch.Tensor, steer_weight: float = 0.0,
                steer_logits: Optional[torch.Tensor] = None) -> torch.Tensor:
    """MSE of actions [B, 2] to the teacher's labels [B, 2]; with steering bins (`steer_logits`
    [B, K]) the steering term is instead the cross-entropy to the label's two-hot distribution
    (`student.two_hot`). With steer_weight w > 0 each sample counts 1 + w |label steering|,
    normalised by the weights' sum, so the hard turns that avoid a contact are not averaged away
    by the many straight-ahead states."""
    if steer_logits is None:
        per_sample = (predicted - labels).square().mean(dim=1)  # [B]
    else:
        target = two_hot(labels[:, 1], steer_logits.shape[1])  # [B, K]
        steer_ce = -(target * torch.log_softmax(steer_logits, dim=1)).sum(dim=1)  # [B]
        per_sample = 0.5 * ((predicted[:, 0] - labels[:, 0]).square() + steer_ce)  # [B]
    if steer_weight <= 0:
        return per_sample.mean()
    weights = 1.0 + steer_weight * labels[:, 1].abs()  # [B]
    return (weights * per_sample).sum() / weights.sum()


def fit(student: StudentPolicy, optimizer: torch.optim.Optimizer, data: Union[Dataset, Batch],
        conf: DistillConfig, rng: np.random.Generator, averaged: Optional[AveragedModel] = None) -> dict[str, float]:
    """`conf.updates_per_round` AdamW steps of `action_loss` to the teacher's labels on batches of
    `conf.batch_size`, random-shifted by `conf.shift_pad`, drawn uniformly from `data` (a Dataset,
    sampled in place, or one Batch; with `conf.hard_fraction` > 0 that share of each batch is drawn
    from the states flagged hard, `Batch.hard`, where there are any), each sample seen in a mirror
    with probability `conf.mirror`
    (`Batch.mirrored`); a student with a clearance head also regresses the teacher's
    clearance readings, that loss weighted by `conf.clearance_weight`, and one with a depth head the
    frame's blocked depth (`depth_loss`), weighted by `conf.depth_weight`, and one with a route head the
    teacher's route ahead (MSE in m), weighted by `conf.waypoint_weight`; `conf.steer_weight`: see
    `action_loss`. `averaged` (an exponential moving average of the student's weights,
    `conf.ema_decay`) is updated after every step. Returns the mean squared error of the actions to
    the labels (whatever the steering head) and the auxiliary losses, over the last tenth of the
    updates."""
    updates, batch_size = conf.updates_per_round, conf.batch_size
    student.train()
    data = data if isinstance(data, Dataset) else _one_part(data)
    aux = student.clearance_head is not None and conf.clearance_weight > 0
    with_depth = student.depth_head is not None and conf.depth_weight > 0
    with_route = student.waypoint_head is not None and conf.waypoint_weight > 0
    n, losses, aux_losses, depth_losses, t0 = data.rows(), [], [], [], time.perf_counter()
    route_losses = []
    hard = data.hard_rows() if conf.hard_fraction > 0 else np.zeros(0, np.int64)  # [H]
    n_hard = int(round(conf.hard_fraction * batch_size)) if len(hard) else 0
    gen = torch.Generator().manual_seed(int(rng.integers(2**31)))
    for _ in range(updates):
        picks = rng.integers(0, n, batch_size - n_hard)  # [B - n_hard] uniform
        if n_hard:
            picks = np.concatenate([picks, hard[rng.integers(0, len(hard), n_hard)]])  # [B]
        batch = data.gather(picks)
        if conf.mirror > 0:  # the gathered batch is a fresh copy: mirrored in place
            batch.mirror_rows(rng.random(batch_size) < conf.mirror)
        x = random_shift(torch.from_numpy(batch.frames).float(), conf.shift_pad, gen)
        pred = student.outputs(x, torch.from_numpy(batch.vectors))
        labels = torch.from_numpy(batch.actions)
        loss = action_loss(pred.actions, labels, conf.steer_weight, pred.steer_logits)
        losses.append((pred.actions.detach() - labels).square().mean().item())  # comparable over heads
        clearance = pred.clearance
        if aux:
            if batch.clearance.shape[1] != clearance.shape[1]:
                raise DistillError(f"clearance_mismatch: the student predicts {clearance.shape[1]} clearance rays, "
                                   f"the data holds {batch.clearance.shape[1]}")
            aux_loss = F.mse_loss(clearance, torch.from_numpy(batch.clearance))
            aux_losses.append(aux_loss.item())
            loss = loss + conf.clearance_weight * aux_loss
        if with_depth:
            near = depth_loss(pred.depth, batch.depth)
            depth_losses.append(near.item())
            loss = loss + conf.depth_weight * near
        if with_route:
            if batch.waypoints.shape[1] != pred.waypoints.shape[1]:
                raise DistillError(f"waypoint_mismatch: the student predicts {pred.waypoints.shape[1]} route points, "
                                   f"the data holds {batch.waypoints.shape[1]}")
            ahead = F.mse_loss(pred.waypoints, torch.from_numpy(batch.waypoints))
            route_losses.append(ahead.item())
            loss = loss + conf.waypoint_weight * ahead
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        if averaged is not None:
            averaged.update_parameters(student)
    student.eval()
    wall, tail = time.perf_counter() - t0, max(1, updates // 10)
    out = {"loss": float(np.mean(losses[-tail:])), "fit_s": wall,
           "samples_per_s": updates * batch_size / max(wall, 1e-9)}
    if aux:
        out["clearance_loss"] = float(np.mean(aux_losses[-tail:]))
    if with_depth:
        out["depth_loss"] = float(np.mean(depth_losses[-tail:]))
    if with_route:
        out["waypoint_loss"] = float(np.mean(route_losses[-tail:]))
    return out


def depth_loss(predicted: torch.Tensor, stored: np.ndarray) -> torch.Tensor:
    """MSE of the depth head [B, h', w'] (in [0, 1]) to the stored blocked depth uint8 [B, 9, 16], min-pooled to
    the head's map (nearest stays nearest)."""
    if stored.ndim != 3 or stored.shape[1] == 0:
        raise DistillError("depth_mismatch: the student has a depth head, the data holds no depth target "
                           "(rounds collected without it)")
    target = torch.from_numpy(stored).float()[:, None] / 255.0  # [B, 1, 9, 16]
    target = -F.adaptive_max_pool2d(-target, predicted.shape[1:])[:, 0]  # [B, h', w']
    return F.mse_loss(predicted, target)


def _one_part(batch: Batch) -> Dataset:
    data = Dataset(max(len(batch.actions), 1))
    data.add(batch)
    return data


# ------------------------------------------------------------------ the loop
def make_student(config: TrainConfig, env: VecEnv) -> StudentPolicy:
    """A fresh student for the env's observation (with `drive_waypoints`, its config takes the env's robot
    for its pure pursuit)."""
    space = env.observation_space
    if not hasattr(space, "spaces") or "image" not in space.spaces:
        raise DistillError(f"observation_mismatch: the student needs the Dict image + vector observation, "
                           f"env {config.env_id} gives {space}")
    student_config = config.distill.student
    if student_config.drive_waypoints:  # its pure pursuit steers the env's robot, as the teacher's does
        robot = env.get_attr("config", indices=[0])[0].robot
        student_config = replace(student_config, wheelbase=robot.wheelbase, max_steer_deg=robot.max_steer_deg)
    torch.manual_seed(config.seed)
    return StudentPolicy(student_config, space["image"].shape, space["vector"].shape).eval()


def make_optimizer(student: StudentPolicy, d: DistillConfig, state: Optional[dict] = None) -> torch.optim.Optimizer:
    """AdamW at the run's learning rate and decoupled weight decay; `state`: a checkpoint's optimizer
    state, whose moments are kept while the config's weight decay applies (runs saved before the
    setting existed used plain Adam, the same as a decay of 0)."""
    optimizer = torch.optim.AdamW(student.parameters(), lr=d.learning_rate, weight_decay=d.weight_decay)
    if state is not None:
        optimizer.load_state_dict(state)
        for group in optimizer.param_groups:
            group.update(lr=d.learning_rate, weight_decay=d.weight_decay, decoupled_weight_decay=True)
    return optimizer


def ema_decay_at(decay: float, n_averaged: int) -> float:
    """The average's decay after `n_averaged` updates: min(decay, (1 + n) / (10 + n)), so it follows the
    young student closely (no lag behind the first rounds' weights) and averages over ~1 / (1 - decay)
    learner steps once trained (the warm-up of TensorFlow's ExponentialMovingAverage)."""
    return min(decay, (1.0 + n_averaged) / (10.0 + n_averaged))


def make_averaged(student: StudentPolicy, decay: float, state: Optional[dict] = None) -> Optional[AveragedModel]:
    """The exponential moving average of the student's weights (None when `decay` is 0): it drives the
    student's episodes and is the run's final student; `state`: a checkpoint's."""
    if decay <= 0:
        return None

    def average(mean: torch.Tensor, current: torch.Tensor, n_averaged: torch.Tensor) -> torch.Tensor:
        d = ema_decay_at(decay, int(n_averaged))
        return d * mean + (1.0 - d) * current

    averaged = AveragedModel(student, avg_fn=average, use_buffers=True)
    if state is not None:
        averaged.load_state_dict(state)
    return averaged.eval()


def save_checkpoint(run: Path, student: StudentPolicy, optimizer: torch.optim.Optimizer, round_index: int,
                    num_timesteps: int, history: list[dict], rng: np.random.Generator,
                    averaged: Optional[AveragedModel] = None, priority: Optional[ScenePriority] = None) -> None:
    ckpt = {"student": student.checkpoint(), "optimizer": optimizer.state_dict(), "round": round_index,
            "num_timesteps": num_timesteps, "history": history, "rng": rng.bit_generator.state,
            "averaged": averaged.state_dict() if averaged is not None else None,
            "scene_priority": priority.state_dict() if priority is not None else None}
    tmp = run / "checkpoints" / "last.pt.tmp"
    torch.save(ckpt, tmp)
    tmp.replace(run / "checkpoints" / "last.pt")


def load_checkpoint(run: Path) -> dict:
    path = run / "checkpoints" / "last.pt"
    if not path.is_file():
        raise DistillError(f"no_checkpoint: cannot resume {run}: {path} does not exist")
    return torch.load(path, map_location="cpu", weights_only=False)


def train_distill(config: TrainConfig, resume: bool = False, log: Optional[Any] = None) -> TrainResult:
    """Train (or resume) one distillation run, on `config.distill.threads` threads; see the module
    docstring for the steps."""
    with thread_pools(config.distill.threads):
        return _train_rounds(config, resume, log)


def _train_rounds(config: TrainConfig, resume: bool, log: Optional[Any]) -> TrainResult:
    d = config.distill
    config.scene_ids = resolve_scenes(config)
    run = write_run_folder(config)
    (run / "data").mkdir(exist_ok=True)
    env = make_vec_env(env_specs(config), config.n_actors)
    writer = SummaryWriter(str(run / "tb" / "distill"))
    try:
        student = make_student(config, env)
        (run / "student.json").write_text(json.dumps({"student": student.config.to_dict(),
                                                      "image_shape": list(student.image_shape),
                                                      "vector_shape": list(student.vector_shape)}, indent=2))
        optimizer = make_optimizer(student, d)
        averaged = make_averaged(student, d.ema_decay)
        rng = np.random.default_rng(config.seed)
        dataset, history, start, done = Dataset(d.max_samples, d.eviction), [], 0, 0
        groups = scene_groups(config.scene_ids, config.n_envs)
        priority = ScenePriority(config.scene_ids, d.scene_priority) if d.scene_priority > 0 else None
        if resume:
            ckpt = load_checkpoint(run)
            student.load_state_dict(ckpt["student"]["state_dict"])
            optimizer = make_optimizer(student, d, ckpt["optimizer"])
            averaged = make_averaged(student, d.ema_decay, ckpt.get("averaged"))
            rng.bit_generator.state = ckpt["rng"]
            start, done, history = ckpt["round"] + 1, ckpt["num_timesteps"], ckpt["history"]
            if priority is not None and ckpt.get("scene_priority"):
                priority.load_state_dict(ckpt["scene_priority"])
            for k in range(start):
                dataset.add(Batch.load(run / "data" / f"round_{k:03d}.npz"))
        driver = averaged.module if averaged is not None else student  # who drives the student's episodes
        # each env's scene weights, sent before the collector's first resets and after every round
        largest_weight = priority.apply(env, groups) if priority is not None else None
        collector = Collector(env, driver, config.seed + 7919 * start)
        rounds = max(1, math.ceil(config.total_steps / d.steps_per_round))
        t_start = time.perf_counter()
        for k in range(start, rounds):
            beta_k = beta(config, k)
            batch, stats = collector.collect(d.steps_per_round, beta_k, d.drop_stuck, d.hard_steps)
            batch.save(run / "data" / f"round_{k:03d}.npz")
            dataset.add(batch)
            done += stats.steps
            fitted = fit(student, optimizer, dataset, d, rng, averaged)
            row = {"round": k, "beta": beta_k, "env_steps": done, "labels": stats.labels, "dataset": len(dataset),
                   "dropped_stuck": stats.dropped_stuck, "hard_labels": stats.hard,
                   "env_steps_per_s": stats.steps / max(stats.wall_s, 1e-9),
                   "teacher_sr": stats.success_rate("teacher"), "student_sr": stats.success_rate("student"),
                   "student_episodes": len(stats.episodes["student"]), **fitted}
            if priority is not None:
                row["scene_weight_max"] = largest_weight  # the largest draw weight an env had this round
                priority.update(stats.episodes["student"])
                largest_weight = priority.apply(env, groups)
            history.append(row)
            for key, value in row.items():
                if key != "round" and value is not None:
                    writer.add_scalar(f"distill/{key}", value, done)
            writer.flush()
            save_checkpoint(run, student, optimizer, k, done, history, rng, averaged, priority)
            if log:
                log(row)
        driver.save(run / STUDENT_NAME)
        return TrainResult(run, done, history, time.perf_counter() - t_start)
    finally:
        writer.close()
        env.close()


def summary(history: list[dict]) -> dict[str, Any]:
    """The last round's figures (what `vid2sim train --method distill` prints)."""
    return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in (history[-1] if history else {}).items()}

