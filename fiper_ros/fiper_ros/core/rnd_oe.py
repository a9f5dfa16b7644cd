"""Random network distillation on observation embeddings (RND-OE), eq. (1) and App. A.2.

A frozen, randomly initialised target network ``g`` and a trained predictor ``f_theta`` map an
observation embedding ``O_t^e`` to ``R^m``; the RND-OE score is ``s_RND(O_t) = ||f(O_t) - g(O_t)||_2``
(eq. 1) and training minimises its mean over the ID calibration steps.

Architecture (App. A.2): target ``E-1024-2048-4096-m`` with LeakyReLU after every layer but the
last; predictor the same trunk, then ``2048-1024`` with ReLU, then ``m``. :meth:`RNDConfig.paper`
is that model (``m = 512`` as in the authors' code); :meth:`RNDConfig.small` is the CPU default.

This module is the model as it scores, in numpy and without torch (the scoring nodes import it): both
networks' float32 parameters, the score of eq. (1), and the files ``rnd_oe.npz`` (the parameters, named as
torch names them) and ``rnd_oe.json`` (dimension, configuration, seed). The training (App. A.2,
training-parameter table: AdamW, cosine schedule, early stopping) is torch's, in
:mod:`fiper_ros.core.rnd_train`, which hands the trained parameters over to :class:`RNDOE`.
"""

from __future__ import annotations

import json
import math
import zipfile
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fiper_ros.core.errors import CoreError
from fiper_ros.core.mlp import LayerSpec, MLPError, NumpyMLP, Parameters, parameter_shapes, state_digest

WEIGHTS_FILE = "rnd_oe.npz"
CONFIG_FILE = "rnd_oe.json"
#: The weights file of calibration format 1 (a torch state dict, read only to convert it: ``fiper calibrate
#: --upgrade``, :func:`fiper_ros.core.rnd_train.read_legacy`).
LEGACY_WEIGHTS_FILE = "rnd_oe.pt"
#: The two networks, in the order of the weights file's names and of :meth:`RNDOE.digest`.
NETWORKS = ("target", "predictor")


class RNDError(CoreError):
    """Bad RND-OE input, configuration or model files."""


@dataclass(frozen=True)
class RNDConfig:
    """Network sizes and training parameters of an RND model.

    Attributes:
        trunk: Hidden widths shared by target and predictor (LeakyReLU).
        head: Extra predictor widths after the trunk (ReLU).
        out_dim: Output dimension ``m``.
    """

    trunk: tuple[int, ...] = (256, 256)
    head: tuple[int, ...] = (256,)
    out_dim: int = 64
    batch_size: int = 256
    max_epochs: int = 250
    lr: float = 1e-4
    lr_min: float = 1e-6
    weight_decay: float = 1e-5
    eps: float = 1e-8
    patience: int = 7
    val_fraction: float = 0.1

    def __post_init__(self) -> None:
        if self.max_epochs < 1:
            raise RNDError(f"RND-OE needs at least one training epoch, got max_epochs {self.max_epochs}")

    @classmethod
    def paper(cls) -> RNDConfig:
        """The paper's model: ``E-1024-2048-4096-m`` target, ``...-2048-1024-m`` predictor, ``m = 512``."""
        return cls(trunk=(1024, 2048, 4096), head=(2048, 1024), out_dim=512)

    @classmethod
    def small(cls) -> RNDConfig:
        """CPU default: ``E-256-256-64`` target, ``E-256-256-256-64`` predictor."""
        return cls()

    def target_layers(self) -> list[LayerSpec]:
        """Layer specification of ``g``."""
        return [*((w, "leaky_relu") for w in self.trunk), (self.out_dim, None)]

    def predictor_layers(self) -> list[LayerSpec]:
        """Layer specification of ``f_theta``."""
        return [*((w, "leaky_relu") for w in self.trunk), *((w, "relu") for w in self.head), (self.out_dim, None)]

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form (lists instead of tuples) for YAML/JSON."""
        data = asdict(self)
        data["trunk"] = list(self.trunk)
        data["head"] = list(self.head)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RNDConfig:
        """Inverse of :meth:`to_dict`."""
        data = dict(data)
        data["trunk"] = tuple(data["trunk"])
        data["head"] = tuple(data["head"])
        return cls(**data)


@dataclass(frozen=True)
class TrainProgress:
    """Reported after every training epoch."""

    epoch: int
    max_epochs: int
    train_loss: float
    val_loss: float
    best_val_loss: float


ProgressCallback = Callable[[TrainProgress], None]


def check_embeddings(x: np.ndarray, embedding_dim: int) -> np.ndarray:
    """``x`` as float32 ``[N, embedding_dim]``; :class:`RNDError` for another shape or a NaN/inf entry."""
    x = np.asarray(x, dtype=np.float32)
    if x.ndim != 2 or x.shape[1] != embedding_dim:
        raise RNDError(f"expected embeddings [N, {embedding_dim}], got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise RNDError("embeddings contain NaN/inf")
    return x


class RNDOE:
    """A trained (or untrained) RND-OE model: target ``g`` and predictor ``f_theta`` as float32 parameters.

    Fitted by :func:`fiper_ros.core.rnd_train.fit_rnd`, read by :meth:`load`; ``target`` and ``predictor`` are
    the networks' parameters (:data:`fiper_ros.core.mlp.Parameters`), checked against ``config``'s layers.
    """

    def __init__(self, embedding_dim: int, config: RNDConfig, seed: int, target: Parameters,
                 predictor: Parameters) -> None:
        if embedding_dim < 1:
            raise RNDError(f"embedding_dim must be >= 1, got {embedding_dim}")
        self.embedding_dim = int(embedding_dim)
        self.config = config
        self.seed = int(seed)
        try:
            self._target = NumpyMLP(self.embedding_dim, config.target_layers(), target)
            self._predictor = NumpyMLP(self.embedding_dim, config.predictor_layers(), predictor)
        except MLPError as error:
            raise RNDError(f"RND-OE networks: {error}") from error

    def parameters(self) -> dict[str, dict[str, np.ndarray]]:
        """``{"target": ..., "predictor": ...}``: both networks' parameters (read-only views)."""
        return {"target": self._target.parameters, "predictor": self._predictor.parameters}

    def score_one(self, x: np.ndarray) -> float:
        """RND-OE score of one embedding ``[E]`` with the float32 weights (eq. 1).

        Where float32 overflows (an activation beyond 3.4e38, or ``inf - inf`` in the difference), the
        score is computed again in float64, which holds every finite float32 input; a score that is still
        not finite is returned as such for the caller to reject (:func:`fiper_ros.core.scores.obs_score`).
        """
        x = np.asarray(x, dtype=np.float32)
        if x.shape != (self.embedding_dim,):
            raise RNDError(f"expected one embedding of shape ({self.embedding_dim},), got {x.shape}")
        with np.errstate(over="ignore", invalid="ignore"):
            diff = self._predictor(x) - self._target(x)
            score = float(np.sqrt(np.dot(diff, diff)))
            if not np.isfinite(score):
                diff = self._predictor(x, np.float64) - self._target(x, np.float64)
                score = float(np.sqrt(np.dot(diff, diff)))
        return score

    def digest(self) -> str:
        """SHA-256 over both networks' weights (the same as over the torch state dicts they came from)."""
        return state_digest(self._target.parameters, self._predictor.parameters)

    def describe(self) -> dict[str, Any]:
        """The content of ``rnd_oe.json``: dimension, seed and configuration."""
        return {"embedding_dim": self.embedding_dim, "seed": self.seed, "config": self.config.to_dict()}

    def save(self, directory: str | Path) -> None:
        """Write ``rnd_oe.npz`` (both networks' parameters, ``target/<name>``, ``predictor/<name>``) and
        ``rnd_oe.json`` (:meth:`describe`)."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        arrays = {f"{network}/{name}": np.ascontiguousarray(array) for network, parameters in self.parameters().items()
                  for name, array in parameters.items()}
        with (directory / WEIGHTS_FILE).open("wb") as stream:
            np.savez(stream, **arrays)
        (directory / CONFIG_FILE).write_text(json.dumps(self.describe(), indent=2) + "\n")

    @classmethod
    def load(cls, directory: str | Path) -> RNDOE:
        """Read a model written by :meth:`save` (numpy only)."""
        directory = Path(directory)
        for name in (WEIGHTS_FILE, CONFIG_FILE):
            if not (directory / name).is_file():
                raise RNDError(f"RND-OE model file missing: {directory / name}")
        meta = json.loads((directory / CONFIG_FILE).read_text())
        config = RNDConfig.from_dict(meta["config"])
        dim = int(meta["embedding_dim"])
        shapes = {f"{network}/{name}": shape for network, layers in zip(NETWORKS, (config.target_layers(),
                                                                                   config.predictor_layers()))
                  for name, shape in parameter_shapes(dim, layers).items()}
        arrays = read_arrays(directory / WEIGHTS_FILE, shapes)
        split = {network: {name.split("/", 1)[1]: array for name, array in arrays.items()
                           if name.startswith(f"{network}/")} for network in NETWORKS}
        return cls(dim, config, meta["seed"], split["target"], split["predictor"])


_NPY_HEADERS = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}


def read_arrays(path: Path, shapes: dict[str, tuple[int, ...]]) -> dict[str, np.ndarray]:
    """The float32 arrays of the ``.npz`` file ``path``, exactly those ``shapes`` names with those shapes: each
    array's header is checked before its data is read, so a damaged or foreign file never makes this read
    more than the described network."""
    try:
        with zipfile.ZipFile(path) as archive:
            members = sorted(archive.namelist())
            if members != sorted(f"{name}.npy" for name in shapes):
                raise RNDError(f"{path}: holds {len(members)} arrays, not the {len(shapes)} of the described network")
            arrays = {}
            for name, shape in shapes.items():
                with archive.open(f"{name}.npy") as member:
                    header = _NPY_HEADERS.get(np.lib.format.read_magic(member))
                    if header is None:
                        raise RNDError(f"{path}: {name}: unsupported .npy format version")
                    got, fortran, dtype = header(member)
                    if got != shape or fortran or dtype != np.dtype("<f4"):
                        raise RNDError(f"{path}: {name}: expected float32 {shape}, got {dtype} {got}")
                    size = 4 * math.prod(shape)
                    data = member.read(size + 1)
                    if len(data) != size:
                        raise RNDError(f"{path}: {name}: {len(data)} bytes of data, expected {size}")
                    arrays[name] = np.frombuffer(data, dtype="<f4").reshape(shape)
            return arrays
    except (OSError, EOFError, ValueError, zipfile.BadZipFile) as error:
        if isinstance(error, RNDError):
            raise
        raise RNDError(f"{path}: unreadable ({type(error).__name__}: {error})") from error
