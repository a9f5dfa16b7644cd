"""The calibration file ``calibration.yaml``: its format versions, how it is read, and what it declares.

Light (no model is loaded), so that a node which only needs to know what a calibration declares (the fusion
node: which detectors it fuses and how many votes an alarm needs) reads it without the score models.
:func:`fiper_ros.core.calibration.load_calibration` reads the whole calibration (models, content hash) through
:func:`read_yaml`.
"""
from __future__ import annotations

import shlex
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from fiper_ros.core.combine_mode import CombineMode
from fiper_ros.core.detectors import DETECTORS, check_once, check_pair_format, in_fusion_order
from fiper_ros.core.errors import ChoiceError, CoreError

FORMAT_VERSION = 3
"""The format this code writes: any declared detectors, each task's models and thresholds, the combine."""
PAIR_FORMAT_VERSION = 2
"""FIPER's pair (or RND-OE alone) with RND-OE's weights in ``rnd_oe.npz``: still read, as it is."""
READ_VERSIONS = (FORMAT_VERSION, PAIR_FORMAT_VERSION)
LEGACY_FORMAT_VERSION = 1
"""RND-OE's weights in the torch file ``rnd_oe.pt``. Refused on load with the command that converts it
(:func:`upgrade_command`), which is the only reader of it left."""
CALIBRATION_FILE = "calibration.yaml"


class CalibrationError(CoreError):
    """A calibration cannot be fitted, read or used."""


def one_line(error: object) -> str:
    """``error`` as one line (YAML and torch errors span several)."""
    return " ".join(str(error).split())


def check_files(directory: Path, names: Sequence[str]) -> None:
    """:class:`CalibrationError` naming a missing calibration ``directory`` or the first missing file of ``names``."""
    if not directory.is_dir():
        raise CalibrationError(f"calibration directory not found: {directory}")
    for name in names:
        if not (directory / name).is_file():
            raise CalibrationError(f"calibration file not found: {directory / name}")


def upgrade_command(directory: Path) -> str:
    """The command that converts the format-1 calibration in ``directory`` to the current format, in place."""
    quoted = shlex.quote(str(directory))
    return f"fiper calibrate --upgrade {quoted} -o {quoted} --force"


def read_yaml(path: Path, versions: Sequence[int] = READ_VERSIONS) -> dict[str, Any]:
    """``calibration.yaml`` as a mapping of one of ``versions`` (the ones this code reads unless converting); a
    calibration of the legacy format is refused with the command that converts it."""
    try:
        with path.open() as stream:
            content = yaml.safe_load(stream)
    except OSError as error:
        raise CalibrationError(f"{path}: unreadable ({one_line(error)})") from error
    except yaml.YAMLError as error:
        raise CalibrationError(f"{path}: not valid YAML ({one_line(error)})") from error
    if not isinstance(content, dict):
        got = "an empty file" if content is None else f"a YAML {type(content).__name__}"
        raise CalibrationError(f"{path}: not a calibration (a YAML mapping expected, got {got})")
    found = content.get("format_version")
    if found == LEGACY_FORMAT_VERSION and LEGACY_FORMAT_VERSION not in versions:
        raise CalibrationError(f"{path}: format_version {found}, whose RND-OE weights (rnd_oe.pt) only torch reads: "
                               f"convert it once with: {upgrade_command(path.parent)}")
    if found == FORMAT_VERSION and FORMAT_VERSION not in versions:
        raise CalibrationError(f"{path}: already of format_version {found}, nothing to convert")
    if found not in versions:
        raise CalibrationError(f"{path}: format_version {found!r} not supported (this code reads "
                               f"{', '.join(map(str, READ_VERSIONS))})")
    return content


def detectors_of(content: dict[str, Any], path: Path) -> tuple[str, ...]:
    """The detectors a calibration's content declares (``settings.detectors``; absent: FIPER's pair, as in
    every calibration written before observation-only ones existed), in the fusion's order."""
    settings = content.get("settings")
    if not isinstance(settings, dict):
        raise CalibrationError(f"{path}: missing entry 'settings'")
    try:
        if content.get("format_version") == PAIR_FORMAT_VERSION:
            return check_pair_format(settings.get("detectors", DETECTORS))
        names = settings.get("detectors", DETECTORS)
        if not isinstance(names, list) or not all(isinstance(name, str) for name in names):
            raise CalibrationError(f"{path}: malformed entry (detectors must be a list of names, got {names!r})")
        return in_fusion_order(check_once(names))
    except (TypeError, ChoiceError) as error:
        raise CalibrationError(f"{path}: malformed entry ({one_line(error)})") from error


def declared_detectors(directory: str | Path) -> tuple[str, ...]:
    """The detectors the calibration in ``directory`` declares; :class:`CalibrationError` (one line naming the
    file) if it is missing or unreadable."""
    return declared(directory).detectors


@dataclass(frozen=True)
class Declared:
    """What a calibration declares to the fusion node: its detectors (in order) and how they are combined."""

    detectors: tuple[str, ...]
    combine: str


def declared(directory: str | Path) -> Declared:
    """The detectors and the combine the calibration in ``directory`` declares (a calibration of format 2 without
    ACE wrote no combine: one detector alone, ``and``); :class:`CalibrationError` (one line naming the file) if it
    is missing or unreadable."""
    check_files(Path(directory), (CALIBRATION_FILE,))
    path = Path(directory) / CALIBRATION_FILE
    content = read_yaml(path)
    return Declared(detectors_of(content, path), str(content["settings"].get("combine", CombineMode.AND.value)))


def merged_split(records: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """Which successes fitted what, over every task: the tasks' split records merged by rollout id (empty when no
    task recorded one); what tells a calibration's own rollouts from new ones."""
    records = [record for record in records if record]
    if not records:
        return {}
    merged: dict[str, Any] = {"mode": records[0]["mode"]}
    for key in ("fit", "conformal", "folds"):
        values = [item for record in records for item in record.get(key, ())]
        if values or key != "folds":
            merged[key] = values
    return merged


def split_of(content: Mapping[str, Any]) -> dict[str, Any]:
    """The merged split record (:func:`merged_split`) of a calibration's ``calibration.yaml`` content, either
    format."""
    if content.get("format_version") == PAIR_FORMAT_VERSION:
        return dict(content.get("split") or {})
    return merged_split([dict(part.get("split") or {}) for part in (content.get("tasks") or {}).values()])
