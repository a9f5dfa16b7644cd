"""Loader of the FIPER authors' rollout pickles (docs/bags.md, "Converters").

Layout: ``<task>/rollouts/{calibration,test}/*.pkl``, one pickle per rollout holding
``{"metadata": {...}, "rollout": [step, ...]}``; each step a dict with ``obs_embedding`` ``(E,)`` and
``action_pred`` ``(B, H, A)`` (other keys such as ``action``, ``agent_pos``, ``rgb`` are ignored).
Success is ``metadata["successful"]`` if present, else read from the file name (``success`` / ``_s_``
vs ``failure`` / ``_f_``; a name with neither counts as a success, as in the authors' code).
``metadata["rollout_subtype"]`` in {ca, id, calibration, na} is the ID scenario; any other subtype is
kept as the (OOD) scenario name.

Unpickling runs code from the file: load pickles only from sources you trust.
"""
from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any

import numpy as np

from fiper_ros.bagio.errors import BagError
from fiper_ros.converters.options import Budget, ConvertOptions, Converted, select_channels
from fiper_ros.core.rollout import ID_SCENARIO, Rollout, RolloutError

SPLITS = ("calibration", "test")
ID_SUBTYPES = frozenset({"ca", "id", "calibration", "na"})


def rollouts_root(src: Path) -> Path:
    """The directory holding ``calibration/`` and ``test/``: ``src/rollouts`` or ``src`` itself."""
    for candidate in (src / "rollouts", src):
        if any((candidate / split).is_dir() for split in SPLITS):
            return candidate
    raise BagError(f"{src}: no rollouts/calibration or rollouts/test directory (FIPER layout <task>/rollouts/<split>/)")


def success_of(metadata: dict[str, Any], file_name: str) -> bool:
    """The outcome: ``metadata["successful"]``, else the file name's marker (neither = success)."""
    if "successful" in metadata:
        return bool(metadata["successful"])
    name = file_name.lower()
    return not ("failure" in name or "_f_" in name)


def scenario_of(metadata: dict[str, Any], split: str) -> str:
    """``"id"`` for the ID subtypes (and calibration rollouts without one), else the subtype."""
    subtype = metadata.get("rollout_subtype")
    if subtype is None:
        return ID_SCENARIO if split == "calibration" else "unknown"
    return ID_SCENARIO if str(subtype).lower() in ID_SUBTYPES else str(subtype)


def _load(path: Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    try:
        with path.open("rb") as stream:
            content = pickle.load(stream)  # noqa: S301 - trusted sources only (documented)
    except Exception as error:  # any unpickling failure is a bad file
        raise BagError(f"{path}: not a readable pickle ({type(error).__name__}: {error})") from error
    if not isinstance(content, dict) or not isinstance(content.get("rollout"), list):
        raise BagError(f"{path}: not a FIPER rollout pickle (expected a dict with a 'rollout' list)")
    metadata = content.get("metadata") or {}
    if not isinstance(metadata, dict):
        raise BagError(f"{path}: 'metadata' is not a dict")
    return metadata, content["rollout"]


def load_rollout(path: Path, split: str, task: str, options: ConvertOptions) -> Rollout:
    """One rollout pickle as a core Rollout."""
    metadata, steps = _load(path)
    if not steps:
        raise BagError(f"{path}: the rollout has no steps")
    try:
        embeddings = np.stack([np.asarray(s["obs_embedding"], dtype=np.float32).ravel() for s in steps])
        actions = np.stack([np.asarray(s["action_pred"], dtype=np.float32) for s in steps])
    except KeyError as error:
        raise BagError(f"{path}: a step has no {error} entry") from error
    except ValueError as error:
        raise BagError(f"{path}: steps of different shapes ({error})") from error
    if actions.ndim != 4:
        raise BagError(f"{path}: action_pred must be (B, H, A), got {actions.shape[1:]}")
    try:
        return Rollout(
            rollout_id=path.stem, task=task, scenario=scenario_of(metadata, split), embeddings=embeddings,
            actions=select_channels(actions, options.channels, path), exec_steps=options.exec_steps_for(task, path),
            success=success_of(metadata, path.name), action_space=options.action_space,
            metadata={"max_steps": options.max_steps},
        )
    except RolloutError as error:
        raise BagError(f"{path}: {error}") from error


def load(src: Path, options: ConvertOptions) -> Converted:
    """Every rollout under ``src`` by split, with its source file name (relative to the rollouts root)."""
    root = rollouts_root(src)
    task = options.task or (root.parent.name if root.name == "rollouts" else root.name)
    converted: Converted = {}
    budget = Budget(options.max_mb)
    for split in SPLITS:
        for path in sorted((root / split).glob("*.pkl")):
            budget.check_file(path, path.stat().st_size)
            rollout = load_rollout(path, split, task, options)
            budget.take(str(path), rollout)
            converted.setdefault(split, []).append((rollout, str(path.relative_to(root))))
    if not converted:
        raise BagError(f"{root}: no *.pkl rollout files in {' or '.join(SPLITS)}/")
    return converted
