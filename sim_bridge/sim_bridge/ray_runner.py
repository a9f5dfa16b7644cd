"""The Ray runner of ``fiper collect --ray`` (:mod:`fiper_ros.commands.collect`): one Ray task per closed-loop
episode (:func:`~sim_bridge.closed_loop.run_episode`: the policy and MuJoCo, no ROS) on any node of the cluster
(:mod:`fiper_ros.cluster`); the rollouts come back to the collecting process, which writes their bags in seed order
exactly as :class:`~sim_bridge.collect_runner.InProcessRunner` does, so the folder is the one ``--jobs 1`` writes.
"""
from __future__ import annotations

import itertools
import tempfile
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import torch

from fiper_ros.bagio.collect_index import CollectSetup
from fiper_ros.bagio.errors import BagError
from fiper_ros.cluster import ClusterError, TaskPool, cluster_cpus
from fiper_ros.policy.policy import CONFIG_FILE, WEIGHTS_FILE, Policy

from .closed_loop import EpisodeResult, run_episode
from .collect_runner import InProcessRunner

#: Episodes kept started per CPU of the cluster: a worker whose episode finished before the one the bags wait
#: for takes the next one at once.
AHEAD_PER_CPU = 2

#: The policy of a Ray worker process: model hash -> policy (loaded once per process, the newest model only).
_worker_policy: dict[str, Policy] = {}


def _policy(model_hash: str, model: list[Any]) -> Policy:
    """The worker's policy of ``model_hash``; its files (``model[0]``, an object of the cluster's store) are read
    only the first time."""
    if model_hash not in _worker_policy:
        import ray  # noqa: PLC0415 - the worker of a Ray task has it

        files: dict[str, bytes] = ray.get(model[0])
        with tempfile.TemporaryDirectory(prefix="fiper-policy-") as directory:
            for name, data in files.items():
                (Path(directory) / name).write_bytes(data)
            policy = Policy.load(directory)
        _worker_policy.clear()
        _worker_policy[model_hash] = policy
    return _worker_policy[model_hash]


def episode_task(model_hash: str, model: list[Any], scenario: str, seed: int, batch: int,
                 max_policy_steps: int | None, threads: int) -> tuple[EpisodeResult, str, float]:
    """One episode on a Ray worker (``model``: the reference of the model's files, in a list so that Ray hands
    over the reference, not the files), the id of the node that ran it and the episode's own seconds."""
    import ray  # noqa: PLC0415

    torch.set_num_threads(threads)
    policy = _policy(model_hash, model)
    started = time.perf_counter()
    result = run_episode(policy, scenario, seed, batch=batch, max_policy_steps=max_policy_steps)
    return result, ray.get_runtime_context().get_node_id(), time.perf_counter() - started


def _describe(key: tuple[str, int]) -> str:
    return f"{key[0]} seed {key[1]}"


class RayRunner(InProcessRunner):
    """Episodes run as Ray tasks of the joined cluster; bags written here in seed order (as in-process).

    Args:
        policy: The loaded policy (its model's files are sent once to the cluster's object store).
        setup: The collect's setup (batch, policy-step cap, the model's hash).
        model_dir: The policy's folder.
        threads: Torch threads of each task.
    """

    def __init__(self, policy: Policy, setup: CollectSetup, model_dir: Path, threads: int = 1) -> None:
        super().__init__(policy, setup)
        import ray  # noqa: PLC0415 - connected by the caller (fiper_ros.cluster.connected)

        files = {name: (model_dir / name).read_bytes() for name in (CONFIG_FILE, WEIGHTS_FILE)}
        self._model = [ray.put(files)]
        self._threads = threads
        self._tasks: TaskPool[tuple[str, int]] = TaskPool(episode_task, _describe)
        #: The nodes that ran the episodes taken so far.
        self.nodes: set[str] = set()
        #: The own seconds of each episode taken (run_episode on its worker, without Ray's part).
        self.episode_seconds: list[float] = []

    def _args(self, scenario: str, seed: int) -> tuple[Any, ...]:
        return (self.setup.policy_hash, self._model, scenario, seed, self.setup.batch, self.setup.max_policy_steps,
                self._threads)

    def ahead(self, scenario: str, seeds: Iterable[int]) -> None:
        """Keep :data:`AHEAD_PER_CPU` episodes per CPU of the cluster started, the first of ``seeds``; drop
        started episodes not among them."""
        wanted = [(scenario, seed) for seed in itertools.islice(seeds, AHEAD_PER_CPU * max(1, cluster_cpus()))]
        for key in self._tasks.keys() - set(wanted):
            self._tasks.drop(key)
            self.discarded += 1
        for key in wanted:
            self._tasks.submit(key, *self._args(*key))

    def result(self, scenario: str, seed: int) -> EpisodeResult:
        """The episode's result from the cluster (started now if it was not)."""
        self._tasks.submit((scenario, seed), *self._args(scenario, seed))
        try:
            result, node, seconds = self._tasks.result((scenario, seed))
        except ClusterError as error:
            raise BagError(str(error)) from None
        self.nodes.add(node)
        self.episode_seconds.append(seconds)
        return result

    def status(self) -> str:
        """The cluster's part of a progress line: episodes done, running, queued, lost (and run again), and
        the nodes that ran the episodes written so far."""
        return f"{self._tasks.status()}; {len(self.nodes)} node{'s' if len(self.nodes) != 1 else ''}"

    def close(self) -> None:
        """Cancel the episodes not finished."""
        self.discarded += len(self._tasks.keys())
        self._tasks.close()
