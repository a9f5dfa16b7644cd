"""Reading a calibration: ``calibration.yaml`` (format 3, written by :meth:`Calibration.save`) and each detector's
model files beside it.

``calibration.yaml`` holds the settings, the policy's layout, the guarantee, the leave-one-out false-alarm
estimate, the joint factor and, per task, the split (which rollout ids fitted what) and each declared detector's
threshold (its per-step values) and plain-data entry (ACE's ranges); the models' files (``rnd_oe.npz`` +
``rnd_oe.json``, ``progress.json`` + ``progress.npz``, ...) lie beside it for a calibration of one task, in
``tasks/<task>/`` for one of several. ``content_hash`` is SHA-256 over the YAML content without it and every
model's digest, so a modified file, swapped weights or files of different runs are refused on load, with one line
naming the file; so is a file whose entries do not give back exactly its content.

Format 2 (FIPER's pair or RND-OE alone, written before any other detector existed) is read as it is, its hash
checked over its own content; format 1 (torch weights) is refused with the command that converts it, which reads it
through :func:`upgrade_calibration`.
"""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from fiper_ros.core.calibration.model import Calibration, DetectorPart, Layout, TaskPart, task_directory
from fiper_ros.core.calibration.settings import CalibrationSettings
from fiper_ros.core.calibration_file import (CALIBRATION_FILE, FORMAT_VERSION, LEGACY_FORMAT_VERSION,
                                             PAIR_FORMAT_VERSION, CalibrationError, check_files, one_line, read_yaml)
from fiper_ros.core.detectors import ACE, RND_OE
from fiper_ros.core.errors import CoreError
from fiper_ros.core.rnd_oe import CONFIG_FILE as RND_CONFIG_FILE
from fiper_ros.core.rnd_oe import LEGACY_WEIGHTS_FILE as RND_LEGACY_WEIGHTS_FILE
from fiper_ros.core.rnd_oe import RNDOE, RNDError
from fiper_ros.core.rnd_oe import WEIGHTS_FILE as RND_WEIGHTS_FILE
from fiper_ros.core.scorers import AceScorer, RndOeScorer, load_scorer
from fiper_ros.core.thresholds import Threshold

def load_calibration(directory: str | Path) -> Calibration:
    """Read a calibration directory written by :meth:`Calibration.save` (format 3) or of format 2.

    Raises :class:`CalibrationError` with one line naming the file for a missing directory or file, a
    file that does not parse, an unknown format version (format 1: with the command that converts it), a
    missing or malformed entry, a modified file (content hash, a model's description) and models that do not
    load.
    """
    directory = Path(directory)
    check_files(directory, (CALIBRATION_FILE,))
    path = directory / CALIBRATION_FILE
    data = read_yaml(path)
    if data["format_version"] == PAIR_FORMAT_VERSION:
        return _read_pair(directory, data, PAIR_FORMAT_VERSION)
    return _read(directory, data)


def upgrade_calibration(directory: str | Path) -> Calibration:
    """Read a calibration of format 1 (weights in ``rnd_oe.pt``; imports torch) or 2, checked as
    :func:`load_calibration` checks one (its content hash included); saved, it is of format 3, with the same
    thresholds, weights and scores."""
    directory = Path(directory)
    check_files(directory, (CALIBRATION_FILE,))
    data = read_yaml(directory / CALIBRATION_FILE, (LEGACY_FORMAT_VERSION, PAIR_FORMAT_VERSION))
    return _read_pair(directory, data, int(data["format_version"]))


def _read(directory: Path, data: dict[str, Any]) -> Calibration:
    path = directory / CALIBRATION_FILE
    stored = data.pop("content_hash", None)
    try:
        try:
            settings = CalibrationSettings.from_dict(data["settings"])
        except CalibrationError as error:
            raise CalibrationError(f"{path}: malformed entry ({one_line(error)})") from error
        layout = _layout(data["layout"])
        names = tuple(data["tasks"])
        tasks = {}
        for name, part in data["tasks"].items():
            where = task_directory(directory, names, name)
            detectors = {}
            for d in settings.detectors:
                entry = dict(part["detectors"][d])
                threshold = Threshold.from_dict(entry.pop("threshold"))
                detectors[d] = DetectorPart(_scorer(d, where, entry, settings, layout), threshold)
            tasks[name] = TaskPart(detectors, int(part["num_rollouts"]), dict(part.get("split", {})))
        calibration = Calibration(settings, layout, tasks, dict(data.get("joint", {})),
                                  dict(data.get("false_alarm_estimate", {})), dict(data.get("auto", {})))
    except CalibrationError:
        raise
    except KeyError as error:
        raise CalibrationError(f"{path}: missing entry {error}") from error
    except (CoreError, TypeError, ValueError, AttributeError) as error:  # ThresholdError, settings values, model files
        raise CalibrationError(f"{path}: malformed entry ({one_line(error)})") from error
    # The entries must give back the file's content and its hash.
    if stored != calibration.hash_of(data) or stored != calibration.content_hash:
        raise CalibrationError(f"{path}: content hash mismatch (file or models modified, or files of different runs)")
    return calibration


def _layout(data: dict[str, Any]) -> Layout:
    """The ``layout`` entry (the action fields only where the calibration fixes them)."""
    return Layout(int(data["embedding_dim"]), int(data.get("action_dim", 0)), int(data.get("horizon", 0)),
                  int(data.get("exec_steps", 0)), str(data.get("action_space", "")))


def _scorer(detector: str, directory: Path, entry: dict[str, Any], settings: CalibrationSettings,
            layout: Layout) -> Any:  # a Scorer
    """A detector's fitted scorer from its files (RND-OE's description checked first: any later failure is the
    weights')."""
    if detector == RND_OE:
        _check_description(directory, layout.embedding_dim, settings)
        return RndOeScorer(_load_rnd(directory, settings, layout.embedding_dim, FORMAT_VERSION), settings.profile_obj)
    try:
        return load_scorer(detector, directory, entry, settings.options(), layout.action_space, settings.profile_obj)
    except (CoreError, ValueError) as error:  # a model file's error, a value the scorer refuses
        raise CalibrationError(one_line(error)) from error


def _check_description(directory: Path, embedding_dim: int, settings: CalibrationSettings) -> None:
    """``rnd_oe.json`` must describe the network ``calibration.yaml`` names (``RNDOE.save``'s fields): the content
    hash covers the YAML and the weights, this check the description."""
    check_files(directory, (RND_CONFIG_FILE,))
    path = directory / RND_CONFIG_FILE
    try:
        described = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise CalibrationError(f"{path}: unreadable ({one_line(error)})") from error
    expected = {"embedding_dim": embedding_dim, "seed": settings.seed, "config": settings.rnd.to_dict()}
    if described != expected:
        raise CalibrationError(f"{path}: does not describe the RND-OE network of {CALIBRATION_FILE} (file modified, "
                               "or files of different runs)")


def _load_rnd(directory: Path, settings: CalibrationSettings, embedding_dim: int, version: int) -> RNDOE:
    """The RND-OE model, once its description is known to be right: any failure is the weights'. The weights of
    format 1 are read with torch (imported here, for the conversion alone)."""
    legacy = version == LEGACY_FORMAT_VERSION
    path = directory / (RND_LEGACY_WEIGHTS_FILE if legacy else RND_WEIGHTS_FILE)
    check_files(directory, (path.name,))
    try:
        if not legacy:
            return RNDOE.load(directory)
        from fiper_ros.core.rnd_train import read_legacy  # noqa: PLC0415 - torch only to convert format 1

        return read_legacy(directory, embedding_dim, settings.rnd, settings.seed)
    except Exception as error:  # numpy, zipfile and torch raise OSError, ValueError, pickle errors...
        cause = error.__cause__ if isinstance(error, RNDError) and error.__cause__ is not None else error
        detail = re.split(r"(?<=\.)\s|\n", str(cause).strip(), maxsplit=1)[0]
        raise CalibrationError(f"{path}: not readable RND-OE weights (damaged, or not written by fiper calibrate: "
                               f"{type(cause).__name__}{': ' + detail if detail else ''})") from error


def _pair_hash(data: dict[str, Any], rnd: RNDOE) -> str:
    """The content hash of formats 1 and 2: SHA-256 over the YAML content without it, then RND-OE's digest."""
    digest = hashlib.sha256(yaml.safe_dump(data, sort_keys=True).encode())
    digest.update(rnd.digest().encode())
    return digest.hexdigest()


def _read_pair(directory: Path, data: dict[str, Any], version: int) -> Calibration:
    """A calibration of format 1 or 2 (FIPER's pair, or RND-OE alone) as a calibration of this code."""
    path = directory / CALIBRATION_FILE
    weights = RND_LEGACY_WEIGHTS_FILE if version == LEGACY_FORMAT_VERSION else RND_WEIGHTS_FILE
    check_files(directory, (RND_CONFIG_FILE, weights))
    stored = data.pop("content_hash", None)
    try:
        settings = CalibrationSettings.from_v2(data["settings"])
        has_ace = settings.has_ace
        layout = Layout(int(data["embedding_dim"]), *((int(data["action_dim"]), int(data["horizon"]),
                                                        int(data["exec_steps"]), str(data["action_space"]))
                                                       if has_ace else ()))
        thresholds = {RND_OE: Threshold.from_dict(data["thresholds"]["obs"])}
        if has_ace:
            thresholds[ACE] = Threshold.from_dict(data["thresholds"]["act"])
            ranges = np.asarray(data["ranges"], dtype=np.float64)
        split = dict(data.get("split", {}))
        num_rollouts = int(data["num_rollouts"])
        task = str(data.get("task", ""))
        false_alarms = dict(data.get("false_alarm_estimate", {}))
    except KeyError as error:
        raise CalibrationError(f"{path}: missing entry {error}") from error
    except (CoreError, TypeError, ValueError) as error:  # ThresholdError, RNDConfig and settings values
        raise CalibrationError(f"{path}: malformed entry ({one_line(error)})") from error
    _check_description(directory, layout.embedding_dim, settings)
    rnd = _load_rnd(directory, settings, layout.embedding_dim, version)
    if stored != _pair_hash(data, rnd):
        raise CalibrationError(f"{path}: content hash mismatch (file or weights modified, or files of different runs)")
    profile = settings.profile_obj
    detectors = {RND_OE: DetectorPart(RndOeScorer(rnd, profile), thresholds[RND_OE])}
    if has_ace:
        detectors[ACE] = DetectorPart(AceScorer(ranges, settings.options(), layout.action_space, profile),
                                      thresholds[ACE])
    split.pop("guarantee", None)  # said again by this code's words (Calibration.guarantee)
    return Calibration(settings, layout, {task: TaskPart(detectors, num_rollouts, split)}, {}, false_alarms)
