"""Loader of rollout logs in a generic layout that users write themselves (docs/bags.md, "Converters").

SRC is one file or a directory searched recursively for ``*.npz``, ``*.parquet``, ``*.pkl`` and ``*.pickle``.
Every file holds the same named fields (:class:`~fiper_ros.converters.options.Keys`, one ``--*-key`` option
each; defaults in brackets):

- per policy step: the observation embedding ``[embeddings]``, ``(E,)``, and optionally the sampled action
  batch ``[actions]``, ``(B, H, D)``, the step index ``[step]`` (integers that order the steps) and, with
  ``--signals-key``, the step's signals ``(K,)`` (or one number) named by ``--signal-names`` (``Rollout.signals``);
- per rollout: the outcome ``[success]`` (bool or 0/1), and optionally ``[split]`` (``calibration`` or
  ``test``; without it the name of a directory on the way to the file; without either for every rollout the
  conversion draws it: :mod:`fiper_ros.core.data_split`), ``[task]`` and ``[scenario]`` (default ``id``), each one
  value per rollout or repeated on every step.

``.npz`` and ``.parquet`` files are tables of steps: with a ``[rollout_id]`` column the rows are grouped into
rollouts by it, without one the file is one rollout. An ``.npz`` holds arrays whose first axis is the row
(``embeddings`` ``[N, E]``, ``actions`` ``[N, B, H, D]``; a rollout's values may be 0-d arrays in a
one-rollout file) and is read with ``allow_pickle=False``; a ``.parquet`` file has one row per step with list
columns (``embeddings`` a list of E numbers, ``actions`` nested lists ``[B][H][D]``). A pickle is a list of
dicts (or one dict), one per rollout, each with ``embeddings`` ``[T, E]``, ``actions`` ``[T, B, H, D]`` and
the per-rollout values (``[rollout_id]`` its name).

Rollouts without action batches (the key absent from every file) are converted as observation-only rollouts:
bags without ``/fiper/action_chunks``. Every rollout of a conversion has one layout (E, B, H, D and h), whatever
its task: one conversion may hold several tasks.
Everything read counts against ``--max-mb`` (:class:`~fiper_ros.converters.options.Budget`); each bad input
is a :class:`~fiper_ros.bagio.errors.BagError` naming the file, the rollout and the key.

Unpickling runs code from the file: load pickles only from sources you trust.
"""
from __future__ import annotations

import pickle
import zipfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fiper_ros.bagio.errors import BagError
from fiper_ros.converters.options import EXEC_STEPS, Budget, ConvertOptions, Converted, Keys, select_channels
from fiper_ros.core.data_split import NO_SPLIT
from fiper_ros.core.detectors import SIGNAL_NAME
from fiper_ros.core.rollout import ID_SCENARIO, Rollout, RolloutError
from fiper_ros.errors import FiperError

SPLITS = ("calibration", "test")
#: The option that names each key, for the error messages.
KEY_OPTIONS = {"embeddings": "--embedding-key", "actions": "--actions-key", "success": "--success-key",
               "rollout": "--rollout-key", "step": "--step-key", "split": "--split-key", "task": "--task-key",
               "scenario": "--scenario-key", "signals": "--signals-key"}
#: ``h`` of observation-only rollouts of a task whose ``h`` is not known (one policy step per control step).
OBSERVATION_ONLY_EXEC_STEPS = 1


@dataclass
class Record:
    """The fields of one rollout as read from a file (arrays over its steps, or one value)."""

    path: Path
    name: str
    fields: dict[str, Any]
    source: str

    @property
    def where(self) -> str:
        """``FILE: rollout NAME``, the head of every error about it."""
        return f"{self.path}: rollout {self.name!r}"


def _key(keys: Keys, field: str) -> str:
    """``'name' (--option)`` of a field, for messages."""
    return f"{getattr(keys, field)!r} ({KEY_OPTIONS[field]})"


def _groups(path: Path, names: np.ndarray, keys: Keys) -> Iterator[tuple[str, np.ndarray | None]]:
    """Rows of each rollout, in order of first appearance, from the ``[rollout_id]`` column (a 0-d value:
    the file is that one rollout)."""
    if names.ndim == 0:
        yield str(names.item()), None
        return
    if names.ndim != 1:
        raise BagError(f"{path}: {_key(keys, 'rollout')} has shape {names.shape}, expected one value per row")
    if names.dtype == object and any(v is None for v in names):
        raise BagError(f"{path}: {_key(keys, 'rollout')} has a row without a rollout id")
    labels = names.astype(str)
    _, first, inverse, counts = np.unique(labels, return_index=True, return_inverse=True, return_counts=True)
    order = np.argsort(inverse, kind="stable")
    starts = np.cumsum(counts) - counts
    for group in np.argsort(first, kind="stable"):
        yield str(labels[first[group]]), order[starts[group]:starts[group] + counts[group]]


def _npz_records(path: Path, rel: str, keys: Keys, budget: Budget) -> Iterator[Record]:
    try:
        with zipfile.ZipFile(path) as archive:
            budget.check_file(path, sum(info.file_size for info in archive.infolist()), " of arrays")
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files if key in _wanted(keys)}
    except BagError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as error:
        raise BagError(f"{path}: not a readable .npz file of arrays ({type(error).__name__}: "
                       f"{' '.join(str(error).split())})") from error
    names = arrays.get(keys.rollout)
    if names is not None and names.ndim == 1:
        for field in KEY_OPTIONS:
            array = arrays.get(getattr(keys, field))
            if array is not None and array.ndim and array.shape[0] != names.shape[0]:
                raise BagError(f"{path}: {_key(keys, field)} has {array.shape[0]} rows, {_key(keys, 'rollout')} "
                               f"{names.shape[0]}: every per-step array has one row per step")
    yield from _table_records(path, rel, keys, set(arrays), lambda key, rows: _rows(arrays[key], rows))


def _rows(array: np.ndarray, rows: np.ndarray | None) -> np.ndarray:
    """The rows of a table column; a 0-d array is one value for the whole file."""
    return array if rows is None or array.ndim == 0 else array[rows]


def _parquet_records(path: Path, rel: str, keys: Keys, budget: Budget) -> Iterator[Record]:
    import pyarrow  # noqa: PLC0415 - only this format needs pyarrow
    import pyarrow.parquet  # noqa: PLC0415

    try:
        file = pyarrow.parquet.ParquetFile(path)
        metadata = file.metadata
        budget.check_file(path, sum(metadata.row_group(i).total_byte_size for i in range(metadata.num_row_groups)),
                          " of uncompressed columns")
        columns = [name for name in file.schema_arrow.names if name in _wanted(keys)]
        table = file.read(columns=columns)
    except BagError:
        raise
    except (OSError, pyarrow.ArrowException) as error:
        raise BagError(f"{path}: not a readable .parquet file ({type(error).__name__}: "
                       f"{' '.join(str(error).split())})") from error

    def column(key: str, rows: np.ndarray | None) -> np.ndarray:
        values = table.column(key)
        try:
            return _arrow_array(values if rows is None else values.take(pyarrow.array(rows)))
        except pyarrow.ArrowException as error:
            raise _ColumnError(f"of type {values.type} is not numbers, strings or lists of them "
                               f"({' '.join(str(error).split())})") from error

    yield from _table_records(path, rel, keys, set(columns), column)


def _arrow_array(column: Any) -> np.ndarray:  # a pyarrow ChunkedArray
    """A parquet column as one numpy array: nested list columns of equal lengths become its trailing axes."""
    import pyarrow  # noqa: PLC0415
    import pyarrow.compute  # noqa: PLC0415

    array = column.combine_chunks() if isinstance(column, pyarrow.ChunkedArray) else column
    shape = [len(array)]
    while pyarrow.types.is_list(array.type) or pyarrow.types.is_large_list(array.type) \
            or pyarrow.types.is_fixed_size_list(array.type):
        if array.null_count:
            raise _ColumnError("has null lists")
        lengths = pyarrow.compute.list_value_length(array).to_numpy(zero_copy_only=False)
        if lengths.size and np.any(lengths != lengths[0]):
            raise _ColumnError("has steps of different lengths")
        shape.append(int(lengths[0]) if lengths.size else 0)
        array = array.flatten()
    if array.null_count and pyarrow.types.is_floating(array.type):
        array = array.fill_null(np.nan)
    values = array.to_numpy(zero_copy_only=False)
    return values.reshape(shape)


class _ColumnError(FiperError):
    """A parquet column that is no array (the caller names the file, rollout and key)."""


def _wanted(keys: Keys) -> set[str]:
    return {getattr(keys, field) for field in KEY_OPTIONS} - {""}


def _table_records(path: Path, rel: str, keys: Keys, present: set[str],
                   column: Callable[[str, np.ndarray | None], np.ndarray]) -> Iterator[Record]:
    """The rollouts of a table of steps: grouped by ``[rollout_id]`` if it has one, else all rows one rollout."""
    grouped = keys.rollout in present
    if grouped:
        try:
            groups = _groups(path, column(keys.rollout, None), keys)
        except _ColumnError as error:
            raise BagError(f"{path}: {_key(keys, 'rollout')} {error}") from error
    else:
        groups = iter([(path.stem, None)])
    fields = [field for field in KEY_OPTIONS if field != "rollout" and getattr(keys, field) in present]
    for name, rows in groups:
        record = Record(path, name, {}, f"{rel}#{name}" if grouped else rel)
        for field in fields:
            try:
                record.fields[getattr(keys, field)] = column(getattr(keys, field), rows)
            except _ColumnError as error:
                raise BagError(f"{record.where}: {_key(keys, field)} {error}") from error
        yield record


def _pickle_records(path: Path, rel: str, keys: Keys, budget: Budget) -> Iterator[Record]:
    budget.check_file(path, path.stat().st_size)
    try:
        with path.open("rb") as stream:
            content = pickle.load(stream)  # noqa: S301 - trusted sources only (documented)
    except Exception as error:  # any unpickling failure is a bad file
        raise BagError(f"{path}: not a readable pickle ({type(error).__name__}: {error})") from error
    items = [content] if isinstance(content, dict) else content
    if not isinstance(items, list) or not all(isinstance(item, dict) for item in items):
        raise BagError(f"{path}: not a list of dicts (one per rollout) but {type(content).__name__}")
    for index, item in enumerate(items):
        name = item.get(keys.rollout, index if len(items) > 1 else path.stem)
        if np.ndim(name) != 0:
            raise BagError(f"{path}: rollout {index}: {_key(keys, 'rollout')} must be one value")
        yield Record(path, str(name), {k: v for k, v in item.items() if k != keys.rollout},
                     f"{rel}#{name}" if len(items) > 1 or keys.rollout in item else rel)


READERS: dict[str, Callable[[Path, str, Keys, Budget], Iterator[Record]]] = {
    ".npz": _npz_records, ".parquet": _parquet_records, ".pkl": _pickle_records, ".pickle": _pickle_records}


def source_files(src: Path) -> list[Path]:
    """``src`` itself, or every file with a known suffix below it (sorted)."""
    if src.is_file():
        if src.suffix.lower() not in READERS:
            raise BagError(f"{src}: not one of the generic formats ({', '.join(READERS)})")
        return [src]
    if not src.is_dir():
        raise BagError(f"{src}: no such file or directory")
    files = sorted(p for p in src.rglob("*") if p.suffix.lower() in READERS and p.is_file())
    if not files:
        raise BagError(f"{src}: no {', '.join('*' + s for s in READERS)} files")
    return files


def _one_value(record: Record, field: str, keys: Keys) -> Any:  # a label of any type
    """A per-rollout field: one value, or the same value on every step."""
    value = record.fields[getattr(keys, field)]
    array = np.asarray(value, dtype=object if isinstance(value, (list, tuple)) else None)
    if array.ndim == 0:
        return array.item()
    if array.ndim != 1 or array.size == 0:
        raise BagError(f"{record.where}: {_key(keys, field)} has shape {array.shape}, expected one value per "
                       "rollout or per step")
    values = {_plain(v) for v in array.tolist()}
    if len(values) != 1:
        shown = ", ".join(sorted(map(repr, values)))
        raise BagError(f"{record.where}: {_key(keys, field)} differs between steps ({shown})")
    return values.pop()


def _plain(value: Any) -> Any:
    """A hashable Python value (NaN as None: a missing label)."""
    if isinstance(value, float) and value != value:
        return None
    return value.item() if isinstance(value, np.generic) else value


def _success(record: Record, keys: Keys) -> bool:
    if keys.success not in record.fields:
        raise BagError(f"{record.where}: no success label {_key(keys, 'success')}")
    value = _plain(_one_value(record, "success", keys))
    if value is None:
        raise BagError(f"{record.where}: the success label {_key(keys, 'success')} is missing (None/NaN)")
    if isinstance(value, bool) or (isinstance(value, int) and value in (0, 1)):
        return bool(value)
    raise BagError(f"{record.where}: the success label {_key(keys, 'success')} must be a bool (or 0/1), got {value!r}")


def _text(record: Record, field: str, keys: Keys, default: str) -> str:
    if getattr(keys, field) not in record.fields:
        return default
    value = _plain(_one_value(record, field, keys))
    if not isinstance(value, str) or not value:
        raise BagError(f"{record.where}: {_key(keys, field)} must be a non-empty string, got {value!r}")
    return value


def _split(record: Record, keys: Keys, root: Path) -> str:
    """``[split]``, else the nearest directory below SRC named ``calibration`` or ``test``, else :data:`NO_SPLIT`."""
    if keys.split in record.fields:
        split = _text(record, "split", keys, "")
        if split not in SPLITS:
            raise BagError(f"{record.where}: {_key(keys, 'split')} is {split!r}; expected one of {', '.join(SPLITS)}")
        return split
    for part in (*reversed(record.path.relative_to(root).parent.parts), root.name):
        if part in SPLITS:
            return part
    return NO_SPLIT


def _steps(record: Record, field: str, keys: Keys, ndim: int | tuple[int, ...], layout: str,
           dtype: type = np.float32) -> np.ndarray:
    """A per-step array field as ``dtype`` of ``ndim`` axes (or one of several; ``layout`` names them), checked
    finite."""
    try:
        array = np.asarray(record.fields[getattr(keys, field)])
        if array.dtype == object and array.ndim == 1 and array.size:
            array = np.stack([np.asarray(step) for step in array])
    except ValueError as error:
        raise BagError(f"{record.where}: {_key(keys, field)} has steps of different shapes") from error
    if not (np.issubdtype(array.dtype, np.number) and not np.issubdtype(array.dtype, np.complexfloating)):
        raise BagError(f"{record.where}: {_key(keys, field)} holds {array.dtype} values, not numbers")
    if array.ndim not in ((ndim,) if isinstance(ndim, int) else ndim) or 0 in array.shape:
        raise BagError(f"{record.where}: {_key(keys, field)} has shape {array.shape}, expected {layout}")
    array = array.astype(dtype)
    bad = np.argwhere(~np.isfinite(array))
    if bad.size:
        raise BagError(f"{record.where}: {_key(keys, field)} holds NaN/inf (first at step {bad[0][0]}, index "
                       f"{bad[0].tolist()})")
    return array


def _order(record: Record, keys: Keys, length: int) -> np.ndarray | None:
    """The row order given by ``[step]`` (None without it)."""
    if keys.step not in record.fields:
        return None
    steps = np.asarray(record.fields[keys.step])
    if steps.shape != (length,) or not np.issubdtype(steps.dtype, np.integer):
        raise BagError(f"{record.where}: {_key(keys, 'step')} must be {length} integers (one per step), got "
                       f"{steps.dtype} of shape {steps.shape}")
    if np.unique(steps).size != length:
        raise BagError(f"{record.where}: {_key(keys, 'step')} repeats a step")
    return np.argsort(steps, kind="stable")


def _signals(record: Record, options: ConvertOptions, length: int) -> dict[str, np.ndarray]:
    """The ``--signals-key`` field as named float64 series of ``length`` steps (empty without the option): ``[T, K]``
    with the K ``--signal-names``, or ``[T]``, one signal named by ``--signal-names`` or else by the key."""
    keys = options.keys
    if not keys.signals:
        return {}
    if keys.signals not in record.fields:
        raise BagError(f"{record.where}: no signals {_key(keys, 'signals')}")
    array = _steps(record, "signals", keys, (1, 2), "[T, K] (or [T]: one signal)", np.float64)
    if array.shape[0] != length:
        raise BagError(f"{record.where}: {_key(keys, 'embeddings')} has T = {length} steps, {_key(keys, 'signals')} "
                       f"T = {array.shape[0]}")
    columns = array.reshape(length, -1)
    names = options.signal_names
    if array.ndim == 1 and not names:
        if not SIGNAL_NAME.fullmatch(keys.signals):
            raise BagError(f"{record.where}: {_key(keys, 'signals')} holds one signal per step, named after its key, "
                           f"but {keys.signals!r} is no signal name ({SIGNAL_NAME.pattern}): give --signal-names NAME")
        names = (keys.signals,)
    if len(names) != columns.shape[1]:
        given = f"--signal-names names {len(names)}" if names else "no --signal-names given"
        raise BagError(f"{record.where}: {_key(keys, 'signals')} has K = {columns.shape[1]} signals per step, "
                       f"{given}: name each column")
    return {name: np.ascontiguousarray(columns[:, k]) for k, name in enumerate(names)}


@dataclass(frozen=True)
class _Layout:
    """What every rollout of a conversion shares with the first, whatever its task: E, the action batch shape
    (B, H, D; None without action batches) and h."""

    embedding_dim: int
    batch: tuple[int, ...] | None
    exec_steps: int
    record: Record

    def check(self, other: _Layout, keys: Keys) -> None:
        """Refuse ``other`` unless it has this layout, naming both rollouts."""
        head = (f"{other.record.where}: {{}}, rollout {self.record.name!r} of {self.record.path} {{}}: one conversion "
                "holds one layout")
        if other.embedding_dim != self.embedding_dim:
            raise BagError(head.format(f"{_key(keys, 'embeddings')} has E = {other.embedding_dim}",
                                       f"E = {self.embedding_dim}"))
        if (other.batch is None) != (self.batch is None):
            raise BagError(head.format(f"{_key(keys, 'actions')} {'absent' if other.batch is None else 'present'}",
                                       "has no action batches" if self.batch is None else "has action batches"))
        if other.batch != self.batch:
            raise BagError(head.format(f"{_key(keys, 'actions')} has B, H, D = {other.batch}",
                                       f"B, H, D = {self.batch}"))
        if other.exec_steps != self.exec_steps:
            raise BagError(head.format(f"h = {other.exec_steps} (--exec-steps, else the task's)",
                                       f"h = {self.exec_steps}"))


def _rollout(record: Record, options: ConvertOptions, task: str, first: _Layout | None) -> tuple[Rollout, _Layout]:
    """One record as a core Rollout (observation-only without ``[actions]``) and its layout, checked against
    the ``first`` rollout's."""
    keys = options.keys
    if keys.embeddings not in record.fields:
        raise BagError(f"{record.where}: no observation embeddings {_key(keys, 'embeddings')}")
    embeddings = _steps(record, "embeddings", keys, 2, "[T, E]")
    actions = _steps(record, "actions", keys, 4, "[T, B, H, D]") if keys.actions in record.fields else None
    if actions is not None and actions.shape[0] != embeddings.shape[0]:
        raise BagError(f"{record.where}: {_key(keys, 'embeddings')} has T = {embeddings.shape[0]} steps, "
                       f"{_key(keys, 'actions')} T = {actions.shape[0]}")
    if actions is None:
        exec_steps = options.exec_steps or EXEC_STEPS.get(task.lower(), OBSERVATION_ONLY_EXEC_STEPS)
    else:
        exec_steps = options.exec_steps_for(task, record.path)
    layout = _Layout(embeddings.shape[1], None if actions is None else actions.shape[1:], exec_steps, record)
    (first or layout).check(layout, keys)
    signals = _signals(record, options, embeddings.shape[0])
    order = _order(record, keys, embeddings.shape[0])
    if order is not None:
        embeddings = embeddings[order]
        actions = None if actions is None else actions[order]
        signals = {name: values[order] for name, values in signals.items()}
    success = _success(record, keys)
    if actions is not None:
        actions = select_channels(actions, options.channels, record.path)
    try:
        return Rollout(rollout_id=record.name, task=task, scenario=_text(record, "scenario", keys, ID_SCENARIO),
                       embeddings=embeddings, actions=actions, exec_steps=exec_steps, success=success,
                       action_space=options.action_space, metadata={"max_steps": options.max_steps},
                       signals=signals), layout
    except RolloutError as error:
        raise BagError(f"{record.path}: {error}") from error


def load(src: Path, options: ConvertOptions) -> Converted:
    """Every rollout of the generic files at ``src`` by split, with its source (``file`` or ``file#rollout``):
    under :data:`NO_SPLIT` if no rollout has a split (the caller draws it); rollouts with and without one are
    refused."""
    files = source_files(src)
    root = src if src.is_dir() else src.parent
    budget = Budget(options.max_mb)
    keys = options.keys
    converted: Converted = {}
    first: _Layout | None = None
    unsplit: Record | None = None
    for path in files:
        rel = str(path.relative_to(root))
        for record in READERS[path.suffix.lower()](path, rel, keys, budget):
            task = options.task or _text(record, "task", keys, src.stem if src.is_file() else src.name)
            rollout, layout = _rollout(record, options, task, first)
            budget.take(record.where, rollout)
            first = first or layout
            split = _split(record, keys, root)
            unsplit = unsplit or (record if split == NO_SPLIT else None)
            converted.setdefault(split, []).append((rollout, record.source))
    if not converted:
        raise BagError(f"{src}: no rollouts (every file has no rows)")
    if unsplit is not None and len(converted) > 1:
        raise BagError(f"{unsplit.where}: no split, while other rollouts have one: give {_key(keys, 'split')} or "
                       "put the file under calibration/ or test/ (without a split for any rollout, the conversion "
                       "draws one: --calibration-fraction)")
    return converted
