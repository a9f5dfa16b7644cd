"""Policy configuration: sizes of App. B.3 / Table 5, scaled to train on a 2-core CPU (docs/policies.md)."""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import yaml

from fiper_ros.policy.errors import PolicyError


@dataclass(frozen=True)
class PolicyConfig:
    """Architecture, sampling and training settings of one task's policy.

    Attributes:
        head: ``"flow"`` (flow matching + transformer) or ``"diffusion"`` (DDPM + temporal U-Net).
        obs_horizon: Observation history ``T_h``; horizon: chunk length ``H``; exec_steps: ``h``;
        sample_batch: Action batch size ``B`` sampled every policy step.
        image_size: Cameras are area-downsampled from 96x96 to this size.
        image_shift: Random-translation augmentation [pixels] in training.
        noise_draws: Noise/time draws per observation in one training step (cheap: the encoder runs once).
    """

    task: str
    head: str
    action_dim: int
    proprio_dim: int
    embed_dim: int
    obs_horizon: int
    horizon: int
    exec_steps: int
    sample_batch: int
    action_space: str
    image_size: int = 64
    encoder_channels: tuple[int, ...] = (8, 16, 32)
    transformer_width: int = 64
    transformer_layers: int = 2
    transformer_heads: int = 4
    unet_channels: tuple[int, ...] = (64, 128)
    integration_steps: int = 16
    diffusion_train_steps: int = 100
    diffusion_sample_steps: int = 10
    diffusion_eta: float = 0.0
    epochs: int = 20
    batch_size: int = 256
    lr: float = 1e-3
    weight_decay: float = 1e-4
    noise_draws: int = 2
    ema_decay: float = 0.995
    image_shift: int = 2

    def to_dict(self) -> dict[str, Any]:
        """Plain values for YAML (tuples become lists)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> PolicyConfig:
        """Inverse of :meth:`to_dict`; unknown keys are an error."""
        names = {f.name for f in fields(cls)}
        unknown = set(values) - names
        if unknown:
            raise ValueError(f"unknown policy config keys: {sorted(unknown)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})

    @classmethod
    def read(cls, path: Path) -> PolicyConfig:
        """The ``config`` entry of a model's ``policy.yaml`` (without loading the network); a file that
        does not hold one raises :class:`PolicyError` naming it."""
        try:
            return cls.from_dict(yaml.safe_load(Path(path).read_text())["config"])
        except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as error:
            raise PolicyError(f"{path}: not a policy configuration ({type(error).__name__}: {error})") from error

    def with_overrides(self, **changes: Any) -> PolicyConfig:
        """A copy with some fields changed."""
        return replace(self, **changes)


PRESETS: dict[str, PolicyConfig] = {
    "sorting": PolicyConfig(task="sorting", head="flow", action_dim=2, proprio_dim=4, embed_dim=128, obs_horizon=1,
                            horizon=8, exec_steps=4, sample_batch=32, action_space="ee_position"),
    "stacking": PolicyConfig(task="stacking", head="flow", action_dim=8, proprio_dim=11, embed_dim=128,
                             obs_horizon=2, horizon=8, exec_steps=4, sample_batch=32, action_space="joint_velocity"),
    "pusht": PolicyConfig(task="pusht", head="diffusion", action_dim=2, proprio_dim=4, embed_dim=64, obs_horizon=1,
                          horizon=16, exec_steps=8, sample_batch=256, action_space="ee_position",
                          unet_channels=(32, 64)),
}
"""Defaults per task (Table 4 / Table 5; every deviation from the paper is listed in docs/policies.md)."""
