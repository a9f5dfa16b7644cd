"""External per-step scores: a detector computed elsewhere, evaluated like a built-in method.

``fiper evaluate --scores NAME=FILE`` reads, per rollout id of the data (:attr:`Rollout.rollout_id`), the
detector's score at every policy step of that rollout:

- ``.json``: one object ``{"<rollout id>": [s_0, s_1, ..., s_{T-1}], ...}``;
- ``.npz``: one 1-D array per rollout, named by its id (``np.savez(FILE, **{rollout_id: scores})``).

The file gives every calibration success and every test rollout of every task of the run (a calibration failure
may be given too: it is not used) and no rollout the data lacks; each rollout exactly its ``T`` scores, finite
and >= 0 (a step missing at run time counts as 0 in a window's sum, a lower bound only for scores >= 0:
:mod:`fiper_ros.core.monitor`). Anything else is refused in one line naming the file and the first rollout at
fault (:class:`~fiper_ros.evaluation.data.DatasetError`), before any score is computed. The scores are taken as
they are (no profile epsilon, no magnitude).

The stream is ``external_<NAME>`` (:func:`fiper_ros.core.detectors.info`). It is evaluated as a method of its own
(every window, threshold kind and delta of the sweep) and as a member of combinations, from the same calibration
split as every other stream. The evaluation cannot know what the scores' model was fitted on: it counts as
unfitted, and its thresholds keep Proposition 1 only if that model saw no calibration rollout.
"""

from __future__ import annotations

import hashlib
import json
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fiper_ros.core.detectors import EXTERNAL_PREFIX, external_stream, info
from fiper_ros.core.errors import ChoiceError
from fiper_ros.evaluation.data import Dataset, DatasetError

#: The file formats of external scores, by suffix.
SUFFIXES = (".json", ".npz")


@dataclass(frozen=True, eq=False)
class ExternalScores:
    """One ``--scores NAME=FILE``: per rollout id, the per-step scores (float64, finite, >= 0)."""

    name: str
    path: Path
    sha256: str
    """SHA-256 of the file's bytes (the score-cache key of the stream)."""
    scores: Mapping[str, np.ndarray]

    @property
    def stream(self) -> str:
        """The stream the scores are: ``external_<name>``."""
        return external_stream(self.name)

    @property
    def where(self) -> str:
        """How messages name the scores: ``--scores NAME=FILE``."""
        return f"--scores {self.name}={self.path}"


def _described(value: object) -> str:
    """A short description of a value that is not one rollout's scores, for a message."""
    if isinstance(value, np.ndarray):
        return f"a {value.dtype} array of shape {value.shape}"
    text = json.dumps(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _array(where: str, rollout_id: str, value: object) -> np.ndarray:
    """One rollout's scores as float64 ``[T]``: numbers (not booleans), at least one, finite, >= 0."""
    try:
        array = np.asarray(value)
    except ValueError:  # a ragged nesting of lists
        array = np.asarray(None)
    if array.dtype.kind not in "iuf" or array.ndim != 1 or array.shape[0] == 0:
        raise DatasetError(f"{where}: rollout {rollout_id!r}: expected a list of numbers, one score per policy step, "
                           f"got {_described(value)}")
    scores = array.astype(np.float64)
    for bad, rule in ((~np.isfinite(scores), "finite"), (scores < 0.0, ">= 0")):
        if bad.any():
            step = int(np.argmax(bad))
            raise DatasetError(f"{where}: rollout {rollout_id!r}: the score of step {step} is {scores[step]:g}; "
                               f"scores must be {rule}")
    return scores


def _read(where: str, path: Path) -> dict[str, object]:
    """The rollout id -> scores mapping of a ``.json`` or ``.npz`` file."""
    if path.suffix not in SUFFIXES:
        raise DatasetError(f"{where}: expected a .json or .npz file of {{rollout_id: [scores]}}")
    if not path.is_file():
        raise DatasetError(f"{where}: file not found")
    if path.suffix == ".json":
        try:
            data = json.loads(path.read_bytes())
        except (ValueError, UnicodeDecodeError) as error:
            raise DatasetError(f"{where}: not JSON: {error}") from error
        if not isinstance(data, dict):
            raise DatasetError(f"{where}: expected a JSON object {{rollout_id: [scores]}}, got {type(data).__name__}")
        return {key: value for key, value in data.items()}
    try:
        with np.load(path, allow_pickle=False) as arrays:
            return {key: arrays[key] for key in arrays.files}
    except (OSError, ValueError, zipfile.BadZipFile) as error:
        raise DatasetError(f"{where}: not a readable .npz file of arrays: {error}") from error


def load_scores(name: str, path: str | Path) -> ExternalScores:
    """The external scores ``NAME=FILE`` (module docstring); :class:`DatasetError` in one line for a bad name, a
    missing or unreadable file, or a rollout's scores that are not numbers, not finite or negative."""
    path = Path(path)
    where = f"--scores {name}={path}"
    try:
        external_stream(name)
    except ChoiceError as error:
        raise DatasetError(f"{where}: {error}") from error
    raw = _read(where, path)
    if not raw:
        raise DatasetError(f"{where}: no rollouts in the file")
    scores = {str(rollout_id): _array(where, str(rollout_id), value) for rollout_id, value in raw.items()}
    return ExternalScores(name, path, hashlib.sha256(path.read_bytes()).hexdigest(), scores)


def _check_distinct(names: Sequence[str]) -> None:
    """Refuse a name of external scores given twice."""
    twice = [name for name in names if names.count(name) > 1]
    if twice:
        raise DatasetError(f"--scores {twice[0]}=... is given twice: one file per name")


def parse_scores(texts: Sequence[str]) -> tuple[ExternalScores, ...]:
    """Every ``NAME=FILE`` of ``--scores`` (distinct names) read by :func:`load_scores`."""
    specs = []
    for text in texts:
        name, sep, path = text.partition("=")
        if not sep or not name.strip() or not path.strip():
            raise DatasetError(f"--scores expects NAME=FILE (a .json or .npz of {{rollout_id: [scores]}}), got "
                               f"{text!r}")
        specs.append((name.strip(), path.strip()))
    _check_distinct([name for name, _ in specs])
    return tuple(load_scores(name, path) for name, path in specs)


def _more(count: int) -> str:
    return f" (and {count} more)" if count else ""


def check_covers(external: ExternalScores, datasets: Sequence[Dataset]) -> None:
    """Refuse, in one line, external scores that do not match the data: rollout ids that are not distinct over the
    run's tasks (the file could not tell them apart), a calibration success or test rollout without scores, scores
    of a rollout the data lacks, or a rollout with another number of scores than its policy steps."""
    where = external.where
    owners: dict[str, str] = {}
    for dataset in datasets:
        for rollout in (*dataset.calibration, *dataset.test):
            if rollout.rollout_id in owners:
                other = owners[rollout.rollout_id]
                tasks = f"twice in task {other!r}" if other == dataset.task else f"in task {other!r} and in task " \
                    f"{dataset.task!r}"
                raise DatasetError(f"{where}: rollout id {rollout.rollout_id!r} is {tasks}: external scores need "
                                   "distinct rollout ids")
            owners[rollout.rollout_id] = dataset.task
    needed = [(d.task, r) for d in datasets for r in (*d.calibration_successes, *d.test)]
    missing = [(task, r.rollout_id) for task, r in needed if r.rollout_id not in external.scores]
    if missing:
        task, rollout_id = missing[0]
        raise DatasetError(f"{where}: no scores for rollout {rollout_id!r} of task {task!r}{_more(len(missing) - 1)}")
    extra = [rollout_id for rollout_id in external.scores if rollout_id not in owners]
    if extra:
        raise DatasetError(f"{where}: scores of rollout {extra[0]!r}{_more(len(extra) - 1)}, which is in no task's "
                           "data")
    for task, rollout in needed:
        count = external.scores[rollout.rollout_id].shape[0]
        if count != rollout.length:
            raise DatasetError(f"{where}: rollout {rollout.rollout_id!r} of task {task!r} has {count} scores for its "
                               f"{rollout.length} policy steps")


def check_external(datasets: Sequence[Dataset], given: Sequence[ExternalScores], streams: Sequence[str]) -> None:
    """Every external stream of ``streams`` has its scores in ``given`` (distinct names), and they match the data
    (:func:`check_covers`); :class:`DatasetError` in one line otherwise."""
    _check_distinct([external.name for external in given])
    names = [external.stream for external in given]
    for stream in streams:
        if info(stream).reads == "external" and stream not in names:
            raise DatasetError(f"detector {stream!r} reads external scores: give them with "
                               f"--scores {stream.removeprefix(EXTERNAL_PREFIX)}=FILE")
    for external in given:
        if external.stream in streams:
            check_covers(external, datasets)
