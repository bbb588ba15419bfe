"""Action mappings between a learned policy's output and the envs' action contract.

The envs' contract (the paper's, `NavEnv.step`): a[0] speed in [-1, 1] is clamped to [0, 1]
(x max_speed, no reverse), a[1] steering in [-1, 1]. For a learned policy that contract leaves
half of the speed range meaning "stop": a Gaussian / tanh policy can park its mean there at no
risk, and a deterministic evaluation then stands still (measured: speed < 0 in most held-out
timeouts of the pixel SAC agent, docs/studies/privileged_agent.md). A mapping changes only what
the policy's output means:

  "clamp": identity (the envs' contract; the default, what the paper's agent uses);
  "full":  policy speed p in [-1, 1] -> env speed (p + 1) / 2 in [0, 1]; steering unchanged.
           p = -1 is the only "stop", and an expert's env speed s maps back to 2 s - 1.

The same two functions serve training (`ActionMapping` wrapper around the training envs, which
also maps the scripted expert's demonstrations into the policy's space), evaluation (applied to
`model.predict`) and export (baked into the ONNX / torch.export graph). A trained model carries
its mapping as `model.action_map` (saved in the SB3 zip) and the run's config as `TrainConfig.action_map`.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

ACTION_MAPS = ("clamp", "full")


def check_map(mapping: str) -> str:
    if mapping not in ACTION_MAPS:
        raise ValueError(f"action_map must be one of {ACTION_MAPS}, got {mapping!r}")
    return mapping


def affine(mapping: str) -> tuple[np.ndarray, np.ndarray]:
    """(scale [2], offset [2]) with env action = policy action * scale + offset."""
    if check_map(mapping) == "full":
        return np.array([0.5, 1.0], np.float32), np.array([0.5, 0.0], np.float32)
    return np.ones(2, np.float32), np.zeros(2, np.float32)


def to_env(action: np.ndarray, mapping: str) -> np.ndarray:
    """Policy action [..., 2] -> env action [..., 2] (export.py applies the same `affine` in torch)."""
    scale, offset = affine(mapping)
    return (np.asarray(action, np.float32) * scale + offset).astype(np.float32)


def from_env(action: np.ndarray, mapping: str) -> np.ndarray:
    """Env action [..., 2] -> policy action [..., 2]; under "full" an env speed <= 0 (stop) maps to -1."""
    scale, offset = affine(mapping)
    a = np.array(action, dtype=np.float32, copy=True)
    if mapping == "full":
        a[..., 0] = np.clip(a[..., 0], 0.0, 1.0)
    return ((a - offset) / scale).astype(np.float32)


class ActionMapping(gym.ActionWrapper):
    """The env seen through a policy-side action mapping; `expert_action()` is mapped back too."""

    def __init__(self, env: gym.Env, mapping: str) -> None:
        super().__init__(env)
        self.mapping = check_map(mapping)

    def action(self, action: Any) -> np.ndarray:
        return to_env(np.asarray(action, np.float32), self.mapping)

    def expert_action(self) -> np.ndarray:
        """The wrapped `ExpertActions`' action in the policy's space [2]."""
        return from_env(self.env.get_wrapper_attr("expert_action")(), self.mapping)
