"""Rollout records: the per-policy-step data FIPER consumes (Sec. 3).

A rollout holds, for every policy timestep ``t = 0, h, 2h, ...`` (indexed ``0..T-1`` here), the
policy's observation embedding ``O_t^e = h(O_t)`` and the batch of ``B`` sampled action chunks
``A_t`` of length ``H`` (eq. 4), and optionally named per-step scalar signals the policy logs (e.g. features of
the executed chunk). :class:`RolloutSet` keeps the calibration and test splits and stores them in one versioned
``.npz`` file.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fiper_ros.core.detectors import SIGNAL_NAME
from fiper_ros.core.errors import CoreError

ACTION_SPACES = ("ee_position", "joint_position", "joint_velocity")
ID_SCENARIO = "id"
NPZ_FORMAT_VERSION = 1


class RolloutError(CoreError):
    """A rollout or rollout file is malformed."""


def check_signal_name(name: object, where: str) -> str:
    """``name`` if it is a signal name (:data:`~fiper_ros.core.detectors.SIGNAL_NAME`), else a :class:`RolloutError`
    starting with ``where``."""
    if not isinstance(name, str) or not SIGNAL_NAME.fullmatch(name):
        raise RolloutError(f"{where}: signal name {name!r} must match {SIGNAL_NAME.pattern} (lower-case letters, "
                           "digits and _, a letter first)")
    return name


def _check_finite(name: str, array: np.ndarray, rollout_id: str) -> None:
    if not np.all(np.isfinite(array)):
        bad = np.argwhere(~np.isfinite(array))[0].tolist()
        raise RolloutError(f"rollout {rollout_id!r}: {name} contains NaN/inf (first at index {bad})")


@dataclass
class Rollout:
    """One policy rollout.

    Attributes:
        rollout_id: Unique name.
        task: Task name, e.g. ``"push_t"``.
        scenario: ``"id"`` or the name of an OOD scenario.
        embeddings: Observation embeddings, float32 ``[T, E]``.
        actions: Sampled action-chunk batches, float32 ``[T, B, H, D]``; ``None`` for a rollout recorded
            without them (observation-only data: only RND-OE can score it).
        exec_steps: Executed actions per chunk, ``h`` (Sec. 3).
        success: Final outcome, ``None`` if unknown.
        action_space: ``"ee_position"``, ``"joint_position"`` or ``"joint_velocity"``.
        metadata: Free-form extras (JSON values or numpy arrays). For ``"joint_velocity"``
            rollouts ACE reads ``metadata["joint_positions"]`` (``[T, nq]``, the measured joint
            position at each policy step).
        signals: Named per-step scalar signals the policy logged, each float64 ``[T]`` and finite; a name
            matches :data:`~fiper_ros.core.detectors.SIGNAL_NAME`. Empty: none logged.
    """

    rollout_id: str
    task: str
    scenario: str
    embeddings: np.ndarray
    actions: np.ndarray | None
    exec_steps: int
    success: bool | None
    action_space: str = "ee_position"
    metadata: dict[str, Any] = field(default_factory=dict)
    signals: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.embeddings = np.ascontiguousarray(self.embeddings, dtype=np.float32)
        rid = self.rollout_id
        if self.embeddings.ndim != 2:
            raise RolloutError(f"rollout {rid!r}: embeddings must be [T, E], got shape {self.embeddings.shape}")
        if self.embeddings.shape[0] == 0:
            raise RolloutError(f"rollout {rid!r}: no steps")
        if self.embeddings.shape[1] < 1:
            raise RolloutError(f"rollout {rid!r}: empty dimension in embeddings {self.embeddings.shape}")
        _check_finite("embeddings", self.embeddings, rid)
        if self.action_space not in ACTION_SPACES:
            raise RolloutError(
                f"rollout {rid!r}: action_space must be one of {ACTION_SPACES}, got {self.action_space!r}"
            )
        if self.actions is not None:
            self._check_actions()
        elif int(self.exec_steps) < 1:
            raise RolloutError(f"rollout {rid!r}: exec_steps must be >= 1, got {self.exec_steps}")
        self.exec_steps = int(self.exec_steps)
        self.signals = {name: self._signal(name, values) for name, values in self.signals.items()}

    def _signal(self, name: object, values: object) -> np.ndarray:
        """One signal checked: a name of :data:`~fiper_ros.core.detectors.SIGNAL_NAME`, ``T`` finite values (as
        float64)."""
        rid = self.rollout_id
        check_signal_name(name, f"rollout {rid!r}")
        try:
            array = np.ascontiguousarray(values, dtype=np.float64)
        except (TypeError, ValueError) as error:
            raise RolloutError(f"rollout {rid!r}: signal {name!r} is not numbers ({error})") from error
        if array.shape != (self.length,):
            raise RolloutError(f"rollout {rid!r}: signal {name!r} has shape {array.shape}, expected ({self.length},) "
                               "(one value per step)")
        bad = np.flatnonzero(~np.isfinite(array))
        if bad.size:
            raise RolloutError(f"rollout {rid!r}: signal {name!r} is NaN/inf at step {int(bad[0])} (first)")
        return array

    def _check_actions(self) -> None:
        self.actions = np.ascontiguousarray(self.actions, dtype=np.float32)
        rid = self.rollout_id
        if self.actions.ndim != 4:
            raise RolloutError(f"rollout {rid!r}: actions must be [T, B, H, D], got shape {self.actions.shape} "
                               "(a rollout without action batches has actions=None)")
        if self.embeddings.shape[0] != self.actions.shape[0]:
            raise RolloutError(
                f"rollout {rid!r}: embeddings have T={self.embeddings.shape[0]} steps "
                f"but actions have T={self.actions.shape[0]}"
            )
        if min(self.actions.shape[1:]) < 1:
            raise RolloutError(f"rollout {rid!r}: empty dimension in actions {self.actions.shape}")
        _check_finite("actions", self.actions, rid)
        horizon = self.actions.shape[2]
        if not 1 <= int(self.exec_steps) <= horizon:
            raise RolloutError(f"rollout {rid!r}: exec_steps must be in [1, H={horizon}], got {self.exec_steps}")

    @property
    def has_actions(self) -> bool:
        """Whether the rollout holds its sampled action batches (ACE and the action baselines need them)."""
        return self.actions is not None

    @property
    def is_ood(self) -> bool:
        """Whether the rollout comes from an OOD scenario."""
        return self.scenario != ID_SCENARIO

    @property
    def length(self) -> int:
        """Number of policy steps ``T``."""
        return int(self.embeddings.shape[0])

    @property
    def failed(self) -> bool | None:
        """Whether the rollout failed (a positive, App. B.4); ``None`` if unknown."""
        return None if self.success is None else not self.success


def _header(rollout: Rollout) -> dict[str, Any]:
    return {
        "rollout_id": rollout.rollout_id,
        "task": rollout.task,
        "scenario": rollout.scenario,
        "exec_steps": rollout.exec_steps,
        "success": rollout.success,
        "action_space": rollout.action_space,
        "metadata_arrays": sorted(k for k, v in rollout.metadata.items() if isinstance(v, np.ndarray)),
        "metadata": {k: v for k, v in rollout.metadata.items() if not isinstance(v, np.ndarray)},
        "signals": sorted(rollout.signals),
    }


@dataclass
class RolloutSet:
    """Calibration and test rollouts of one task, stored as a versioned ``.npz`` file."""

    calibration: list[Rollout] = field(default_factory=list)
    test: list[Rollout] = field(default_factory=list)

    def save_npz(self, path: str | Path) -> None:
        """Write all rollouts to ``path`` (numpy ``.npz``, no pickles).

        Layout: ``__header__`` is a JSON string ``{"format_version", "splits": {name: [header]}}``;
        arrays are stored as ``{split}/{i}/embeddings``, ``{split}/{i}/actions`` (absent for a rollout without
        action batches), ``{split}/{i}/meta/{key}`` for array-valued metadata and ``{split}/{i}/signals/{name}``
        for the signals (their names in the rollout's header, ``signals``; a file without them, as written before
        signals existed, reads as rollouts without signals, and a reader of before them reads every other field of
        a file with them). Non-array metadata must be JSON.
        """
        arrays: dict[str, np.ndarray] = {}
        splits: dict[str, list[dict[str, Any]]] = {}
        for split, rollouts in (("calibration", self.calibration), ("test", self.test)):
            splits[split] = []
            for i, rollout in enumerate(rollouts):
                splits[split].append(_header(rollout))
                arrays[f"{split}/{i}/embeddings"] = rollout.embeddings
                if rollout.actions is not None:
                    arrays[f"{split}/{i}/actions"] = rollout.actions
                for key, value in rollout.metadata.items():
                    if isinstance(value, np.ndarray):
                        arrays[f"{split}/{i}/meta/{key}"] = value
                for name, values in rollout.signals.items():
                    arrays[f"{split}/{i}/signals/{name}"] = values
        try:
            header = json.dumps({"format_version": NPZ_FORMAT_VERSION, "splits": splits})
        except TypeError as error:
            raise RolloutError(f"rollout metadata must be JSON values or numpy arrays: {error}") from error
        with Path(path).open("wb") as stream:
            np.savez(stream, __header__=np.array(header), **arrays)

    @classmethod
    def load_npz(cls, path: str | Path) -> RolloutSet:
        """Read a file written by :meth:`save_npz`; a damaged or foreign file is a :class:`RolloutError`
        naming it."""
        path = Path(path)
        if not path.is_file():
            raise RolloutError(f"rollout file not found: {path}")
        try:
            return cls._read_npz(path)
        except RolloutError:
            raise
        except (OSError, EOFError, ValueError, KeyError, TypeError, zipfile.BadZipFile) as error:
            detail = " ".join(str(error).split())
            raise RolloutError(f"{path}: not a readable rollout set, damaged or not written by save_npz "
                               f"({type(error).__name__}: {detail})") from error

    @classmethod
    def _read_npz(cls, path: Path) -> RolloutSet:
        with np.load(path, allow_pickle=False) as data:
            if "__header__" not in data:
                raise RolloutError(f"{path}: not a rollout set (no __header__)")
            header = json.loads(str(data["__header__"]))
            version = header.get("format_version")
            if version != NPZ_FORMAT_VERSION:
                raise RolloutError(f"{path}: format_version {version!r} not supported (expected {NPZ_FORMAT_VERSION})")
            result = cls()
            for split in ("calibration", "test"):
                for i, head in enumerate(header["splits"].get(split, [])):
                    metadata = dict(head["metadata"])
                    for key in head["metadata_arrays"]:
                        metadata[key] = data[f"{split}/{i}/meta/{key}"]
                    getattr(result, split).append(
                        Rollout(
                            rollout_id=head["rollout_id"],
                            task=head["task"],
                            scenario=head["scenario"],
                            embeddings=data[f"{split}/{i}/embeddings"],
                            actions=data[actions] if (actions := f"{split}/{i}/actions") in data else None,
                            exec_steps=head["exec_steps"],
                            success=head["success"],
                            action_space=head["action_space"],
                            metadata=metadata,
                            signals={name: data[f"{split}/{i}/signals/{name}"] for name in head.get("signals", [])},
                        )
                    )
        return result

    def max_length(self) -> int:
        """Longest rollout over both splits (the reference code's ``T_max``, App. B.4)."""
        lengths = [r.length for r in (*self.calibration, *self.test)]
        return max(lengths) if lengths else 0


def successful(rollouts: list[Rollout]) -> list[Rollout]:
    """The rollouts with ``success is True`` (the calibration data ``D_c`` of Sec. 4.3)."""
    return [r for r in rollouts if r.success is True]
