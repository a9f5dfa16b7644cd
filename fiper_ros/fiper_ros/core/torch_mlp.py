"""The torch side of :mod:`fiper_ros.core.mlp`: the builder with the paper's initialisation, and the pieces of a
training loop shared by RND-OE, logpZO and RND-A.

RND-OE's training (:mod:`fiper_ros.core.rnd_train`), logpZO's (:mod:`fiper_ros.core.logpzo_train`) and the RND-A
baseline build their networks here and train them epoch by epoch with :func:`train_epoch`;
:func:`parameters_of` hands a trained network to the numpy forward pass (:class:`fiper_ros.core.mlp.NumpyMLP`)
the scoring code uses.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

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


@contextmanager
def deterministic() -> Iterator[None]:
    """Run the enclosed torch code with ``torch.use_deterministic_algorithms`` (warnings only where an operation
    has no deterministic form), restoring the previous setting."""
    previous = torch.are_deterministic_algorithms_enabled()
    torch.use_deterministic_algorithms(True, warn_only=True)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(previous)


def train_epoch(optimizer: torch.optim.Optimizer, order: torch.Tensor, batch_size: int,
                loss_of: Callable[[torch.Tensor], torch.Tensor]) -> float:
    """One epoch: the sample indices ``order`` in batches of ``batch_size`` (the last one shorter), each a step of
    ``optimizer`` on ``loss_of(batch_indices)`` (a mean over the batch); returns the mean loss over the samples."""
    total = 0.0
    for start in range(0, order.shape[0], batch_size):
        batch = order[start : start + batch_size]
        loss = loss_of(batch)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        total += float(loss.detach()) * batch.shape[0]
    return total / order.shape[0]
