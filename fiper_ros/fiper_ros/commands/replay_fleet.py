"""``fiper replay --offline --ray [ADDRESS]``: the offline alarms of many bags at once (a fleet's recordings), one
Ray task per bag (:func:`fiper_ros.evaluation.offline.predict_bag`, the same function as the serial run) on a local
instance or an existing cluster (:mod:`fiper_ros.cluster`); the calibration goes once to the cluster's object
store, the bags are read where they lie (on a cluster: a path every node mounts, docs/scale.md), and the results
come back in the order of the bags, so the closing table is the serial run's.
"""
from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fiper_ros.cluster import TaskPool, connected
from fiper_ros.commands.options import fk_of
from fiper_ros.evaluation.offline import predict_bag

if TYPE_CHECKING:
    from fiper_ros.core.calibration import Calibration
    from fiper_ros.core.kinematics import RobotModel
    from fiper_ros.evaluation.results import RolloutResult


def bag_task(bag: str, calibration: list[Any], robot: RobotModel | None) -> list[RolloutResult]:
    """The offline alarms of every rollout of ``bag`` on a Ray worker (``calibration``: the reference of the
    calibration in the object store, in a list so that Ray hands over the reference)."""
    import ray  # noqa: PLC0415 - the worker of a Ray task has it

    return predict_bag(Path(bag), ray.get(calibration[0]), fk_of(robot))


def predict_bags(bags: list[Path], calibration: Calibration, robot: RobotModel | None,
                 address: str) -> list[RolloutResult]:
    """:func:`predict_bag` of every bag as Ray tasks of the cluster at ``address``; the results in bag order.

    Raises:
        ClusterError: The cluster cannot be reached, or a bag's task failed (its reason, in one line).
    """
    results: dict[int, list[RolloutResult]] = {}
    with connected(address):
        import ray  # noqa: PLC0415 - after connected, which sets Ray's environment

        shared = [ray.put(calibration)]
        tasks: TaskPool[int] = TaskPool(bag_task, lambda index: f"bag {bags[index]}")
        for index, bag in enumerate(bags):
            tasks.submit(index, str(bag.resolve()), shared, robot)
        try:
            for index, rows in tasks.completed():
                results[index] = rows
                print(f"fiper replay: {len(results)}/{len(bags)} bags | ray: {tasks.status()}", file=sys.stderr,
                      flush=True)
        finally:
            tasks.close()
    return [result for index in range(len(bags)) for result in results[index]]
