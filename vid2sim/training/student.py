"""The pixel student: the deployable observation in, the envs' action out.

Input (exactly what `vid2sim/PointNav-v0` observes and `NavPolicy` feeds): `image` uint8
[B, 6, C, 72, 128] (6 stacked frames, oldest first) and `vector` float [B, 6, 2] (distance to the
goal in m, heading to the goal / pi). Output: [B, 2] (speed, steering) in [-1, 1], the envs'
contract (speed <= 0 stops).

Chosen for a 2-core CPU (`StudentConfig`, recorded in the run folder and the export):
- `frames` of the 6 stacked frames, every `frame_stride`-th back from the latest (default 2 x 1:
  the current view and one 0.2 s back, for motion),
  average-pooled by `pool` (default 2: 36 x 64 pixels), rounded to integers so the stored
  training inputs and the deployed graph see the same numbers;
- one small conv encoder shared by the frames (weights shared, features concatenated), about
  3 MFLOP per frame at 36 x 64, so the learner fits ~3,000 samples per second on 2 threads;
- the latest `vector_history` entries of the goal-vector history (default all 6: 12 numbers, scaled
  as `NavCNN`) through a small MLP. Two entries reveal the heading change of the last step, that is
  the steering just applied: where the teacher drove (DAgger's first rounds) it predicts the
  teacher's next label almost alone (R^2 0.82 on the first round's states, 0.08 from the latest
  entry alone; `benchmarks/distill_labels.py --history-probe`), the copycat shortcut of behaviour
  cloning from observation histories; 1 reads only where the goal is now (measured: no better);
- an MLP head with `tanh`; `steer_gain` > 1 scales the steering's pre-activation when the student
  drives (DAgger's collection, evaluation, the export) but not in the learner's loss: a regression
  on what the frames show only roughly answers hard-turn labels with a fraction of their size, and
  the gain asks it to commit (measured: no better, 0.752 with 2 against 0.75 with 1, three seeds);
- optionally (`steer_bins` K > 0) the steering as a distribution over K evenly spaced values in
  [-1, 1] instead of one regressed number, learnt by cross-entropy to the label's two nearest
  bins: where the teacher turns hard left in some states and hard right in others that look alike,
  a regressed steering averages them to straight ahead, the bins keep both; the action is the
  probability-weighted steering of the most likely bin and its two neighbours
  (`steer_from_logits`, in the exported graph too);
- optionally (`mirror_average`) driving with the mean of its action and the mirrored action for
  the mirrored view, so it turns left where it would turn right in the mirrored street (pairs
  with the learner's mirrored samples, `DistillConfig.mirror`); twice the inference;
- optionally (`keypoints` K > 0) each frame's features from K spatial-softmax keypoints of its last
  conv map instead of the flattened map (Levine et al. 2016; robomimic's image encoders): a 1 x 1
  conv to K maps, a softmax over each map's cells with a learnt temperature, and each map's
  expected (x, y) in [-1, 1] (x negates under the mirror): the features say where in the view
  something is, which the flattened map's position-specific weights must learn cell by cell
  (measured: worse, 0.755 held-out over two seeds against 0.80 with the flattened map);
- optionally (`waypoints` K > 0) a second head on the MLP's hidden layer predicting the teacher's route
  ahead, K points `WAYPOINT_SPACING` m apart in the robot's frame (`TeacherLabels`), trained beside
  the actions; with `drive_waypoints` the student steers by pure pursuit on its own predicted route
  (the point `lookahead` m along it, the teacher's controller and the robot's wheelbase and steering
  limit), as "Learning by Cheating" (Chen et al. 2019) drives its image student: the network says
  where the way goes, the controller turns that into steering (in the exported graph too; measured:
  0.805 held-out over two seeds, as good as the action head's students, street-v17 unchanged);
- optionally (`clearance_rays` K > 0) a linear head from the latest frame's features to K
  clearance readings in [0, 1], trained as an auxiliary target and left out of the export;
- optionally (`depth_target`) a 1 x 1 conv head on the latest frame's last conv map (5 x 8 at
  36 x 64) predicting the nearest depth in each cell, / 5 m, in [0, 1]: a dense auxiliary target
  (the teacher's `depth_blocks`, min-pooled to the map) that asks the encoder where things are and
  how near, also left out of the export.
`preprocess` (select + pool) and `act` (the network) are separate so the learner stores the
small preprocessed frames and augments them (random shifts) before `act`; `forward` is
`act(preprocess(...))`, the graph that is exported.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Optional

import torch
import torch.nn.functional as F
from torch import nn

from vid2sim.formats.robot import ROBOT
from vid2sim.ranges import checked
from vid2sim.training.policy import VECTOR_SCALE

STACK = 6  # frames in the env observation
WAYPOINT_SPACING = 0.5  # m along the teacher's route between its waypoint labels (`TeacherLabels`)
DRIVING_SETTINGS = ("steer_gain", "mirror_average", "drive_waypoints", "lookahead", "wheelbase",
                    "max_steer_deg")  # no weight depends on them


@checked
@dataclass
class StudentConfig:
    """Encoder and input size of the pixel student (see the module docs)."""

    frames: int = 2  # stacked frames the student looks at (1..6), the most recent one last
    frame_stride: int = 1  # every k-th stacked frame back from the latest (2 with 3 frames: t-4, t-2, t)
    pool: int = 2  # average-pooling factor of the 72 x 128 frames (1: full size)
    channels: tuple[int, ...] = (16, 32, 32, 32)  # conv widths; first conv 5x5 stride 2, then 3x3 strides 2, 2, 1
    frame_dim: int = 128  # features per frame
    vector_dim: int = 64  # features of the goal-vector history
    hidden: int = 256  # head width
    vector_history: int = STACK  # latest goal-vector entries the student reads (1: only the current one)
    clearance_rays: int = 0  # auxiliary head: the teacher's clearance over the view, K rays (0: none)
    steer_bins: int = 0  # steering as a distribution over K values in [-1, 1] (0: one regressed value)
    depth_target: bool = False  # auxiliary head: the latest frame's nearest depth per cell of the last conv map
    keypoints: int = 0  # frame features: K spatial-softmax keypoints of the last conv map (0: the flattened map)
    waypoints: int = 0  # second head: the teacher's route ahead as K points WAYPOINT_SPACING m apart (0: none)
    drive_waypoints: bool = False  # when driving: steer by pure pursuit on the predicted route (needs waypoints)
    lookahead: float = 1.0  # m along the predicted route the pure pursuit aims (drive_waypoints)
    # the robot the pure pursuit steers (drive_waypoints): the training env's `RobotConfig`, which the
    # learner copies here, so the run folder and the export record it
    wheelbase: float = ROBOT.wheelbase_m  # m
    max_steer_deg: float = ROBOT.max_steer_deg  # deg
    steer_gain: float = 1.0  # when driving: steering tanh(gain x pre-activation); the learner's loss sees gain 1
    # when driving: the mean of its action and the mirrored action for the mirrored view (frames flipped left
    # to right, the goal's heading negated), so left and right are treated exactly alike; the loss sees one pass
    mirror_average: bool = False

    def __post_init__(self) -> None:  # single fields: their ranges (vid2sim.ranges: frames 1..6, pool >= 1, ...)
        if (self.frames - 1) * self.frame_stride + 1 > STACK:
            raise ValueError(f"student frames x frame_stride must fit the {STACK} stacked frames, got "
                             f"{self.frames} x {self.frame_stride}")
        self.channels = tuple(int(c) for c in self.channels)
        if len(self.channels) != 4:
            raise ValueError(f"student channels must list 4 conv widths, got {list(self.channels)}")
        if self.steer_bins in (1, 2):
            raise ValueError(f"student steer_bins must be 0 (regressed steering) or >= 3, got {self.steer_bins}")
        if self.drive_waypoints and not self.waypoints:
            raise ValueError("student drive_waypoints needs a route head (waypoints > 0)")
        if self.drive_waypoints and self.lookahead > self.waypoints * WAYPOINT_SPACING:
            raise ValueError(f"student lookahead {self.lookahead} m lies past its {self.waypoints} waypoints "
                             f"({self.waypoints * WAYPOINT_SPACING} m of route)")
        if self.steer_bins and self.steer_gain != 1.0:
            raise ValueError(f"student steer_gain applies to a regressed steering; with steer_bins "
                             f"{self.steer_bins} it must be 1, got {self.steer_gain}")

    def to_dict(self) -> dict:
        return asdict(self)


def frame_encoder(in_channels: int, widths: tuple[int, ...]) -> nn.Sequential:
    c1, c2, c3, c4 = widths
    return nn.Sequential(
        nn.Conv2d(in_channels, c1, 5, stride=2, padding=2), nn.ReLU(),
        nn.Conv2d(c1, c2, 3, stride=2, padding=1), nn.ReLU(),
        nn.Conv2d(c2, c3, 3, stride=2, padding=1), nn.ReLU(),
        nn.Conv2d(c3, c4, 3, stride=1, padding=1), nn.ReLU(),
        nn.Flatten())


class StudentPolicy(nn.Module):
    """Last frames + goal-vector history -> (speed, steering) in [-1, 1]."""

    def __init__(self, config: StudentConfig, image_shape: tuple[int, ...], vector_shape: tuple[int, ...]):
        super().__init__()
        self.config = config
        self.image_shape, self.vector_shape = tuple(image_shape), tuple(vector_shape)  # [6, C, H, W], [6, 2]
        stack, channels, height, width = self.image_shape
        self.frame_index = [stack - 1 - k * config.frame_stride for k in reversed(range(config.frames))]
        if self.frame_index[0] < 0:
            raise ValueError(f"the observation stacks {stack} frames, the student wants {config.frames} "
                             f"every {config.frame_stride}")
        self.channels = channels
        # channels-last conv weights: the fit 10-15 % cheaper on CPU (benchmarks/distill_cost.py), the
        # same values up to float rounding
        self.encoder = frame_encoder(channels, config.channels).to(memory_format=torch.channels_last)
        with torch.no_grad():
            probe = self.preprocess(torch.zeros(1, *self.image_shape, dtype=torch.uint8))
            map_shape = self.encoder[:-1](probe[:, 0].float()).shape[1:]  # [c4, h', w']
        # with keypoints: the last conv map -> K (x, y) keypoints [2K]; else the flattened map
        self.keypoint_head = SpatialSoftmax(*map_shape, config.keypoints) if config.keypoints else None
        n_flat = 2 * config.keypoints if config.keypoints else math.prod(map_shape)
        self.frame_head = nn.Sequential(nn.Linear(n_flat, config.frame_dim), nn.ReLU())
        if config.vector_history > self.vector_shape[0]:
            raise ValueError(f"the observation stacks {self.vector_shape[0]} goal vectors, the student wants the "
                             f"latest {config.vector_history}")
        n_vec = config.vector_history * math.prod(self.vector_shape[1:])
        self.register_buffer("vector_scale", torch.tensor(VECTOR_SCALE, dtype=torch.float32).repeat(n_vec // 2))
        self.vector_head = nn.Sequential(nn.Linear(n_vec, config.vector_dim), nn.ReLU())
        n_out = 1 + config.steer_bins if config.steer_bins else 2  # speed + steering bins, or speed + steering
        self.head = nn.Sequential(nn.Linear(config.frames * config.frame_dim + config.vector_dim, config.hidden),
                                  nn.ReLU(), nn.Linear(config.hidden, n_out))
        # [K] steering value of each bin, with steer_bins (derived from the config, so not in the state dict)
        bins = torch.linspace(-1.0, 1.0, config.steer_bins) if config.steer_bins else None
        self.register_buffer("steer_values", bins, persistent=False)
        # the MLP's hidden layer -> the teacher's route ahead [K, 2] (robot frame, m)
        self.waypoint_head = nn.Linear(config.hidden, 2 * config.waypoints) if config.waypoints else None
        # trained only (not in the exported graph): the latest frame's features -> clearance [K]
        self.clearance_head = nn.Linear(config.frame_dim, config.clearance_rays) if config.clearance_rays else None
        # trained only: the latest frame's last conv map [c4, h', w'] -> nearest depth / 5 m per cell [h', w']
        self.depth_head = nn.Conv2d(config.channels[-1], 1, 1) if config.depth_target else None

    @property
    def input_shape(self) -> tuple[int, int, int, int]:
        """Shape of one preprocessed sample [frames, C, h, w] (what the learner stores)."""
        _, c, h, w = self.image_shape
        p = self.config.pool
        return self.config.frames, c, h // p, w // p

    def preprocess(self, image: torch.Tensor) -> torch.Tensor:
        """uint8/float [B, 6, C, H, W] -> float [B, frames, C, h, w] of integers in 0..255."""
        x = image[:, self.frame_index].float()
        b, k, c, h, w = x.shape
        if self.config.pool > 1:
            x = F.avg_pool2d(x.reshape(b * k, c, h, w), self.config.pool).reshape(b, k, c, h // self.config.pool,
                                                                                w // self.config.pool)
        return torch.round(x)

    def act(self, frames: torch.Tensor, vector: torch.Tensor) -> torch.Tensor:
        """Preprocessed frames [B, frames, C, h, w] (0..255) + vector [B, 6, 2] -> the actions it drives
        with [B, 2] (steering with the config's `steer_gain`; with `mirror_average`, averaged with its own
        mirror image)."""
        actions = self._driven(self.outputs(frames, vector, self.config.steer_gain))
        if not self.config.mirror_average:
            return actions
        flip = actions.new_tensor([1.0, -1.0])  # [2]: distance and speed kept, heading and steering negated
        mirrored = self._driven(self.outputs(frames.flip(-1), vector * flip, self.config.steer_gain)) * flip
        return 0.5 * (actions + mirrored)

    def _driven(self, out: "StudentOutputs") -> torch.Tensor:
        """The actions it drives with [B, 2]: the head's, or with `drive_waypoints` the head's speed and
        pure pursuit's steering on the predicted route."""
        if not self.config.drive_waypoints:
            return out.actions
        c = self.config
        steering = pursuit_steering(out.waypoints, c.lookahead, c.wheelbase, c.max_steer_deg)
        return torch.stack([out.actions[:, 0], steering], dim=1)

    def outputs(self, frames: torch.Tensor, vector: torch.Tensor, steer_gain: float = 1.0) -> "StudentOutputs":
        """The actions (regressed steering tanh(steer_gain x pre-activation); the learner's losses use 1),
        the steering logits (with steer_bins), and the clearance, depth and route predictions (with
        their heads)."""
        b, k = frames.shape[:2]
        x = frames.float().reshape(b * k, *frames.shape[2:]) / 255.0
        maps = self.encoder[:-1](x)  # [B * frames, c4, h', w'] (the encoder without its Flatten)
        features = self.keypoint_head(maps) if self.keypoint_head is not None else maps.flatten(1)
        per_frame = self.frame_head(features).reshape(b, k, -1)  # [B, frames, frame_dim]
        recent = vector[:, -self.config.vector_history:]  # [B, vector_history, 2]
        vec = self.vector_head(recent.float().flatten(1) * self.vector_scale)
        hidden = self.head[:2](torch.cat([per_frame.flatten(1), vec], dim=1))  # [B, hidden]
        out = self.head[2:](hidden)  # [B, 2] or [B, 1 + K]
        logits = out[:, 1:] if self.config.steer_bins else None
        steering = (steer_from_logits(logits, self.steer_values) if logits is not None
                    else torch.tanh(steer_gain * out[:, 1]))
        actions = torch.stack([torch.tanh(out[:, 0]), steering], dim=1)  # [B, 2]
        clearance = (torch.sigmoid(self.clearance_head(per_frame[:, -1])) if self.clearance_head is not None
                     else actions.new_zeros(b, 0))  # [B, K] in [0, 1]
        depth = (torch.sigmoid(self.depth_head(maps.reshape(b, k, *maps.shape[1:])[:, -1]))[:, 0]
                 if self.depth_head is not None else actions.new_zeros(b, 0, 0))  # [B, h', w'] in [0, 1]
        waypoints = (self.waypoint_head(hidden).reshape(b, -1, 2) if self.waypoint_head is not None
                     else actions.new_zeros(b, 0, 2))  # [B, K, 2] robot frame, m
        return StudentOutputs(actions, logits, clearance, depth, waypoints)

    def forward(self, image: torch.Tensor, vector: torch.Tensor) -> torch.Tensor:
        return self.act(self.preprocess(image), vector)

    # ------------------------------------------------------------------ persistence
    def checkpoint(self) -> dict:
        return {"config": self.config.to_dict(), "image_shape": list(self.image_shape),
                "vector_shape": list(self.vector_shape), "state_dict": self.state_dict()}

    @classmethod
    def from_checkpoint(cls, ckpt: dict) -> "StudentPolicy":
        student = cls(StudentConfig(**ckpt["config"]), tuple(ckpt["image_shape"]), tuple(ckpt["vector_shape"]))
        student.load_state_dict(ckpt["state_dict"])
        return student.eval()

    def save(self, path) -> None:
        torch.save(self.checkpoint(), path)

    def driving_with(self, **settings) -> "StudentPolicy":
        """The same weights driving with other `StudentConfig` driving settings (`steer_gain`,
        `mirror_average`, `drive_waypoints`, `lookahead`; a copy, this student is unchanged)."""
        unknown = set(settings) - set(DRIVING_SETTINGS)
        if unknown:
            raise ValueError(f"driving_with: {sorted(unknown)} are not driving settings "
                             f"({', '.join(DRIVING_SETTINGS)})")
        ckpt = self.checkpoint()
        ckpt["config"].update(settings)
        return StudentPolicy.from_checkpoint(ckpt)

    @classmethod
    def load(cls, path) -> "StudentPolicy":
        return cls.from_checkpoint(torch.load(path, map_location="cpu", weights_only=False))


class SpatialSoftmax(nn.Module):
    """Conv maps [N, C, h, w] -> K keypoints [N, 2K] (x1, y1, x2, y2, ...): a 1 x 1 conv to K maps,
    a softmax over each map's h x w cells at a learnt temperature, and each map's expected cell
    position, x and y in [-1, 1] (left to right, top to bottom; symmetric, so a view flipped left to
    right negates x)."""

    def __init__(self, channels: int, height: int, width: int, keypoints: int) -> None:
        super().__init__()
        self.project = nn.Conv2d(channels, keypoints, 1)
        self.log_temperature = nn.Parameter(torch.zeros(()))
        ys, xs = torch.meshgrid(torch.linspace(-1.0, 1.0, height), torch.linspace(-1.0, 1.0, width), indexing="ij")
        self.register_buffer("grid", torch.stack([xs.flatten(), ys.flatten()], dim=1), persistent=False)  # [h w, 2]

    def forward(self, maps: torch.Tensor) -> torch.Tensor:
        logits = self.project(maps).flatten(2) * torch.exp(-self.log_temperature)  # [N, K, h w]
        return (torch.softmax(logits, dim=2) @ self.grid).flatten(1)  # [N, K, 2] -> [N, 2K]


@dataclass
class StudentOutputs:
    actions: torch.Tensor  # [B, 2] speed, steering in [-1, 1]
    steer_logits: Optional[torch.Tensor]  # [B, K] with steer_bins, else None
    clearance: torch.Tensor  # [B, clearance_rays] in [0, 1] ([B, 0] without the head)
    depth: torch.Tensor  # [B, h', w'] nearest depth / 5 m per cell of the last conv map ([B, 0, 0] without)
    waypoints: torch.Tensor  # [B, K, 2] the predicted route ahead, robot frame, m ([B, 0, 2] without the head)


def pursuit_steering(waypoints: torch.Tensor, lookahead: float, wheelbase: float = ROBOT.wheelbase_m,
                     max_steer_deg: float = ROBOT.max_steer_deg) -> torch.Tensor:
    """Route points [B, K, 2] (`WAYPOINT_SPACING` m apart, robot frame: x forward, y left) -> normalised
    steering [B] in [-1, 1]: pure pursuit of the point `lookahead` m along the route (interpolated)
    for a bicycle model of `wheelbase` m, the teacher's controller (`envs/expert.py`):
    atan(2 L sin(alpha) / l_d) = atan(2 L y / l_d^2), over the steering limit `max_steer_deg`."""
    pos = min(max(lookahead / WAYPOINT_SPACING - 1.0, 0.0), waypoints.shape[1] - 1.0)  # index into K
    lo = min(int(math.floor(pos)), waypoints.shape[1] - 1)
    hi, frac = min(lo + 1, waypoints.shape[1] - 1), pos - lo
    target = waypoints[:, lo] * (1.0 - frac) + waypoints[:, hi] * frac  # [B, 2]
    ld2 = target.square().sum(dim=1).clamp_min(1e-6)  # [B]
    steer = torch.atan(2.0 * wheelbase * target[:, 1] / ld2)  # rad
    return (steer / math.radians(max_steer_deg)).clamp(-1.0, 1.0)


def steer_from_logits(logits: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
    """Logits [B, K] over steering `values` [K] -> steering [B]: the probability-weighted mean of the
    most likely bin and its two neighbours (one mode, never the average of a left and a right turn)."""
    probs = torch.softmax(logits, dim=1)  # [B, K]
    index = torch.arange(logits.shape[1], device=logits.device)  # [K]
    near = (index[None] - probs.argmax(dim=1, keepdim=True)).abs() <= 1  # [B, K]
    weights = probs * near
    return (weights * values).sum(dim=1) / weights.sum(dim=1)


def two_hot(steering: torch.Tensor, bins: int) -> torch.Tensor:
    """Steering labels [B] in [-1, 1] -> target distributions [B, K] on the two nearest of K evenly
    spaced values (linear interpolation: their expectation is the label)."""
    pos = (steering.clamp(-1.0, 1.0) + 1.0) * 0.5 * (bins - 1)  # [B] in [0, K - 1]
    low = pos.floor().clamp(max=bins - 2)
    frac = (pos - low)[:, None]  # [B, 1]
    target = torch.zeros(len(steering), bins, dtype=steering.dtype, device=steering.device)
    target.scatter_(1, low.long()[:, None], 1.0 - frac)
    target.scatter_add_(1, low.long()[:, None] + 1, frac)
    return target


def random_shift(frames: torch.Tensor, pad: int, generator: torch.Generator | None = None) -> torch.Tensor:
    """DrQ's augmentation: replicate-pad by `pad` pixels and crop back at a random offset per sample.

    frames [B, K, C, h, w] -> [B, K, C, h, w]; the K frames of one sample share the offset."""
    if pad <= 0:
        return frames
    b, k, c, h, w = frames.shape
    padded = F.pad(frames.reshape(b, k * c, h, w), (pad, pad, pad, pad), mode="replicate")
    dx = torch.randint(0, 2 * pad + 1, (b,), generator=generator)
    dy = torch.randint(0, 2 * pad + 1, (b,), generator=generator)
    # one slice per sample: ~6x cheaper than one gather over broadcast index grids
    crops = [padded[i, :, y:y + h, x:x + w] for i, (y, x) in enumerate(zip(dy.tolist(), dx.tolist()))]
    return torch.stack(crops).reshape(b, k, c, h, w)
