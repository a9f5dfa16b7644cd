"""On-disk cache of per-step score streams: one ``<key>.npz`` per (dataset, stream, settings, split, seed).

The key is a SHA-256 over the dataset digest, the stream name and settings (with the calibration split
for streams fitted on the calibration successes), the seed (for streams that use one, the split's
included) and the code version (a hash of the source files that compute scores), so a changed
dataset, setting, split or scoring code never reads stale scores.

What is cached is :class:`RolloutScores`, the scores of every successful calibration rollout and every
test rollout; :meth:`StreamScores.of` then separates the calibration successes into the fit part and the
conformal part of the split (:func:`fiper_ros.core.calibration.split_successes`).
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import fiper_ros
from fiper_ros.core.calibration import CalibrationSplit

LOG = logging.getLogger(__name__)

DEFAULT_DIRECTORY = Path(".cache") / "fiper-eval"
#: Packages whose source determines the scores.
_SCORING_PACKAGES = ("core", "baselines")
_SCORING_MODULES = ("evaluation/scoring.py", "evaluation/methods.py", "evaluation/external.py")


@dataclass
class RolloutScores:
    """Per-step scores of one stream: every successful calibration rollout (in order) and every test rollout.

    A calibration success's scores come from the model that the split lets see it: with ``"split"`` the
    model fitted on the fit part (which saw the fit part and not the conformal part), with ``"cross"``
    the model of the other folds, with ``"same"`` the model fitted on all. Test scores come from the
    deployed model (fitted on the fit part with ``"split"``, on all successes otherwise). ``shape``: with
    cross-fitted shapes, the fit part's curves (in the split's order), each from the model of the other folds.
    """

    calibration: list[np.ndarray]
    test: list[np.ndarray]
    shape: list[np.ndarray] | None = None


@dataclass
class StreamScores:
    """Per-step scores of one stream, the calibration successes separated by the split.

    ``fit``: the fit part's curves, which give the thresholds' per-step shape (``I1`` of ``cp_band``,
    ``cp_scaled``, ``gaussian``: ``shape_curves`` of :func:`fiper_ros.core.thresholds.fit_threshold`), the
    cross-fitted ones where the scores have them;
    ``None`` where the fit part is not disjoint from the conformal part (``"same"``, ``"cross"``): the
    core then splits ``I1`` off the conformal curves, as :func:`fiper_ros.core.calibration.calibrate`
    does. ``conformal``: the curves the thresholds' conformal quantiles are taken over. ``test``: the
    test rollouts.
    """

    fit: list[np.ndarray] | None
    conformal: list[np.ndarray]
    test: list[np.ndarray]

    @classmethod
    def of(cls, scores: RolloutScores, split: CalibrationSplit) -> StreamScores:
        """``scores`` separated as ``split`` says (its indices count the calibration successes)."""
        count = len(split.conformal) + (len(split.fit) if split.mode == "split" else 0)
        if len(scores.calibration) != count:
            raise ValueError(f"a split of {count} successes for {len(scores.calibration)} scored ones")
        conformal = [scores.calibration[i] for i in split.conformal]
        fit = None
        if split.mode == "split":
            fit = scores.shape if scores.shape is not None else [scores.calibration[i] for i in split.fit]
        return cls(fit, conformal, scores.test)


def code_version() -> str:
    """SHA-256 over the source files that compute scores (core, baselines, scoring)."""
    root = Path(fiper_ros.__file__).parent
    files = sorted(f for package in _SCORING_PACKAGES for f in (root / package).rglob("*.py"))
    files += [root / module for module in _SCORING_MODULES]
    digest = hashlib.sha256(fiper_ros.__version__.encode())
    for file in files:
        digest.update(file.relative_to(root).as_posix().encode())
        digest.update(file.read_bytes())
    return digest.hexdigest()


def cache_key(data_digest: str, stream: str, settings: dict[str, Any], seed: int | None, version: str) -> str:
    """The cache key of one stream of one dataset (``seed=None`` for seedless streams)."""
    payload = json.dumps({"data": data_digest, "stream": stream, "settings": settings, "seed": seed,
                          "code": version}, sort_keys=True)
    return hashlib.sha256(payload.encode()).hexdigest()


def _pack(arrays: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    lengths = np.array([a.shape[0] for a in arrays], dtype=np.int64)
    flat = np.concatenate(arrays) if arrays else np.zeros(0)
    return flat.astype(np.float64), lengths


def _unpack(flat: np.ndarray, lengths: np.ndarray) -> list[np.ndarray]:
    return np.split(flat, np.cumsum(lengths)[:-1]) if lengths.size else []


class ScoreCache:
    """A directory of cached :class:`RolloutScores`; counts hits and misses."""

    def __init__(self, directory: str | Path = DEFAULT_DIRECTORY) -> None:
        self.directory = Path(directory)
        self.hits = 0
        self.misses = 0

    def _path(self, key: str) -> Path:
        return self.directory / f"{key}.npz"

    def get(self, key: str) -> RolloutScores | None:
        """The cached scores of ``key`` or ``None`` (a miss)."""
        path = self._path(key)
        if not path.is_file():
            self.misses += 1
            return None
        try:
            with np.load(path, allow_pickle=False) as data:
                shape = _unpack(data["shape"], data["shape_lengths"]) if "shape" in data else None
                scores = RolloutScores(_unpack(data["calibration"], data["calibration_lengths"]),
                                      _unpack(data["test"], data["test_lengths"]), shape)
        except (OSError, KeyError, ValueError) as error:
            LOG.warning("ignoring unreadable score cache file %s: %s", path, error)
            self.misses += 1
            return None
        self.hits += 1
        return scores

    def put(self, key: str, scores: RolloutScores) -> None:
        """Store ``scores`` under ``key`` (written to a temporary file, then renamed)."""
        self.directory.mkdir(parents=True, exist_ok=True)
        calibration, calibration_lengths = _pack(scores.calibration)
        test, test_lengths = _pack(scores.test)
        shape = {} if scores.shape is None else dict(zip(("shape", "shape_lengths"), _pack(scores.shape)))
        temporary = self._path(key).with_suffix(".tmp.npz")
        np.savez(temporary, calibration=calibration, calibration_lengths=calibration_lengths, test=test,
                 test_lengths=test_lengths, **shape)
        temporary.replace(self._path(key))
