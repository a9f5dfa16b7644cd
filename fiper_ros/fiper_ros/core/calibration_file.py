"""The calibration file ``calibration.yaml``: its format version, how it is read, and what it declares.

Torch-free, so that a node which only needs to know what a calibration declares (the fusion node: which
detectors it fuses) reads it without loading the score models. :func:`fiper_ros.core.calibration.
load_calibration` reads the whole calibration (network weights, content hash) through :func:`read_yaml`.
"""
from __future__ import annotations

import shlex
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from fiper_ros.core.detectors import DETECTORS, check_detectors

FORMAT_VERSION = 2
"""The format this code writes and reads: RND-OE's weights in ``rnd_oe.npz``, which numpy reads (no torch)."""
LEGACY_FORMAT_VERSION = 1
"""The format before: RND-OE's weights in the torch file ``rnd_oe.pt``. Refused on load with the command that
converts it (:func:`upgrade_command`), which is the only reader of it left."""
CALIBRATION_FILE = "calibration.yaml"


class CalibrationError(ValueError):
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


def read_yaml(path: Path, version: int = FORMAT_VERSION) -> dict[str, Any]:
    """``calibration.yaml`` as a mapping of format ``version`` (the current one unless converting); a
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
    if found == LEGACY_FORMAT_VERSION and version == FORMAT_VERSION:
        raise CalibrationError(f"{path}: format_version {found}, whose RND-OE weights (rnd_oe.pt) only torch reads: "
                               f"convert it once with: {upgrade_command(path.parent)}")
    if found == FORMAT_VERSION and version == LEGACY_FORMAT_VERSION:
        raise CalibrationError(f"{path}: already of format_version {found}, nothing to convert")
    if found != version:
        raise CalibrationError(f"{path}: format_version {found!r} not supported (this code reads {version})")
    return content


def detectors_of(content: dict[str, Any], path: Path) -> tuple[str, ...]:
    """The detectors a calibration's content declares (``settings.detectors``; absent: FIPER's pair, as in
    every calibration written before observation-only ones existed)."""
    settings = content.get("settings")
    if not isinstance(settings, dict):
        raise CalibrationError(f"{path}: missing entry 'settings'")
    try:
        return check_detectors(settings.get("detectors", DETECTORS))
    except (TypeError, ValueError) as error:
        raise CalibrationError(f"{path}: malformed entry ({one_line(error)})") from error


def declared_detectors(directory: str | Path) -> tuple[str, ...]:
    """The detectors the calibration in ``directory`` declares; :class:`CalibrationError` (one line naming the
    file) if it is missing or unreadable."""
    check_files(Path(directory), (CALIBRATION_FILE,))
    path = Path(directory) / CALIBRATION_FILE
    return detectors_of(read_yaml(path), path)
