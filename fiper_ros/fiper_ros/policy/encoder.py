"""Observation encoder ``O^e = h(O)``: small ResNet-style CNNs over both cameras + proprioception MLP.

Per camera: stride-2 stem, residual blocks with GroupNorm, spatial softmax keypoints (as in
Diffusion Policy's ResNet encoder, scaled down for CPU training). The per-frame features of the
``T_h`` observation frames are concatenated and projected to the embedding dimension.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from .errors import PolicyError

CAMERAS = ("wrist_rgb", "third_rgb")
RAW_IMAGE_SIZE = 96


def preprocess_images(images: np.ndarray, size: int, what: str = "images") -> torch.Tensor:
    """uint8 ``[N, 96, 96, 3]`` camera frames -> uint8 ``[N, 3, size, size]`` (area downsampling); frames of another
    type or shape (a demonstration file's) are a :class:`~fiper_ros.policy.errors.PolicyError` naming ``what``.

    Training caches and inference both go through this function, so they see identical pixels.
    """
    array = np.asarray(images)
    if array.ndim != 4 or array.shape[-1] != 3 or array.dtype != np.uint8:
        raise PolicyError(f"{what}: expected uint8 images [N, H, W, 3], got {array.dtype} {array.shape}")
    tensor = torch.from_numpy(np.ascontiguousarray(array)).permute(0, 3, 1, 2)
    if array.shape[1] == size and array.shape[2] == size:
        return tensor.contiguous()
    resized = F.interpolate(tensor.float(), size=(size, size), mode="area")
    return resized.round().clamp(0, 255).to(torch.uint8).contiguous()


def _group_norm(channels: int) -> nn.GroupNorm:
    return nn.GroupNorm(min(8, channels // 4), channels)


class ResidualBlock(nn.Module):
    """Two 3x3 convolutions with GroupNorm and a skip connection."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(channels, channels, 3, padding=1, bias=False)
        self.norm1 = _group_norm(channels)
        self.conv2 = nn.Conv2d(channels, channels, 3, padding=1, bias=False)
        self.norm2 = _group_norm(channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``x + F(x)`` followed by ReLU."""
        y = F.relu(self.norm1(self.conv1(x)))
        return F.relu(x + self.norm2(self.conv2(y)))


class SpatialSoftmax(nn.Module):
    """Expected image coordinates of each channel's softmax attention map: ``[N, C, H, W] -> [N, 2C]``."""

    def __init__(self, size: int) -> None:
        super().__init__()
        coords = torch.linspace(-1.0, 1.0, size)
        grid_y, grid_x = torch.meshgrid(coords, coords, indexing="ij")
        self.register_buffer("grid", torch.stack([grid_x.reshape(-1), grid_y.reshape(-1)], dim=1))
        self.log_temperature = nn.Parameter(torch.zeros(()))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Keypoints ``(x, y)`` per channel."""
        n, c = x.shape[:2]
        attention = torch.softmax(x.reshape(n, c, -1) / self.log_temperature.exp(), dim=-1)
        return (attention @ self.grid).reshape(n, 2 * c)


class CameraTrunk(nn.Module):
    """CNN of one camera: uint8 ``[N, 3, S, S]`` -> keypoint features ``[N, 2 * channels[-1]]``."""

    def __init__(self, image_size: int, channels: Sequence[int]) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        width, size = 3, image_size
        for out in channels:
            layers += [nn.Conv2d(width, out, 3, stride=2, padding=1, bias=False), _group_norm(out), nn.ReLU(),
                       ResidualBlock(out)]
            width, size = out, (size + 1) // 2
        self.body = nn.Sequential(*layers)
        self.keypoints = SpatialSoftmax(size)
        self.out_dim = 2 * width

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """Features of a batch of uint8 images."""
        return self.keypoints(self.body(images.float() / 127.5 - 1.0))


class ObservationEncoder(nn.Module):
    """``T_h`` frames of (two cameras, proprio) -> observation embedding ``[N, embed_dim]``."""

    def __init__(self, image_size: int, channels: Sequence[int], proprio_dim: int, obs_horizon: int,
                 embed_dim: int, proprio_features: int = 64) -> None:
        super().__init__()
        self.cameras = nn.ModuleList(CameraTrunk(image_size, channels) for _ in CAMERAS)
        self.proprio = nn.Sequential(nn.Linear(proprio_dim, proprio_features), nn.ReLU(),
                                     nn.Linear(proprio_features, proprio_features))
        frame_dim = sum(trunk.out_dim for trunk in self.cameras) + proprio_features
        self.project = nn.Sequential(nn.Linear(obs_horizon * frame_dim, embed_dim), nn.LayerNorm(embed_dim))
        self.obs_horizon = obs_horizon

    def forward(self, images: Sequence[torch.Tensor], proprio: torch.Tensor) -> torch.Tensor:
        """Embed a batch.

        Args:
            images: One uint8 tensor ``[N, T_h, 3, S, S]`` per camera (order of ``CAMERAS``).
            proprio: Normalised proprioception ``[N, T_h, P]``.
        """
        n, t_h = proprio.shape[:2]
        if t_h != self.obs_horizon:
            raise ValueError(f"expected {self.obs_horizon} observation frames, got {t_h}")
        parts = [trunk(frames.flatten(0, 1)).reshape(n, t_h, -1) for trunk, frames in zip(self.cameras, images)]
        parts.append(self.proprio(proprio))
        return self.project(torch.cat(parts, dim=-1).reshape(n, -1))
