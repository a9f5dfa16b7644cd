"""Reference generative policies (App. B.3): flow matching + transformer, DDPM + temporal U-Net.

Pure torch / numpy (no rclpy). ``Policy.load(dir)`` gives ``embed(obs_history) -> [E]`` (the
observation embedding ``O^e`` FIPER monitors) and ``sample(embedding, B, generator) -> [B, H, D]``
(the batch of action chunks, sampled in one batched pass).
"""
from __future__ import annotations

from fiper_ros.policy.errors import PolicyError

__all__ = ["PolicyError", "config", "dataset", "diffusion", "encoder", "errors", "fit", "flow_matching", "noise",
           "normalizer", "policy", "session", "time_embedding", "train", "transformer", "unet1d"]
