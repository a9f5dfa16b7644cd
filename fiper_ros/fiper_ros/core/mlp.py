"""Fully connected networks for random network distillation (App. A.2): their parameters and a numpy forward pass.

RND-OE (:mod:`fiper_ros.core.rnd_oe`) scores with these pieces, without torch: the parameters of a network
are a mapping from the names a torch ``nn.Sequential`` gives them (``"0.weight"`` ``[out, in]``,
``"0.bias"`` ``[out]``, the next linear layer at index 1 or 2 as an activation sits between) to float32
arrays. The torch builder with the paper's initialisation, which trains them, is
:func:`fiper_ros.core.torch_mlp.build_mlp`; a numpy forward pass is faster than torch for a single input on a
CPU, and the same numbers wherever a score is computed (calibration, nodes, replay).
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence

import numpy as np

from fiper_ros.core.errors import CoreError

LayerSpec = tuple[int, str | None]
"""``(out_features, activation)`` of one linear layer; activation ``"leaky_relu"``, ``"relu"`` or None."""

ACTIVATIONS = ("leaky_relu", "relu")
LEAKY_SLOPE = 0.01  # torch's nn.LeakyReLU default

#: A network's parameters: name (as in a torch ``nn.Sequential``'s state dict) -> float32 array.
Parameters = Mapping[str, np.ndarray]


class MLPError(CoreError):
    """Parameters that do not match the network's layer specification."""


def linear_indices(layers: Sequence[LayerSpec]) -> list[int]:
    """Index of each linear layer in the ``nn.Sequential`` of ``layers`` (an activation takes one index)."""
    indices, index = [], 0
    for _, activation in layers:
        if activation is not None and activation not in ACTIVATIONS:
            raise MLPError(f"unknown activation {activation!r}; expected one of {ACTIVATIONS} or None")
        indices.append(index)
        index += 1 if activation is None else 2
    return indices


def parameter_shapes(in_dim: int, layers: Sequence[LayerSpec]) -> dict[str, tuple[int, ...]]:
    """Name -> shape of every parameter of the network ``in_dim`` -> ``layers``."""
    shapes: dict[str, tuple[int, ...]] = {}
    width = in_dim
    for index, (out_dim, _) in zip(linear_indices(layers), layers):
        shapes[f"{index}.weight"] = (out_dim, width)
        shapes[f"{index}.bias"] = (out_dim,)
        width = out_dim
    return shapes


class NumpyMLP:
    """Numpy float32 forward pass of the network ``in_dim`` -> ``layers`` with the given parameters."""

    def __init__(self, in_dim: int, layers: Sequence[LayerSpec], parameters: Parameters) -> None:
        shapes = parameter_shapes(in_dim, layers)
        if set(parameters) != set(shapes):
            raise MLPError(f"parameters {sorted(parameters)} do not match the layers' {sorted(shapes)}")
        for name, shape in shapes.items():
            array = parameters[name]
            if array.shape != shape or array.dtype != np.float32:
                raise MLPError(f"parameter {name}: expected float32 {shape}, got {array.dtype} {array.shape}")
        self._indices = linear_indices(layers)
        # The weights transposed (``[in, out]``, C order) for ``x @ W``, each parameter held once.
        self.layers: list[tuple[np.ndarray, np.ndarray, str | None]] = [
            (parameters[f"{index}.weight"].T.copy(), np.array(parameters[f"{index}.bias"]), activation)
            for index, (_, activation) in zip(self._indices, layers)]

    @property
    def parameters(self) -> dict[str, np.ndarray]:
        """The parameters by name (read-only views: the weights ``[out, in]`` as given, not C-contiguous)."""
        named: dict[str, np.ndarray] = {}
        for index, (weight, bias, _) in zip(self._indices, self.layers):
            named[f"{index}.weight"], named[f"{index}.bias"] = weight.T, bias.view()
        for view in named.values():
            view.flags.writeable = False
        return named

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


def state_digest(*networks: Parameters) -> str:
    """SHA-256 over the parameter names, shapes and float32 values of the networks (for content hashes)."""
    digest = hashlib.sha256()
    for index, network in enumerate(networks):
        for name, array in sorted(network.items()):
            digest.update(f"{index}/{name}/{tuple(array.shape)}".encode())
            digest.update(np.asarray(array, dtype=np.float32).tobytes())
    return digest.hexdigest()
