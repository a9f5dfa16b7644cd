"""Suite-wide fixtures: refuse to run outside the workspace environment; DDS isolation per test."""
from __future__ import annotations

import os
from collections.abc import Iterator

import pytest

from helpers.dds import allocate_domain


def pytest_configure(config: pytest.Config) -> None:
    """Stop with a clear message when env.sh was not sourced (make test does it)."""
    del config
    if os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE") != "LOCALHOST" or not os.environ.get("FIPER_ROOT"):
        pytest.exit("run the tests through 'make test' (or source ./env.sh first): DDS must stay on loopback", 2)


@pytest.fixture
def ros_domain() -> Iterator[int]:
    """A ROS_DOMAIN_ID nobody else on this machine uses while the test runs."""
    with allocate_domain() as domain:
        yield domain
