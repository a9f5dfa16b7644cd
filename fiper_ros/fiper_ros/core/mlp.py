"""Fully connected networks for random network distillation (App. A.2), in torch and numpy.

RND-OE (:mod:`fiper_ros.core.rnd_oe`) and the RND-A baseline share these pieces: a builder with the
paper's initialisation (orthogonal weights with gain ``sqrt(2)``, zero biases) and a numpy forward
pass over cached float32 weights, which is faster than torch for a single input on a CPU.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

LayerSpec = tuple[int, str | None]
"""``(out_features, activation)`` of one linear layer; activation ``"leaky_relu"``, ``"relu"`` or None."""

ACTIVATIONS = ("leaky_relu", "relu")
LEAKY_SLOPE = 0.01  # torch's nn.LeakyReLU default


def build_mlp(in_dim: int, layers: Sequence[LayerSpec], generator: torch.Generator) -> nn.Sequential:
    """Linear layers with the given activations; orthogonal init (gain ``sqrt(2)``), zero bias."""
    modules: list[nn.Module] = []
    width = in_dim
    for out_dim, activation in layers:
        linear = nn.Linear(width, out_dim)
        with torch.no_grad():
            nn.init.orthogonal_(linear.weight, gain=math.sqrt(2.0), generator=generator)
            nn.init.zeros_(linear.bias)
        modules.append(linear)
        if activation == "leaky_relu":
            modules.append(nn.LeakyReLU(LEAKY_SLOPE))
        elif activation == "relu":
            modules.append(nn.ReLU())
        elif activation is not None:
            raise ValueError(f"unknown activation {activation!r}; expected one of {ACTIVATIONS} or None")
        width = out_dim
    return nn.Sequential(*modules)


class NumpyMLP:
    """Numpy float32 forward pass of a :func:`build_mlp` network (weights copied at construction)."""

    def __init__(self, network: nn.Sequential) -> None:
        self.layers: list[tuple[np.ndarray, np.ndarray, str | None]] = []
        for module in network:
            if isinstance(module, nn.Linear):
                weight = module.weight.detach().cpu().numpy().astype(np.float32).T.copy()
                bias = module.bias.detach().cpu().numpy().astype(np.float32).copy()
                self.layers.append((weight, bias, None))
            elif isinstance(module, (nn.LeakyReLU, nn.ReLU)):
                weight, bias, _ = self.layers[-1]
                self.layers[-1] = (weight, bias, "leaky_relu" if isinstance(module, nn.LeakyReLU) else "relu")
            else:
                raise TypeError(f"unsupported module {type(module).__name__}")

    def __call__(self, x: np.ndarray, dtype: type[np.floating] = np.float32) -> np.ndarray:
        """Forward ``x [..., in]`` -> ``[..., out]`` in float32, or in ``dtype`` (e.g. float64 for inputs whose
        float32 activations would overflow; the weights are converted on the fly)."""
        h = np.asarray(x, dtype=dtype)
        for weight, bias, activation in self.layers:
            h = h @ weight.astype(dtype, copy=False)
            h += bias.astype(dtype, copy=False)
            if activation == "leaky_relu":
                np.maximum(h, LEAKY_SLOPE * h, out=h)
            elif activation == "relu":
                np.maximum(h, 0.0, out=h)
        return h


def state_digest(*networks: nn.Module) -> str:
    """SHA-256 over the parameter names and float32 values of the networks (for content hashes)."""
    digest = hashlib.sha256()
    for index, network in enumerate(networks):
        for name, tensor in sorted(network.state_dict().items()):
            digest.update(f"{index}/{name}/{tuple(tensor.shape)}".encode())
            digest.update(tensor.detach().cpu().numpy().astype(np.float32).tobytes())
    return digest.hexdigest()
