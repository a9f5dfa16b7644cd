"""What the detectors of :mod:`fiper_ros.core` whose fitted state is a few numpy arrays (progress, action
consistency, PCA-kmeans, logpZO) share: the check of their input (:func:`check_input`) and their files.

On disk a model is ``<stem>.json`` (readable: kind, format version, settings and fitted scalars, the arrays'
shapes and dtypes, the content digest) beside ``<stem>.npz`` (the arrays, read without pickles); the detectors are
:class:`StoredModel` subclasses, written and read here with numpy only. The digest is SHA-256 over the description
(everything in the JSON but the digest itself, keys sorted) and every array's name, dtype, shape and bytes; it
is stored in the JSON and checked on load, so a modified, swapped or foreign file is refused with one line
naming it, and it is what a calibration's content hash covers of the model.
"""

from __future__ import annotations

import hashlib
import json
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar, Self

import numpy as np

from fiper_ros.core.errors import CoreError
from fiper_ros.core.rollout import Rollout

#: Bytes a ``.npy`` member may hold beyond its data: the magic string and the header (numpy pads it to 64-byte
#: multiples; 4 KiB is far more than a header of a few arrays needs).
NPY_HEADER_BYTES = 4096


class ModelFileError(CoreError):
    """A detector model file is missing, unreadable or not the model its description names."""


def check_input(x: np.ndarray, shape: tuple[int | str, ...], what: str, error: type[ValueError]) -> np.ndarray:
    """``x`` as an array if it has ``shape`` (an ``int`` is a required size, a ``str`` names a free one) with no
    empty axis and holds finite numbers; else ``error`` with one line: ``what`` and the shape expected and got,
    or that it holds NaN/inf or no numbers. Cost: one pass over ``x``."""
    x = np.asarray(x)
    if x.ndim != len(shape) or 0 in x.shape or any(isinstance(want, int) and got != want
                                                   for got, want in zip(x.shape, shape)):
        raise error(f"{what} must have shape ({', '.join(map(str, shape))}) with no empty axis, got {x.shape}")
    if x.dtype.kind not in "fiu" or not np.isfinite(x).all():
        raise error(f"{what} contain NaN/inf or are not numbers")
    return x


def _sha256(content: Mapping[str, Any], arrays: Mapping[str, np.ndarray]) -> str:
    """SHA-256 over ``content`` (JSON, keys sorted) and each array's name, dtype, shape and bytes (by name)."""
    sha = hashlib.sha256(json.dumps(content, sort_keys=True).encode())
    for name in sorted(arrays):
        array = np.ascontiguousarray(arrays[name])
        sha.update(f"{name}/{array.dtype.str}/{tuple(array.shape)}".encode())
        sha.update(array.tobytes())
    return sha.hexdigest()


def _layout(arrays: Mapping[str, np.ndarray]) -> dict[str, dict[str, Any]]:
    return {name: {"dtype": np.asarray(array).dtype.str, "shape": list(np.shape(array))}
            for name, array in sorted(arrays.items())}


def _content(stem: str, version: int, description: Mapping[str, Any],
             arrays: Mapping[str, np.ndarray]) -> dict[str, Any]:
    return {"kind": stem, "format_version": version, **description, "arrays": _layout(arrays)}


def model_digest(stem: str, version: int, description: Mapping[str, Any], arrays: Mapping[str, np.ndarray]) -> str:
    """The digest :func:`write_model` stores: SHA-256 over the JSON content (kind, version, ``description``, the
    arrays' layout; keys sorted) and each array's name, dtype, shape and bytes."""
    return _sha256(_content(stem, version, description, arrays), arrays)


def write_model(directory: str | Path, stem: str, version: int, description: Mapping[str, Any],
                arrays: Mapping[str, np.ndarray]) -> None:
    """Write ``<stem>.npz`` (``arrays``) and ``<stem>.json``: ``kind`` (``stem``), ``format_version``,
    ``description`` (JSON values), ``arrays`` (each one's dtype and shape) and ``digest``
    (:func:`model_digest`)."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    content = _content(stem, version, description, arrays)
    with (directory / f"{stem}.npz").open("wb") as stream:
        np.savez(stream, **{name: np.ascontiguousarray(array) for name, array in arrays.items()})
    (directory / f"{stem}.json").write_text(json.dumps({**content, "digest": _sha256(content, arrays)}, indent=2)
                                            + "\n")


def _read_json(path: Path, stem: str, version: int) -> dict[str, Any]:
    try:
        content = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ModelFileError(f"{path}: unreadable ({type(error).__name__}: {error})") from error
    if not isinstance(content, dict) or content.get("kind") != stem:
        raise ModelFileError(f"{path}: not a {stem} model description")
    if content.get("format_version") != version:
        raise ModelFileError(f"{path}: format_version {content.get('format_version')!r} not supported "
                             f"(expected {version})")
    if not isinstance(content.get("arrays"), dict) or not isinstance(content.get("digest"), str):
        raise ModelFileError(f"{path}: no arrays layout or digest")
    return content


def _read_arrays(path: Path, layout: dict[str, Any]) -> dict[str, np.ndarray]:
    """The arrays of ``path``, exactly those ``layout`` names with its dtypes and shapes; no member is read whose
    stored size exceeds its described data (plus a header), so a damaged file never makes this read more."""
    try:
        with zipfile.ZipFile(path) as archive:
            members = {info.filename: info for info in archive.infolist()}
            if sorted(members) != sorted(f"{name}.npy" for name in layout):
                raise ModelFileError(f"{path}: holds {sorted(members)}, not the arrays its description names")
            arrays = {}
            for name, entry in layout.items():
                dtype, shape = np.dtype(entry["dtype"]), tuple(int(n) for n in entry["shape"])
                if dtype.hasobject:
                    raise ModelFileError(f"{path}: {name}: object arrays are never read")
                if members[f"{name}.npy"].file_size > dtype.itemsize * int(np.prod(shape)) + NPY_HEADER_BYTES:
                    raise ModelFileError(f"{path}: {name}: larger than its described {dtype} {shape}")
                with archive.open(f"{name}.npy") as member:
                    array = np.lib.format.read_array(member, allow_pickle=False)
                if array.dtype != dtype or array.shape != shape:
                    raise ModelFileError(f"{path}: {name}: expected {dtype} {shape}, got {array.dtype} {array.shape}")
                arrays[name] = array
            return arrays
    except ModelFileError:
        raise
    except (OSError, EOFError, ValueError, KeyError, TypeError, zipfile.BadZipFile) as error:
        raise ModelFileError(f"{path}: unreadable ({type(error).__name__}: {error})") from error


def read_model(directory: str | Path, stem: str, version: int) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Read what :func:`write_model` wrote: ``(description, arrays)`` (the description without ``kind``,
    ``format_version``, ``arrays`` and ``digest``). :class:`ModelFileError` (one line naming the file) for a
    missing or unreadable file, another kind or version, arrays other than described, or a digest mismatch."""
    directory = Path(directory)
    for suffix in ("json", "npz"):
        if not (directory / f"{stem}.{suffix}").is_file():
            raise ModelFileError(f"{stem} model file missing: {directory / f'{stem}.{suffix}'}")
    path = directory / f"{stem}.json"
    content = _read_json(path, stem, version)
    arrays = _read_arrays(directory / f"{stem}.npz", content["arrays"])
    stored = content.pop("digest")
    if _sha256(content, arrays) != stored:
        raise ModelFileError(f"{path}: content digest mismatch (the description or {stem}.npz was modified, or they "
                             "come from different fits)")
    return {k: v for k, v in content.items() if k not in ("kind", "format_version", "arrays")}, arrays


class StoredModel:
    """A model stored as ``<name>.json`` + ``<name>.npz``: :meth:`digest`, :meth:`save` and :meth:`load`.

    A subclass names itself (:attr:`name`, the files' stem), its :attr:`format_version` and its :attr:`error` (a
    ``ValueError`` subclass, which :meth:`load` raises for every problem, one line naming the file), and gives
    :meth:`describe` (JSON values), :meth:`arrays` and :meth:`from_stored` (their inverse, which refuses an
    inconsistent model).
    """

    name: ClassVar[str]
    format_version: ClassVar[int]
    error: ClassVar[type[ValueError]]

    def describe(self) -> dict[str, Any]:
        """The model's JSON description (settings, layout, fitted scalars)."""
        raise NotImplementedError

    def arrays(self) -> dict[str, np.ndarray]:
        """The model's fitted arrays by name."""
        raise NotImplementedError

    @classmethod
    def from_stored(cls, description: dict[str, Any], arrays: dict[str, np.ndarray]) -> Self:
        """The model of a :meth:`describe` output and its :meth:`arrays`."""
        raise NotImplementedError

    def digest(self) -> str:
        """SHA-256 over the description and the arrays (:func:`model_digest`)."""
        return model_digest(self.name, self.format_version, self.describe(), self.arrays())

    def save(self, directory: str | Path) -> None:
        """Write ``<name>.json`` and ``<name>.npz`` into ``directory`` (created if needed)."""
        write_model(directory, self.name, self.format_version, self.describe(), self.arrays())

    @classmethod
    def load(cls, directory: str | Path) -> Self:
        """Read a model written by :meth:`save` (numpy only); :attr:`error` naming the file if it is missing,
        damaged, modified or inconsistent."""
        try:
            description, arrays = read_model(directory, cls.name, cls.format_version)
        except ModelFileError as error:
            raise cls.error(str(error)) from error
        try:
            return cls.from_stored(description, arrays)
        except (CoreError, ValueError, KeyError, TypeError) as error:
            path = Path(directory) / f"{cls.name}.json"
            raise cls.error(f"{path}: not a {cls.name} model ({type(error).__name__}: {error})") from error


class EmbeddingDetector(StoredModel):
    """A stored detector whose score of a policy step reads that step's observation embedding alone
    (:attr:`history` 0): :meth:`score_one` per step, :meth:`score_embeddings` / :meth:`scores` for a whole rollout
    with the same function, so both agree bit for bit. A subclass gives :attr:`embedding_dim`, :meth:`_input`
    (the checked, perhaps transformed, embeddings) and :meth:`_score` (one embedding)."""

    #: A score reads the step's own embedding only.
    history: ClassVar[int] = 0

    @property
    def embedding_dim(self) -> int:
        """``E``, the embedding size the model was fitted on."""
        raise NotImplementedError

    def _input(self, embeddings: np.ndarray, shape: tuple[int | str, ...]) -> np.ndarray:
        """``embeddings`` checked to have ``shape`` (:func:`check_input`) and ready for :meth:`_score`."""
        raise NotImplementedError

    def _score(self, x: np.ndarray) -> float:
        """The score of one embedding as :meth:`_input` made it."""
        raise NotImplementedError

    def score_one(self, embedding: np.ndarray) -> float:
        """The score of one embedding ``[E]``."""
        return self._score(self._input(embedding, (self.embedding_dim,)))

    def score_embeddings(self, embeddings: np.ndarray) -> np.ndarray:
        """Scores ``[T]`` (float64) of embeddings ``[T, E]``, step by step as :meth:`score_one`."""
        x = self._input(embeddings, ("T", self.embedding_dim))
        return np.array([self._score(row) for row in x], dtype=np.float64)

    def scores(self, rollout: Rollout) -> np.ndarray:
        """Per-step scores ``[T]`` of ``rollout``'s embeddings."""
        return self.score_embeddings(rollout.embeddings)
