"""Fixtures of the bag tests: a small bag of synthetic rollouts (3 successes, 1 failure) and its calibration,
and a publisher of the policy's topics and the alarm over DDS."""
from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from fiper_ros.bags.rollouts import write_rollouts
from fiper_ros.bags.schema import BagInfo
from fiper_ros.core.rollout import Rollout
from helpers.stream import Policy
from helpers.synthetic import make_calibration, make_rollout

ROLLOUT_IDS = [7, 8, 9, 10]


def small_rollouts() -> list[Rollout]:
    """Three successes and one failure of the synthetic test task."""
    return [make_rollout(100), make_rollout(101), make_rollout(102, fail=True), make_rollout(103)]


@pytest.fixture
def rollouts() -> list[Rollout]:
    """The rollouts of ``small_bag`` (ids ``ROLLOUT_IDS``)."""
    return small_rollouts()


@pytest.fixture
def rollout_ids() -> list[int]:
    """Message rollout ids of the rollouts of ``small_bag``."""
    return list(ROLLOUT_IDS)


@pytest.fixture(scope="session")
def small_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("bags") / "small"
    write_rollouts(path, small_rollouts(), ROLLOUT_IDS, BagInfo(task="synthetic", synthetic=True, source="test"))
    return path


@pytest.fixture(scope="session")
def small_calibration(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_calibration(tmp_path_factory.mktemp("calibration"))


@pytest.fixture
def policy(ros_domain: int) -> Iterator[Policy]:
    """The test's publishers of the policy topics and the alarm, in the test's ROS domain."""
    p = Policy(ros_domain)
    try:
        yield p
    finally:
        p.close()
