"""The index of a ``fiper collect`` folder: ``DIR/collect.json``.

It names what produced the folder's bags (task, policy model and its hash, split, batch size, policy-step
cap, in-process or through ROS: :class:`CollectSetup`, which a resumed run must match), the knobs of every
scenario collected (a resumed scenario must have the same ones), the settings of every run into the
folder, and one entry per rollout (scenario, seed, outcome, steps, bag path). An entry
is written before its bag, and the file is replaced atomically, so after a kill the index lists every
complete bag; entries whose bag never appeared are dropped when the index is read. A runner's episode is a
:class:`RanEpisode` until its bag is written.
"""
from __future__ import annotations

import json
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import MISSING, asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from fiper_ros.bagio.atomic import temporary_sibling
from fiper_ros.bagio.errors import BagError
from fiper_ros.bagio.reader import METADATA

INDEX_FILE = "collect.json"
#: Version of the index layout, stored as ``"format"``.
INDEX_FORMAT = 1
#: How the rollouts were produced: in the collecting process, or through the live ROS node suite.
IN_PROCESS, ROS = "in-process", "ros"
#: A scenario's knob ranges as JSON stores them: knob -> [low, high].
Knobs = dict[str, list[float]]


@dataclass(frozen=True)
class CollectSetup:
    """What makes the rollouts of a folder comparable; a run into an existing folder must match it.

    Attributes:
        task: The sim's task name.
        policy_hash: SHA-256 of the model's ``policy.pt`` and ``policy.yaml``.
        split: ``calibration`` or ``test`` (the bags' ``custom_data`` split).
        batch: ``B``, chunks sampled per policy step.
        max_policy_steps: Policy-step cap of a smoke run (None: the task's time limit).
        runner: :data:`IN_PROCESS` or :data:`ROS` (an index without the key is from before ``--ros``:
            in-process).
    """

    task: str
    policy_hash: str
    split: str
    batch: int
    max_policy_steps: int | None
    runner: str = IN_PROCESS

    def differences(self, other: CollectSetup) -> list[str]:
        """``name: ours != theirs`` for every field that differs."""
        return [f"{item.name} {getattr(self, item.name)!r} != {getattr(other, item.name)!r}"
                for item in fields(self) if getattr(self, item.name) != getattr(other, item.name)]


@dataclass(frozen=True)
class IndexEntry:
    """One collected rollout.

    Attributes:
        scenario: Scenario name.
        seed: Episode seed.
        success: The episode's outcome.
        policy_steps: ``T``, policy steps of the rollout.
        control_steps: Control steps executed.
        bag: The bag directory, relative to the folder.
        rollout_id: ``rollout_id`` of the bag's messages.
        seconds: Wall time of the episode and its bag.
    """

    scenario: str
    seed: int
    success: bool
    policy_steps: int
    control_steps: int
    bag: str
    rollout_id: int
    seconds: float


@dataclass
class CollectIndex:
    """The index of one folder: setup, model, runs and rollouts (keyed by ``(scenario, seed)``)."""

    setup: CollectSetup
    policy: str
    policy_data_hash: str
    runs: list[dict[str, Any]] = field(default_factory=list)
    rollouts: dict[tuple[str, int], IndexEntry] = field(default_factory=dict)
    scenarios: dict[str, Knobs] = field(default_factory=dict)
    """Knob ranges of each scenario collected into the folder (an index from before this field: empty)."""

    def use_scenario(self, name: str, ranges: Mapping[str, Sequence[float]]) -> None:
        """Record ``name``'s knob ranges, or refuse if the folder's rollouts of ``name`` had other ones."""
        knobs = {key: [float(v) for v in bounds] for key, bounds in sorted(ranges.items())}
        recorded = self.scenarios.setdefault(name, knobs)
        if recorded != knobs:
            raise BagError(f"scenario {name!r} has changed since its rollouts in this folder were collected "
                           f"(knobs {recorded} then, {knobs} now): remove its folder or choose another --out")

    def add_run(self, settings: dict[str, Any]) -> None:
        """Record the settings of a run (a rerun with the same settings is recorded once)."""
        if not self.runs or self.runs[-1] != settings:
            self.runs.append(dict(settings))

    def to_json(self) -> dict[str, Any]:
        """The JSON document."""
        return {"format": INDEX_FORMAT, **asdict(self.setup), "policy": self.policy,
                "policy_data_hash": self.policy_data_hash, "scenarios": self.scenarios, "runs": self.runs,
                "rollouts": [asdict(self.rollouts[key]) for key in sorted(self.rollouts)]}

    def save(self, directory: Path) -> None:
        """Write ``directory/collect.json``, atomically replacing the previous index."""
        path = directory / INDEX_FILE
        temporary = temporary_sibling(path)
        temporary.write_text(json.dumps(self.to_json(), indent=1) + "\n")
        os.replace(temporary, path)

    @classmethod
    def load(cls, directory: Path) -> CollectIndex | None:
        """The index of ``directory`` (None if there is none), without entries whose bag is missing."""
        path = directory / INDEX_FILE
        if not path.is_file():
            return None
        try:
            document = json.loads(path.read_text())
            if document.get("format") != INDEX_FORMAT:
                raise BagError(f"{path}: index format {document.get('format')!r}, this code reads {INDEX_FORMAT}")
            setup = CollectSetup(**{item.name: document[item.name] for item in fields(CollectSetup)
                                    if item.default is MISSING or item.name in document})
            entries = [IndexEntry(**entry) for entry in document["rollouts"]]
            index = cls(setup, str(document["policy"]), str(document["policy_data_hash"]), list(document["runs"]),
                        scenarios=dict(document.get("scenarios", {})))
        except (OSError, ValueError, KeyError, TypeError, AttributeError) as error:
            raise BagError(f"{path}: not a readable fiper collect index ({type(error).__name__}: {error})") from error
        index.rollouts = {(e.scenario, e.seed): e for e in entries if (directory / e.bag / METADATA).is_file()}
        return index


@dataclass(frozen=True)
class RanEpisode:
    """An episode that ran; its bag is not there yet.

    Attributes:
        success: The episode's outcome.
        policy_steps: ``T``, policy steps of the rollout.
        control_steps: Control steps executed.
        rollout_id: ``rollout_id`` of the bag's messages.
        write: Makes the episode's bag appear, complete, at its path.
    """

    success: bool
    policy_steps: int
    control_steps: int
    rollout_id: int
    write: Callable[[], None]
