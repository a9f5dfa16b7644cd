"""``fiper evaluate --dump DIR``: every configuration's thresholds per step and first alarm per rollout.

So that two implementations can be compared cell by cell, the sweep's own arrays (the thresholds the alarms were
decided with, and the first alarms) are written, per task and seed, to one ``.npz`` file, and one ``index.json``
names the configurations and the files (docs/evaluation.md, "The dump"):

- ``index.json``: ``format`` (:data:`FORMAT`), ``version`` (:data:`VERSION`), the run's ``profile``,
  ``calibration_split`` and ``deltas``, the ``configurations`` in the order of the arrays' first axis (method,
  window, threshold kind, combine, and the ``detectors`` whose thresholds it has, in order), and ``files``: per
  task and seed its file, the file's SHA-256, its test rollouts and steps.
- ``<task>_seed<seed>.npz``: ``rollout_ids`` ``[N]`` (the test rollouts, in order), ``lengths`` ``[N]`` (their
  policy steps), ``alarms`` ``int32 [configurations, deltas, N]`` (the first alarm step, -1 for none),
  ``thresholds`` ``float64 [R, T]`` (distinct threshold curves ``gamma_t`` over the task's ``T`` test steps, each
  extended past its calibration length by its rule; ``inf`` where the conformal quantile is ``+inf``) and
  ``threshold_rows`` ``int32 [configurations, deltas, D]`` (the row of ``thresholds`` of each of the
  configuration's detectors, -1 past its own number of detectors; FIPER's rows are those of RND-OE and ACE alone
  at its windows).

Writing happens only with ``--dump``: the sweep keeps the thresholds only then.
"""

from __future__ import annotations

import hashlib
import json
import re
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from fiper_ros.evaluation.data import Dataset
from fiper_ros.evaluation.sweep import Group, TaskSweep

FORMAT = "fiper-evaluate-dump"
VERSION = 1
INDEX = "index.json"


def file_name(task: str, seed: int) -> str:
    """``<task>_seed<seed>.npz``, the task's characters other than letters, digits, ``.``, ``-`` and ``_`` as ``_``."""
    return f"{re.sub(r'[^A-Za-z0-9_.-]', '_', task)}_seed{seed}.npz"


def _distinct_rows(groups: list[Group], thresholds: list[np.ndarray], detectors: Mapping[str, tuple[str, ...]],
                   deltas: int) -> tuple[np.ndarray, np.ndarray]:
    """The distinct threshold curves ``[R, T]`` and every (configuration, delta, detector)'s row of them."""
    width = max(len(detectors[g.method]) for g in groups)
    rows = np.full((len(groups), deltas, width), -1, dtype=np.int32)
    seen: dict[bytes, int] = {}
    curves: list[np.ndarray] = []
    for g, (group, gamma) in enumerate(zip(groups, thresholds)):
        if gamma.shape[:2] != (deltas, len(detectors[group.method])):
            raise ValueError(f"{group}: thresholds of shape {gamma.shape} for {deltas} deltas and detectors "
                             f"{detectors[group.method]}")
        for d in range(deltas):
            for j, curve in enumerate(gamma[d]):
                key = curve.tobytes()
                if key not in seen:
                    seen[key] = len(curves)
                    curves.append(curve)
                rows[g, d, j] = seen[key]
    return np.stack(curves), rows


class Dump:
    """Writes one ``.npz`` per task and seed as the sweep goes (:meth:`add`), then the index (:meth:`close`).

    ``detectors`` names, per method and combination, the detectors whose thresholds its configurations have;
    ``seconds`` counts the time spent writing.
    """

    def __init__(self, directory: Path, header: Mapping[str, Any], detectors: Mapping[str, tuple[str, ...]]) -> None:
        self.directory = Path(directory)
        self.header = dict(header)
        self.detectors = detectors
        self.groups: list[Group] | None = None
        self.files: list[dict[str, Any]] = []
        self.seconds = 0.0

    def add(self, dataset: Dataset, seed: int, swept: TaskSweep) -> Path:
        """Write the configurations of one task and seed (``swept`` with its thresholds kept)."""
        start = time.perf_counter()
        if swept.thresholds is None:
            raise ValueError("the sweep kept no thresholds to dump (sweep with thresholds=True)")
        if self.groups is None:
            self.groups = list(swept.groups)
        elif swept.groups != self.groups:
            raise ValueError(f"task {dataset.task!r} seed {seed}: other configurations than the first task's")
        curves, rows = _distinct_rows(swept.groups, swept.thresholds, self.detectors, swept.alarms.shape[1])
        name = file_name(dataset.task, seed)
        if any(entry["file"] == name for entry in self.files):  # two task names alike but for odd characters
            name = file_name(f"{dataset.task}-{len(self.files)}", seed)
        path = self.directory / name
        self.directory.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(path, rollout_ids=np.array([r.rollout_id for r in dataset.test]), lengths=dataset.lengths,
                            alarms=swept.alarms.astype(np.int32), thresholds=curves, threshold_rows=rows)
        self.files.append({"task": dataset.task, "seed": seed, "file": name,
                           "sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
                           "test_rollouts": len(dataset.test), "steps": int(curves.shape[1]),
                           "threshold_rows": int(curves.shape[0])})
        self.seconds += time.perf_counter() - start
        return path

    def close(self) -> Path:
        """Write ``index.json`` (module docstring; one configuration per line); returns its path."""
        start = time.perf_counter()
        configurations = [{"method": g.method, "window": g.window, "threshold": g.kind, "combine": g.combine,
                           "detectors": list(self.detectors[g.method])} for g in self.groups or []]
        head = json.dumps({"format": FORMAT, "version": VERSION, **self.header, "files": self.files}, indent=1)
        lines = ",\n".join(f"  {json.dumps(c)}" for c in configurations)
        path = self.directory / INDEX
        self.directory.mkdir(parents=True, exist_ok=True)
        path.write_text(f"{head[:-2]},\n \"configurations\": [\n{lines}\n ]\n}}\n")
        self.seconds += time.perf_counter() - start
        return path
