"""The in-process runner of ``fiper collect`` (:mod:`fiper_ros.commands.collect`): closed-loop episodes of a
policy in the simulator (:func:`~sim_bridge.closed_loop.run_episode`, no ROS, no DDS), in this process or in
worker processes, each written as the bag of the messages a policy node publishes on the task's control clock.
"""
from __future__ import annotations

import itertools
import multiprocessing
import os
import zlib
from collections.abc import Iterable
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch

from fiper_ros.bagio.collect_index import CollectSetup, RanEpisode
from fiper_ros.bagio.rollout_bags import write_rollouts
from fiper_ros.bagio.schema import BagInfo
from fiper_ros.platform.dds import die_with
from fiper_ros.policy.policy import Policy

from .closed_loop import EpisodeResult, run_episode
from .tasks import TASKS

SOURCE = "fiper collect (sim, in-process)"


def collected_rollout_id(scenario: str, seed: int) -> int:
    """Message ``rollout_id``: a hash of the scenario name in the high 32 bits (below 2^63), the seed in the low
    32 bits: unique over a collected data set and the same in every run."""
    return ((zlib.crc32(scenario.encode()) & 0x7FFF_FFFF) << 32) | seed


#: The policy of a ``--jobs`` worker process (loaded once by :func:`_start_worker`).
_worker_policy: Policy | None = None


def _start_worker(parent: int, model_dir: str, threads: int) -> None:
    global _worker_policy  # noqa: PLW0603 - one policy per worker process
    # a collect that is killed takes its workers with it (they would run their episodes for nobody)
    die_with(parent)
    torch.set_num_threads(threads)
    _worker_policy = Policy.load(model_dir)


def _run_in_worker(scenario: str, seed: int, batch: int, max_policy_steps: int | None) -> EpisodeResult:
    assert _worker_policy is not None
    return run_episode(_worker_policy, scenario, seed, batch=batch, max_policy_steps=max_policy_steps)


class InProcessRunner:
    """Episodes run without ROS (:func:`run_episode`: no DDS), in this process or in ``jobs`` worker
    processes; the bag is written from the recorded rollout on the sim's control clock, with ids from
    :func:`collected_rollout_id`.

    Args:
        policy: The loaded policy.
        setup: The collect's setup (batch, policy-step cap).
        jobs: Worker processes (1: episodes run in this process).
        model_dir: The policy's folder, which the workers load.
        threads: Torch threads of each worker.
    """

    source = SOURCE

    def __init__(self, policy: Policy, setup: CollectSetup, jobs: int = 1, model_dir: Path | None = None,
                 threads: int = 1) -> None:
        self.policy = policy
        self.setup = setup
        task = TASKS[setup.task]
        cap = setup.max_policy_steps
        self.env_dt_ns = round(1e9 / task.control_hz)
        self.max_steps = task.max_policy_steps if cap is None else min(task.max_policy_steps, cap)
        self.jobs = jobs
        #: Episodes a worker ran or started that were not needed after all.
        self.discarded = 0
        self._pool: ProcessPoolExecutor | None = None
        if jobs > 1:
            if model_dir is None:
                raise ValueError("worker processes need the model folder")
            self._pool = ProcessPoolExecutor(jobs, multiprocessing.get_context("spawn"), _start_worker,
                                             (os.getpid(), str(model_dir), threads))
        self._started: dict[tuple[str, int], Future[EpisodeResult]] = {}

    def prepare(self) -> None:
        """Nothing to start."""

    def ahead(self, scenario: str, seeds: Iterable[int]) -> None:
        """Keep the workers busy with the first ``jobs`` of ``seeds``; drop started episodes not among them."""
        if self._pool is None:
            return
        wanted = [(scenario, seed) for seed in itertools.islice(seeds, self.jobs)]
        for key in [k for k in self._started if k not in wanted]:
            self._started.pop(key).cancel()
            self.discarded += 1
        for scenario_seed in wanted:
            self._start(*scenario_seed)

    def _start(self, scenario: str, seed: int) -> None:
        assert self._pool is not None
        if (scenario, seed) not in self._started:
            self._started[(scenario, seed)] = self._pool.submit(_run_in_worker, scenario, seed, self.setup.batch,
                                                                self.setup.max_policy_steps)

    def close(self) -> None:
        """Stop the worker processes (episodes started for nothing are dropped)."""
        if self._pool is not None:
            self.discarded += len(self._started)
            self._started.clear()
            self._pool.shutdown(cancel_futures=True)
            self._pool = None

    def result(self, scenario: str, seed: int) -> EpisodeResult:
        """The episode, run in this process or taken from the worker that ran it."""
        if self._pool is None:
            return run_episode(self.policy, scenario, seed, batch=self.setup.batch,
                               max_policy_steps=self.setup.max_policy_steps)
        self._start(scenario, seed)
        return self._started.pop((scenario, seed)).result()

    def run(self, scenario: str, seed: int, path: Path, fields: dict[str, Any]) -> RanEpisode:
        """Run the episode (or take it from the worker that ran it); its bag is written by ``write``."""
        result = self.result(scenario, seed)
        assert result.rollout is not None  # run_episode records by default
        rollout = replace(result.rollout, metadata={**result.rollout.metadata, "max_steps": self.max_steps})
        rollout_id = collected_rollout_id(scenario, seed)

        def write() -> None:
            write_rollouts(path, [rollout], [rollout_id], BagInfo(**fields), env_dt_ns=self.env_dt_ns)

        return RanEpisode(result.success, result.policy_steps, result.control_steps, rollout_id, write)
