"""Fixtures of the node tests: one small calibration per session, a fresh in-process suite per test, a
/diagnostics listener."""
from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from helpers.diagnostics import DiagnosticsListener
from helpers.suite import Suite
from helpers.synthetic import make_calibration


@pytest.fixture(scope="session")
def calibration_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_calibration(tmp_path_factory.mktemp("calibration"))


@pytest.fixture
def suite(ros_domain: int, calibration_dir: Path) -> Iterator[Suite]:
    s = Suite(ros_domain, str(calibration_dir))
    try:
        s.wait_active()
        yield s
    finally:
        s.close()


@pytest.fixture
def listener(ros_domain: int) -> Iterator[DiagnosticsListener]:
    listening = DiagnosticsListener(ros_domain)
    try:
        yield listening
    finally:
        listening.close()
