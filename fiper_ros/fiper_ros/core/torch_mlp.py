"""The torch side of :mod:`fiper_ros.core.mlp`: the builder with the paper's initialisation, which trains.

RND-OE's training (:mod:`fiper_ros.core.rnd_train`), the RND-A and logpZO baselines build their networks
here; :func:`parameters_of` hands a trained network to the numpy forward pass
(:class:`fiper_ros.core.mlp.NumpyMLP`) the scoring code uses.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import torch
from torch import nn

from fiper_ros.core.mlp import LEAKY_SLOPE, LayerSpec, linear_indices


def build_mlp(in_dim: int, layers: Sequence[LayerSpec], generator: torch.Generator) -> nn.Sequential:
    """Linear layers with the given activations; orthogonal init (gain ``sqrt(2)``), zero bias."""
    linear_indices(layers)  # refuses an unknown activation
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
        width = out_dim
    return nn.Sequential(*modules)


def parameters_of(network: nn.Module) -> dict[str, np.ndarray]:
    """The network's state dict as float32 numpy arrays (copies), named as torch names them."""
    return {name: tensor.detach().cpu().numpy().astype(np.float32, copy=True)
            for name, tensor in network.state_dict().items()}
