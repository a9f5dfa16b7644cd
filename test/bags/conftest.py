"""Fixtures of the bag tests: a small bag of synthetic rollouts (3 successes, 1 failure) and its calibration,
observation-only data (a calibration and a test bag without action batches, generated) with its
observation-only calibration, and a publisher of the policy's topics and the alarm over DDS."""
from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from helpers.stream import Policy
from helpers.synthetic import OBSERVATION_CALIBRATE, make_calibration, make_rollout

from fiper_ros.bagio.rollout_bags import write_rollouts
from fiper_ros.bagio.schema import BagInfo
from fiper_ros.cli import main
from fiper_ros.commands.samples import observation_only
from fiper_ros.core.rollout import Rollout

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


@pytest.fixture(scope="session")
def observation_bags(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """``calibration`` (12 successes) and ``test`` (2 successes, 1 failure), each as written (``*_full``, with
    action batches) and as its observation-only copy."""
    root = tmp_path_factory.mktemp("observation_only")
    sets = {"calibration": ([make_rollout(200 + i) for i in range(12)], list(range(1, 13))),
            "test": ([make_rollout(300), make_rollout(301, fail=True), make_rollout(302)], [21, 22, 23])}
    bags = {}
    for split, (rollouts, ids) in sets.items():
        full = root / f"{split}_full"
        write_rollouts(full, rollouts, ids, BagInfo(task="synthetic", synthetic=True, source="test", split=split))
        bags[f"{split}_full"], bags[split] = full, observation_only(full, root / split)
    return bags


@pytest.fixture(scope="session")
def observation_calibration(observation_bags: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The observation-only calibration ``fiper calibrate --detectors rnd_oe`` fits on the observation-only bag."""
    out = tmp_path_factory.mktemp("observation_calibration") / "calibration"
    assert main(["calibrate", str(observation_bags["calibration"]), "-o", str(out), *OBSERVATION_CALIBRATE]) == 0
    return out


@pytest.fixture
def policy(ros_domain: int) -> Iterator[Policy]:
    """The test's publishers of the policy topics and the alarm, in the test's ROS domain."""
    p = Policy(ros_domain)
    try:
        yield p
    finally:
        p.close()
