"""CNN feature extractor for the stacked camera frames plus the goal vector.

Input (Vid2Sim observation): `image` uint8 [B, 6, C, H, W] (6 stacked frames, C = 3 RGB or 1
depth) and `vector` float [B, 6, 2] (distance in m and heading / pi to the goal per stacked step). The
frames are folded into channels (6*C), scaled to [0, 1] and passed through a Nature-CNN style
stack; the vector goes through a small MLP; both are concatenated.

No augmentation here: the published Vid2Sim extractor applies random brightness / contrast /
hue jitter inside `forward`, i.e. also at evaluation and deployment. Augmentation belongs to
the training envs (`vid2sim.envs` augmentation config), so the evaluated and exported policy is
a deterministic function of its observation.
"""

from __future__ import annotations

import gymnasium as gym
import torch
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

VECTOR_SCALE = (1.0 / 30.0, 1.0)  # distance (m) -> about [0, 1]; heading is already heading / pi in the envs


def conv_stack(in_channels: int) -> nn.Sequential:
    """Nature-CNN layout; strides chosen for 72x128 inputs (-> 64 x 5 x 12 maps)."""
    return nn.Sequential(
        nn.Conv2d(in_channels, 32, 8, stride=4), nn.ReLU(),
        nn.Conv2d(32, 64, 4, stride=2), nn.ReLU(),
        nn.Conv2d(64, 64, 3, stride=1), nn.ReLU(),
        nn.Flatten())


class NavCNN(BaseFeaturesExtractor):
    """Stacked frames + goal vector -> features (image_dim + vector_dim)."""

    def __init__(self, observation_space: gym.spaces.Dict, image_dim: int = 256, vector_dim: int = 64,
                 vector_scale: tuple[float, float] = VECTOR_SCALE):
        image_space, vector_space = observation_space["image"], observation_space["vector"]
        super().__init__(observation_space, image_dim + vector_dim)
        stack, channels, height, width = image_space.shape
        self.in_channels = stack * channels
        self.cnn = conv_stack(self.in_channels)
        with torch.no_grad():
            n_flat = self.cnn(torch.zeros(1, self.in_channels, height, width)).shape[1]
        self.image_head = nn.Sequential(nn.Linear(n_flat, image_dim), nn.ReLU())
        n_vec = int(torch.tensor(vector_space.shape).prod())
        self.register_buffer("vector_scale", torch.tensor(vector_scale, dtype=torch.float32).repeat(n_vec // 2))
        self.vector_head = nn.Sequential(nn.Linear(n_vec, vector_dim), nn.ReLU())

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        image = observations["image"].float()
        image = image.reshape(image.shape[0], self.in_channels, *image.shape[-2:])
        image = image / 255.0  # SB3 does not scale a 4-D [stack, C, H, W] Box: done here, always
        vector = observations["vector"].float().flatten(1) * self.vector_scale
        return torch.cat([self.image_head(self.cnn(image)), self.vector_head(vector)], dim=1)
