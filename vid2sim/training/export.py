"""Policy export for deployment: ONNX (checked with onnxruntime) and a `torch.export` program.

The exported graph is the deterministic SAC actor, or the distilled pixel student
(`training/student.py`, whose graph is its own `forward`), with everything a robot needs baked in:
uint8 frames in (scaled to [0, 1] inside), the goal vector in metres / radians (scaled inside),
`tanh` squashing, the action-space rescale, a clamp to [low, high] and the policy's action
mapping (`model.action_map`, `vid2sim.training.actions`: "full" maps speed to (p + 1) / 2).
Output: normalised [speed, steering] in the envs' contract, [-1, 1] (speed <= 0 means stop).
TorchScript is not shipped: PyTorch marks it deprecated in favour
of `torch.export`, and robot stacks (Isaac Lab, SB3's export guide) consume ONNX.

`NavPolicy` is the inference API: feed one camera frame plus the odometry (distance and heading
to the goal) per control step; it keeps the last 6 frames and vectors like the env does.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import onnxruntime as ort
import torch
from stable_baselines3 import SAC
from torch import nn

from vid2sim.training.actions import affine, check_map
from vid2sim.training.ensemble import StudentEnsemble, load_student
from vid2sim.training.run_files import policy_path
from vid2sim.training.student import StudentPolicy
from vid2sim.versioning import code_version

ONNX_NAME, PROGRAM_NAME, META_NAME = "policy.onnx", "policy.pt2", "policy.json"


class DeterministicActor(nn.Module):
    """SAC actor mean -> tanh -> action-space rescale -> clamp; inputs are raw env observations."""

    def __init__(self, model: SAC):
        super().__init__()
        policy = model.policy
        self.features = policy.actor.features_extractor
        self.latent_pi, self.mu = policy.actor.latent_pi, policy.actor.mu
        space = model.action_space
        self.register_buffer("low", torch.as_tensor(space.low, dtype=torch.float32))
        self.register_buffer("high", torch.as_tensor(space.high, dtype=torch.float32))
        scale, offset = affine(action_map(model))  # env action = policy action * scale + offset
        self.register_buffer("map_scale", torch.from_numpy(scale))
        self.register_buffer("map_offset", torch.from_numpy(offset))

    def forward(self, image: torch.Tensor, vector: torch.Tensor) -> torch.Tensor:
        feats = self.features({"image": image.float(), "vector": vector.float()})
        squashed = torch.tanh(self.mu(self.latent_pi(feats)))
        action = self.low + 0.5 * (squashed + 1.0) * (self.high - self.low)
        return torch.clamp(action, self.low, self.high) * self.map_scale + self.map_offset  # [B, 2] env contract


def action_map(model: SAC) -> str:
    """The model's policy -> env action mapping ("clamp" for models saved before mappings existed)."""
    return check_map(getattr(model, "action_map", "clamp"))


@dataclass
class PolicyMeta:
    image_shape: list[int]  # [6, C, H, W] uint8
    vector_shape: list[int]  # [6, 2]: distance (m), heading / pi to the goal per stacked step (as the envs)
    actions: list[str]
    code_version: str
    source: str
    action_map: str = "clamp"  # baked into the graph already; recorded for the reader
    method: str = "sac"  # "sac" (actor of a SAC model) or "distill" (pixel student)
    # the student's encoder and input choice (StudentConfig), for distill; {"ensemble": [StudentConfig...]}
    # for an ensemble of students (training/ensemble.py)
    architecture: Optional[dict] = None


Model = SAC | StudentPolicy | StudentEnsemble
MODEL_TYPES = (SAC, StudentPolicy, StudentEnsemble)


def load_model(model: Model | str | Path) -> Model:
    """A SAC model, a distilled student or an ensemble of students, from memory, a SAC .zip, a student
    .pt or a run (or ensemble) folder."""
    if isinstance(model, MODEL_TYPES):
        return model
    path = policy_path(str(model))
    return load_student(path) if path.suffix == ".pt" else SAC.load(path, device="cpu")


def graph_and_meta(model: Model, source: str) -> tuple[nn.Module, PolicyMeta]:
    """The module to export and its metadata."""
    if isinstance(model, (StudentPolicy, StudentEnsemble)):
        architecture = model.architecture() if isinstance(model, StudentEnsemble) else model.config.to_dict()
        meta = PolicyMeta(list(model.image_shape), list(model.vector_shape), ["speed", "steering"], code_version(),
                          source, "clamp", "distill", architecture)
        return model.eval(), meta
    spaces = model.observation_space.spaces
    meta = PolicyMeta(list(spaces["image"].shape), list(spaces["vector"].shape), ["speed", "steering"],
                      code_version(), source, action_map(model))
    return DeterministicActor(model).eval(), meta


def export_policy(model: Model | str | Path, out_dir: str | Path) -> Path:
    """Write policy.onnx, policy.pt2 and policy.json into `out_dir`; returns `out_dir`."""
    source = "in-memory" if isinstance(model, MODEL_TYPES) else str(model)
    actor, meta = graph_and_meta(load_model(model), source)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    image = torch.randint(0, 256, (2, *meta.image_shape), dtype=torch.uint8)
    inputs = (image, torch.randn(2, *meta.vector_shape))
    batch = torch.export.Dim("batch", min=1, max=1024)
    shapes = {"image": {0: batch}, "vector": {0: batch}}
    program = torch.export.export(actor, inputs, dynamic_shapes=shapes)
    torch.export.save(program, out / PROGRAM_NAME)
    torch.onnx.export(actor, inputs, out / ONNX_NAME, input_names=["image", "vector"], output_names=["action"],
                      dynamic_shapes=shapes, dynamo=True, external_data=False)
    (out / META_NAME).write_text(json.dumps(asdict(meta), indent=2))
    return out


class NavPolicy:
    """Deployment API: last 6 frames + odometry -> normalised (speed, steering)."""

    def __init__(self, export_dir: str | Path, backend: str = "onnx"):
        d = Path(export_dir)
        self.meta = PolicyMeta(**json.loads((d / META_NAME).read_text()))
        self.backend = backend
        if backend == "onnx":
            self.session = ort.InferenceSession(str(d / ONNX_NAME), providers=["CPUExecutionProvider"])
        elif backend == "torch":
            self.program = torch.export.load(d / PROGRAM_NAME).module()
        else:
            raise ValueError(f"backend must be 'onnx' or 'torch', got {backend!r}")
        self.frames: Optional[np.ndarray] = None
        self.vectors: Optional[np.ndarray] = None

    def act_stacked(self, image: np.ndarray, vector: np.ndarray) -> np.ndarray:
        """Batched call: image uint8 [B, 6, C, H, W], vector [B, 6, 2] -> actions [B, 2]."""
        image = np.ascontiguousarray(image, dtype=np.uint8)
        vector = np.ascontiguousarray(vector, dtype=np.float32)
        if self.backend == "onnx":
            return self.session.run(["action"], {"image": image, "vector": vector})[0]
        with torch.no_grad():
            return self.program(torch.from_numpy(image), torch.from_numpy(vector)).numpy()

    def reset(self) -> None:
        """Start a new episode: the next frame fills the whole history."""
        self.frames = self.vectors = None

    def step(self, frame: np.ndarray, distance: float, heading: float) -> tuple[float, float]:
        """One control step; `frame` is [H, W, C] or [C, H, W] uint8; heading to the goal in radians."""
        stack, channels = self.meta.image_shape[0], self.meta.image_shape[1]
        chw = frame if frame.shape[0] == channels else np.transpose(frame, (2, 0, 1))
        vec = np.array([distance, heading / np.pi], np.float32)  # the envs' vector convention
        if self.frames is None:
            self.frames = np.repeat(chw[None], stack, axis=0).astype(np.uint8)
            self.vectors = np.repeat(vec[None], stack, axis=0)
        else:
            self.frames = np.concatenate([self.frames[1:], chw[None]])
            self.vectors = np.concatenate([self.vectors[1:], vec[None]])
        speed, steering = self.act_stacked(self.frames[None], self.vectors[None])[0]
        return float(speed), float(steering)
