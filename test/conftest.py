"""Suite-wide fixtures: refuse to run outside the workspace environment; DDS isolation per test; Fast DDS
shared memory of dead processes removed at the start of the session and of every DDS test (tests kill
nodes on purpose). The tests' own participants use the suite's Fast DDS discovery profile, as docs/nodes.md
tells a supervisor to (the nodes they start use it anyway): a node they start is seen within about 0.5 s."""
from __future__ import annotations

import os
from collections.abc import Iterator

import pytest

from fiper_ros.platform.process import use_discovery_profile
from helpers.dds import allocate_domain, clean_stale

#: The session's start-up cleaning, reported in pytest's header.
_STARTUP_CLEANING = pytest.StashKey[str]()


def pytest_configure(config: pytest.Config) -> None:
    """Stop with a clear message when env.sh was not sourced (make test does it); then clean shared memory."""
    if os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE") != "LOCALHOST" or not os.environ.get("FIPER_ROOT"):
        pytest.exit("run the tests through 'make test' (or source ./env.sh first): DDS must stay on loopback", 2)
    config.stash[_STARTUP_CLEANING] = clean_stale().summary()
    use_discovery_profile()  # before any participant of this process


def pytest_report_header(config: pytest.Config) -> str:
    """The start-up cleaning's line."""
    return config.stash[_STARTUP_CLEANING]


@pytest.fixture
def ros_domain() -> Iterator[int]:
    """A ROS_DOMAIN_ID nobody else on this machine uses while the test runs (stale shared memory removed)."""
    clean_stale()
    with allocate_domain() as domain:
        yield domain
