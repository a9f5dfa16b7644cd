"""The search rule of relative model and calibration paths (fiper_ros/data_paths.py): the working directory, then
the installed fiper_ros share, then each directory of $FIPER_MODELS; absolute paths as given."""
from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from fiper_ros.data_paths import MODELS_ENV, DataPathNotFound, data_path_argument, package_share, resolve_data_path

SHIPPED = "models/sorting/calibration"


def test_the_shipped_models_are_installed_in_the_share() -> None:
    share = package_share()
    assert share is not None
    assert (share / SHIPPED / "calibration.yaml").is_file()


def test_from_another_directory_the_share_has_the_shipped_calibration(tmp_path: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert resolve_data_path(SHIPPED, env={}) == package_share() / SHIPPED


def test_the_working_directory_comes_first(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / SHIPPED).mkdir(parents=True)  # e.g. just written by fiper calibrate --out
    monkeypatch.chdir(tmp_path)
    assert resolve_data_path(SHIPPED, env={}) == Path(SHIPPED)


def test_fiper_models_directories_are_searched_after_the_share_in_order(tmp_path: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    first, second = tmp_path / "a", tmp_path / "b"
    for folder in (first / "pick" / "x", second / "pick" / "x", second / "pick" / "calibration", first / SHIPPED):
        folder.mkdir(parents=True)
    monkeypatch.chdir(tmp_path)
    env = {MODELS_ENV: f"{first}:{second}"}
    assert resolve_data_path("pick/calibration", env) == second / "pick" / "calibration"
    assert resolve_data_path("pick/x", env) == first / "pick" / "x"
    assert resolve_data_path(SHIPPED, env) == package_share() / SHIPPED  # the share before $FIPER_MODELS


def test_an_absolute_path_is_taken_as_given(tmp_path: Path) -> None:
    missing = tmp_path / "nothing"
    assert resolve_data_path(missing, env={}) == missing  # its loader names what is missing


def test_found_nowhere_names_every_place_looked_at(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    with pytest.raises(DataPathNotFound) as unset:
        resolve_data_path("models/nope", env={})
    assert str(tmp_path) in str(unset.value) and str(package_share()) in str(unset.value)
    assert f"${MODELS_ENV} is not set" in str(unset.value)
    with pytest.raises(DataPathNotFound) as searched:
        resolve_data_path("models/nope", env={MODELS_ENV: str(tmp_path / "extra")})
    assert str(tmp_path / "extra") in str(searched.value)


def test_the_commands_option_type_turns_not_found_into_a_usage_error(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv(MODELS_ENV, raising=False)
    assert data_path_argument(SHIPPED) == package_share() / SHIPPED
    with pytest.raises(argparse.ArgumentTypeError, match="models/nope: not found"):
        data_path_argument("models/nope")
