"""The failure classes of calibration directories (docs/reliability.md, "Bags and calibration files"):
each a function that damages a copy of a good calibration directory in place and returns the text the
refusal must hold (naming the file), shared by the loader table of test/core/test_calibration.py, the
command tables of test/bags/test_errors.py and the scoring nodes' table of
test/nodes/test_calibration_files.py. No ROS here (the core tests use it).

Calibrations are fitted by :func:`fiper_ros.core.calibration.calibrate` and saved, then edited, cut or
replaced file by file; :func:`fit_damages` gives calibrations that load but do not fit the data.
"""
from __future__ import annotations

import dataclasses
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import yaml

from fiper_ros.core.calibration import load_calibration
from fiper_ros.core.calibration_file import CALIBRATION_FILE, FORMAT_VERSION, READ_VERSIONS
from fiper_ros.core.rnd_oe import CONFIG_FILE, WEIGHTS_FILE

#: A damage: modifies the calibration directory at the path, returns the text its refusal holds.
Damage = Callable[[Path], str]
HASH_MISMATCH = "content hash mismatch (file or models modified, or files of different runs)"


def _edit_yaml(directory: Path, edit: Callable[[dict], None]) -> Path:
    path = directory / CALIBRATION_FILE
    content = yaml.safe_load(path.read_text())
    edit(content)
    path.write_text(yaml.safe_dump(content, sort_keys=False))
    return path


def directory_missing(directory: Path) -> str:
    shutil.rmtree(directory)
    return f"calibration directory not found: {directory}"


def yaml_missing(directory: Path) -> str:
    (directory / CALIBRATION_FILE).unlink()
    return f"calibration file not found: {directory / CALIBRATION_FILE}"


def weights_missing(directory: Path) -> str:
    (directory / WEIGHTS_FILE).unlink()
    return f"calibration file not found: {directory / WEIGHTS_FILE}"


def description_missing(directory: Path) -> str:
    (directory / CONFIG_FILE).unlink()
    return f"calibration file not found: {directory / CONFIG_FILE}"


def yaml_not_yaml(directory: Path) -> str:
    (directory / CALIBRATION_FILE).write_text(f"format_version: {FORMAT_VERSION}\nranges: [0.5,\n")
    return f"{directory / CALIBRATION_FILE}: not valid YAML (while parsing "


def yaml_empty(directory: Path) -> str:
    (directory / CALIBRATION_FILE).write_text("")
    return f"{directory / CALIBRATION_FILE}: not a calibration (a YAML mapping expected, got an empty file)"


def newer_format_version(directory: Path) -> str:
    path = _edit_yaml(directory, lambda content: content.update(format_version=FORMAT_VERSION + 1))
    return (f"{path}: format_version {FORMAT_VERSION + 1} not supported (this code reads "
            f"{', '.join(map(str, READ_VERSIONS))})")


def older_format_version(directory: Path) -> str:
    """Format 1 (weights in the torch file rnd_oe.pt): refused with the command that converts it."""
    path = _edit_yaml(directory, lambda content: content.update(format_version=1))
    return f"{path}: format_version 1, whose RND-OE weights (rnd_oe.pt) only torch reads: convert it once with: "


def entry_missing(directory: Path) -> str:
    path = _edit_yaml(directory, lambda content: content["layout"].pop("embedding_dim"))
    return f"{path}: missing entry 'embedding_dim'"


def entry_malformed(directory: Path) -> str:
    path = _edit_yaml(directory, lambda content: content["layout"].update(embedding_dim="sixteen"))
    return f"{path}: malformed entry (invalid literal for int() with base 10: 'sixteen')"


def _rnd_oe_threshold(content: dict) -> dict:
    """The RND-OE threshold entry of a calibration of one task."""
    return next(iter(content["tasks"].values()))["detectors"]["rnd_oe"]["threshold"]


def yaml_edited(directory: Path) -> str:
    """A threshold value changed: still a well-formed calibration, but not the fitted one."""
    path = _edit_yaml(directory, lambda content: _rnd_oe_threshold(content)["values"].__setitem__(0, 1e-3))
    return f"{path}: {HASH_MISMATCH}"


def weights_edited(directory: Path) -> str:
    """One predictor weight changed, saved as a valid weights file."""
    path = directory / WEIGHTS_FILE
    arrays = dict(np.load(path))
    name = next(name for name in arrays if name.startswith("predictor/"))
    arrays[name] = arrays[name].copy()
    arrays[name].flat[0] += 1.0
    with path.open("wb") as stream:
        np.savez(stream, **arrays)
    return f"{directory / CALIBRATION_FILE}: {HASH_MISMATCH}"


def weights_truncated(directory: Path) -> str:
    path = directory / WEIGHTS_FILE
    path.write_bytes(path.read_bytes()[:1000])
    return f"{path}: not readable RND-OE weights (damaged, or not written by fiper calibrate: "


def weights_random(directory: Path) -> str:
    path = directory / WEIGHTS_FILE
    path.write_bytes(np.random.default_rng(0).bytes(4096))
    return f"{path}: not readable RND-OE weights (damaged, or not written by fiper calibrate: "


def description_edited(directory: Path) -> str:
    path = directory / CONFIG_FILE
    path.write_text(path.read_text().replace('"seed": 0', '"seed": 5'))
    return (f"{path}: does not describe the RND-OE network of calibration.yaml (file modified, or files of "
            "different runs)")


def description_not_json(directory: Path) -> str:
    path = directory / CONFIG_FILE
    path.write_text("{embedding_dim: 16")
    return f"{path}: unreadable (Expecting property name enclosed in double quotes"


CALIBRATION_DAMAGES: dict[str, Damage] = {damage.__name__: damage for damage in (
    directory_missing, yaml_missing, weights_missing, description_missing, yaml_not_yaml, yaml_empty,
    newer_format_version, older_format_version, entry_missing, entry_malformed, yaml_edited, weights_edited,
    weights_truncated, weights_random, description_edited, description_not_json)}


# -- calibrations that load but do not fit ----------------------------------------------------------

#: The names of :func:`fit_damages` (for parametrizing before the calibrations exist).
FIT_DAMAGES = ("another_embedding_size", "another_action_shape", "another_execution_horizon", "another_action_space",
               "another_task")


def resaved(base: Path, directory: Path, task: str | None = None, **layout: object) -> None:
    """``base``'s calibration with a changed ``layout`` (and one task renamed ``task``), saved as a valid calibration
    (its own content hash)."""
    calibration = load_calibration(base)
    tasks = calibration.tasks if task is None else {task: next(iter(calibration.tasks.values()))}
    dataclasses.replace(calibration, layout=dataclasses.replace(calibration.layout, **layout), tasks=tasks).save(directory)


def fit_damages(base: Path, foreign: Path) -> dict[str, Damage]:
    """Calibrations that load but do not fit the data ``base`` fits: another embedding size (the valid
    calibration ``foreign``), action shape, execution horizon, action space or task."""
    embedding_dim = load_calibration(foreign).layout.embedding_dim
    fitting = load_calibration(base).layout

    def another_embedding_size(directory: Path) -> str:
        shutil.rmtree(directory)
        shutil.copytree(foreign, directory)
        return f"calibration mismatch for embedding_dim: expected {embedding_dim}, got "

    def another_action_shape(directory: Path) -> str:
        resaved(base, directory, horizon=2 * fitting.horizon)
        return f"calibration mismatch for horizon: expected {2 * fitting.horizon}, got {fitting.horizon}"

    def another_execution_horizon(directory: Path) -> str:
        resaved(base, directory, exec_steps=2 * fitting.exec_steps)
        return f"calibration mismatch for exec_steps: expected {2 * fitting.exec_steps}, got {fitting.exec_steps}"

    def another_action_space(directory: Path) -> str:
        resaved(base, directory, action_space="joint_position")
        return f"calibration mismatch for action_space: expected joint_position, got {fitting.action_space}"

    def another_task(directory: Path) -> str:
        resaved(base, directory, task="another_task")
        return "calibration mismatch for task: expected another_task, got "

    damages = {damage.__name__: damage for damage in (another_embedding_size, another_action_shape,
                                                      another_execution_horizon, another_action_space, another_task)}
    assert tuple(damages) == FIT_DAMAGES
    return damages
