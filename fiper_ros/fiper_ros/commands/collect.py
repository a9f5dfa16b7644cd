"""``fiper collect``: closed-loop rollouts of a trained policy in the simulation, one MCAP bag each.

Runs the policy on seeded episodes of each scenario and writes every rollout as its own bag,
``DIR/<scenario>/<task>_<scenario>_<seed>/``. In-process (default, :class:`sim_bridge.collect_runner.InProcessRunner`:
:func:`sim_bridge.closed_loop.run_episode`, no ROS, no DDS) a bag holds the messages a policy node
publishes (:func:`fiper_ros.bagio.rollout_bags.write_rollouts`) on the task's control clock; with ``--ros``
(:class:`fiper_ros.client.live_collect.RosRunner`) the episodes run through the live node suite and the bag
holds what was recorded from DDS. ``--episodes N`` runs the seeds ``S .. S+N-1``; ``--successes M`` runs
seeds from ``S`` on until ``M`` of them succeeded (at most ``--max-episodes``). A bag appears complete or
not at all, and a rollout is a function of its seed, so a rerun skips the finished bags and runs the rest:
a resumed folder holds the same rollouts as an uninterrupted run. ``DIR/collect.json`` indexes the
rollouts (:mod:`fiper_ros.bagio.collect_index`). In-process, ``--jobs N`` runs the next ``N`` episodes in
``N`` worker processes while this process writes the index and the bags in seed order, so the folder is
the one a single process writes; with ``--successes`` a worker may run an episode past the M-th success,
which is thrown away. ``--ray [ADDRESS]`` runs the episodes as Ray tasks (:class:`sim_bridge.ray_runner.RayRunner`)
on a local instance or an existing cluster (:mod:`fiper_ros.cluster`, docs/scale.md) and writes the same folder.
"""
from __future__ import annotations

import argparse
import fcntl
import math
import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import torch
import yaml
from sim_bridge.collect_runner import InProcessRunner
from sim_bridge.ray_runner import RayRunner
from sim_bridge.scenarios import TASK_NAMES, get_scenario

from fiper_ros.bagio.atomic import remove
from fiper_ros.bagio.collect_index import (INDEX_FILE, IN_PROCESS, ROS, CollectIndex, CollectSetup, IndexEntry,
                                           RanEpisode)
from fiper_ros.bagio.errors import BagError
from fiper_ros.bagio.reader import METADATA, find_bags
from fiper_ros.cluster import LOCAL, connected
from fiper_ros.commands.errors import UsageError
from fiper_ros.data_paths import SEARCH_RULE, data_path_argument
from fiper_ros.evaluation.offline import calibration_for, policy_layout
from fiper_ros.policy.dataset import files_hash
from fiper_ros.policy.errors import PolicyError
from fiper_ros.policy.policy import CONFIG_FILE, WEIGHTS_FILE, Policy

LOCK_FILE = ".collect.lock"
#: ``--max-episodes`` default of ``--successes M``: this many episodes per wanted success.
DEFAULT_EPISODES_PER_SUCCESS = 4
SPLITS = ("test", "calibration")


def bag_name(task: str, scenario: str, seed: int) -> str:
    """Directory name of a rollout's bag (the seed zero-padded, so names sort by seed)."""
    return f"{task}_{scenario}_{seed:06d}"


@dataclass(frozen=True)
class Target:
    """How far to run each scenario: ``max_episodes`` episodes, or until ``successes`` succeeded (at most
    ``max_episodes``)."""

    max_episodes: int
    successes: int | None = None

    def reached(self, episodes: int, successes: int) -> bool:
        """Whether a scenario with these counts is finished (the goal met or the cap hit)."""
        return episodes >= self.max_episodes or (self.successes is not None and successes >= self.successes)

    def remaining(self, known: dict[tuple[str, int], IndexEntry], scenario: str, start: int, rate: float) -> int:
        """Estimated episodes still to run for ``scenario`` (``rate``: the success rate seen so far)."""
        if self.successes is None:
            return sum((scenario, seed) not in known for seed in range(start, start + self.max_episodes))
        episodes = successes = 0
        while not self.reached(episodes, successes) and (scenario, start + episodes) in known:
            successes += known[(scenario, start + episodes)].success
            episodes += 1
        if self.reached(episodes, successes):
            return 0
        left = self.max_episodes - episodes
        return left if rate <= 0 else min(left, math.ceil((self.successes - successes) / rate))


@dataclass(frozen=True)
class Model:
    """A policy model folder and what identifies it."""

    policy: Policy
    path: str
    hash: str
    data_hash: str


def default_model(task: str) -> Path:
    """``models/<task>`` of the checkout (``$FIPER_ROOT``), or of the working directory."""
    return Path(os.environ.get("FIPER_ROOT", ".")) / "models" / task


def shown_path(path: Path) -> str:
    """``path`` relative to the checkout when inside it (the same in every clone), else absolute."""
    path = path.resolve()
    root = Path(os.environ.get("FIPER_ROOT", ".")).resolve()
    return str(path.relative_to(root)) if path.is_relative_to(root) else str(path)


def load_model(directory: Path, task: str) -> Model:
    """Load a model folder (``policy.pt`` + ``policy.yaml``) and check that it is a ``task`` policy."""
    files = [directory / WEIGHTS_FILE, directory / CONFIG_FILE]
    policy = Policy.load(directory)
    info = yaml.safe_load(files[1].read_text()).get("info") or {}
    if policy.config.task != task:
        raise PolicyError(f"{directory}: a {policy.config.task} policy, not {task}")
    return Model(policy, shown_path(directory), files_hash(files), str(info.get("data_hash", "")))


@contextmanager
def locked(directory: Path) -> Iterator[None]:
    """Hold ``directory``'s lock file: one ``fiper collect`` at a time writes into a folder. The file is
    removed (still locked) when done, so a finished folder holds only the index and the bags."""
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / LOCK_FILE
    with path.open("w") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError as error:
            raise BagError(f"{directory}: another fiper collect is writing into this folder") from error
        try:
            yield
        finally:
            path.unlink(missing_ok=True)


def open_index(out: Path, setup: CollectSetup, model: Model) -> CollectIndex:
    """The folder's index, new or resumed; a folder made with another setup is refused."""
    index = CollectIndex.load(out)
    if index is None:
        try:
            find_bags([out])
        except BagError:
            return CollectIndex(setup, model.path, model.data_hash)
        raise BagError(f"{out}: holds bags but no {INDEX_FILE}: not a fiper collect folder (choose another --out)")
    differences = index.setup.differences(setup)
    if differences:
        raise BagError(f"{out / INDEX_FILE}: the folder was collected with other settings "
                       f"({'; '.join(differences)}, folder != this run): choose another --out")
    return index


def duration(seconds: float) -> str:
    """``42 s``, ``3 min 5 s`` or ``2 h 7 min``."""
    seconds = round(seconds)
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60} s"
    return f"{seconds // 3600} h {seconds % 3600 // 60} min"


class Runner(Protocol):
    """Runs the episodes of a ``fiper collect``: in this process, or through the live ROS suite."""

    #: ``custom_data`` source of the bags.
    source: str

    def prepare(self) -> None:
        """Get ready to run an episode (not counted in the episode's time)."""

    def run(self, scenario: str, seed: int, path: Path, fields: dict[str, Any]) -> RanEpisode:
        """Run ``(scenario, seed)`` for a bag at ``path`` whose ``custom_data`` holds ``fields``."""

    def ahead(self, scenario: str, seeds: Iterable[int]) -> None:
        """The episodes of ``scenario`` that come next, in order (the first one runs next): a runner may
        start some of them early."""


class Collector:
    """Runs (through a :class:`Runner`) and records the episodes of one ``fiper collect`` into one folder."""

    def __init__(self, runner: Runner, out: Path, index: CollectIndex, *, seed: int, target: Target,
                 status: Callable[[], str] | None = None) -> None:
        self.runner = runner
        #: The runner's part of the progress line (the Ray cluster's task counts), if it has one.
        self.status = status
        self.out = out
        self.index = index
        self.seed = seed
        self.target = target
        self.seconds: list[float] = []

    def bag_fields(self, seed: int) -> dict[str, Any]:
        """``custom_data`` of a rollout's bag that collect knows (the shapes come from the rollout)."""
        setup = self.index.setup
        return {"task": setup.task, "synthetic": False, "source": self.runner.source, "split": setup.split,
                "policy": self.index.policy, "policy_hash": setup.policy_hash,
                "policy_data_hash": self.index.policy_data_hash, "seed": str(seed)}

    def _relative(self, scenario: str, seed: int) -> str:
        return f"{scenario}/{bag_name(self.index.setup.task, scenario, seed)}"

    def _finished(self, scenario: str, seed: int) -> bool:
        return (self.out / self._relative(scenario, seed) / METADATA).is_file()

    def episode(self, scenario: str, seed: int) -> tuple[IndexEntry, bool]:
        """The rollout of ``(scenario, seed)``: from its finished bag, or run and written now. True if run now."""
        relative = self._relative(scenario, seed)
        path = self.out / relative
        if self._finished(scenario, seed):
            entry = self.index.rollouts.get((scenario, seed))
            if entry is None:
                raise BagError(f"{path}: a bag that {self.out / INDEX_FILE} does not list (not written by "
                               f"fiper collect into this folder): remove it or choose another --out")
            return entry, False
        for stale in path.parent.glob(f".{path.name}.partial-*"):  # left by a killed run (we hold the lock)
            remove(stale)
        self.runner.prepare()
        started = time.monotonic()
        ran = self.runner.run(scenario, seed, path, self.bag_fields(seed))
        entry = IndexEntry(scenario, seed, ran.success, ran.policy_steps, ran.control_steps, relative,
                           ran.rollout_id, round(time.monotonic() - started, 3))
        self.index.rollouts[(scenario, seed)] = entry
        self.index.save(self.out)  # before the bag: an index entry without its bag is dropped on reading
        ran.write()
        self.seconds.append(time.monotonic() - started)
        return entry, True

    def eta(self, scenarios: Sequence[str]) -> str:
        """Time left: episodes still to run (estimated for ``--successes``) x mean seconds per episode."""
        known = self.index.rollouts
        if not self.seconds:
            return "?"
        rate = sum(e.success for e in known.values()) / len(known) if known else 0.0
        left = sum(self.target.remaining(known, scenario, self.seed, rate) for scenario in scenarios)
        return duration(left * sum(self.seconds) / len(self.seconds))

    def scenario(self, scenario: str, scenarios: Sequence[str]) -> tuple[int, int]:
        """Run ``scenario`` to its target, one progress line per episode; ``(episodes, successes)``."""
        episodes = successes = 0
        goal = f"/{self.target.successes} wanted" if self.target.successes is not None else ""
        while not self.target.reached(episodes, successes):
            seed = self.seed + episodes
            self.runner.ahead(scenario, (s for s in range(seed, self.seed + self.target.max_episodes)
                                         if not self._finished(scenario, s)))
            entry, ran = self.episode(scenario, seed)
            episodes += 1
            successes += entry.success
            timing = f"{entry.seconds:.1f} s, ETA {self.eta(scenarios)}" if ran else "bag exists, skipped"
            cluster = f" | ray: {self.status()}" if self.status is not None else ""
            print(f"[{scenario} {episodes}/{self.target.max_episodes}] seed {seed}: "
                  f"{'success' if entry.success else 'failure'}, {entry.policy_steps} policy steps | "
                  f"successes {successes}{goal} | {timing}{cluster}", file=sys.stderr, flush=True)
        return episodes, successes


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``fiper collect``."""
    parser.add_argument("--task", choices=TASK_NAMES, required=True, help="sim task")
    parser.add_argument("--scenarios", nargs="+", default=["id"], metavar="SCENARIO",
                        help="scenarios to run (docs/sim.md; default: id)")
    count = parser.add_mutually_exclusive_group(required=True)
    count.add_argument("--episodes", type=int, help="episodes per scenario: seeds S .. S+N-1")
    count.add_argument("--successes", type=int,
                       help="run seeds S, S+1, ... until this many succeeded per scenario (calibration sets)")
    parser.add_argument("--max-episodes", type=int, default=None,
                        help=f"cap of --successes per scenario (default {DEFAULT_EPISODES_PER_SUCCESS} x M)")
    parser.add_argument("--seed", type=int, default=1000, help="first episode seed (the demos use 0 ..)")
    parser.add_argument("--out", type=Path, required=True,
                        help="output folder: DIR/<scenario>/<task>_<scenario>_<seed>/ bags and DIR/collect.json")
    parser.add_argument("--model", type=data_path_argument, default=None,
                        help=f"policy model folder (default models/<task>; {SEARCH_RULE})")
    parser.add_argument("--split", choices=SPLITS, default="test", help="custom_data split of the bags")
    parser.add_argument("--batch", type=int, default=None,
                        help="B, chunks sampled per policy step (default: the model's; smaller for tests/smoke runs)")
    parser.add_argument("--max-policy-steps", type=int, default=None,
                        help="stop episodes after this many policy steps, as a failure (tests/smoke runs only)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (1 is fastest on a shared machine)")
    parser.add_argument("--jobs", type=int, default=1,
                        help="in-process: run this many episodes at once in worker processes (one per core)")
    parser.add_argument("--ray", nargs="?", const=LOCAL, default=None, metavar="ADDRESS",
                        help="in-process: run the episodes as Ray tasks; without ADDRESS on a local Ray instance "
                             "bound to 127.0.0.1 (--jobs N: N CPUs, default all cores), with 'auto', HOST:PORT or "
                             "ray://HOST:10001 on that cluster (docs/scale.md); the folder is the one --jobs 1 writes")
    parser.add_argument("--ros", action="store_true",
                        help="run the episodes through the live node suite (sim bridge + policy node over DDS, "
                             "each its own process) and record each from DDS, instead of in-process")
    parser.add_argument("--calibration", type=data_path_argument, default=None,
                        help="with --ros: also run the scoring nodes of the detectors this calibration folder "
                             "declares (RND-OE and ACE, or RND-OE alone) and fusion on it (the bags then hold "
                             "their scores and the alarms)")


def _target(args: argparse.Namespace) -> Target:
    """The per-scenario target of ``--episodes`` or ``--successes`` / ``--max-episodes``."""
    if args.successes is None:
        if args.max_episodes is not None:
            raise UsageError("--max-episodes caps --successes; with --episodes N give N only")
        if args.episodes < 1:
            raise UsageError(f"--episodes must be at least 1, got {args.episodes}")
        return Target(args.episodes)
    if args.successes < 1:
        raise UsageError(f"--successes must be at least 1, got {args.successes}")
    cap = args.max_episodes if args.max_episodes is not None else DEFAULT_EPISODES_PER_SUCCESS * args.successes
    if cap < args.successes:
        raise UsageError(f"--max-episodes {cap} is below --successes {args.successes}")
    return Target(cap, args.successes)


def _scenarios(task: str, names: Sequence[str]) -> list[str]:
    """The scenario names, checked against the sim's registry (a :class:`ScenarioError` naming the known ones),
    each once."""
    for name in names:
        get_scenario(task, name)
    return list(dict.fromkeys(names))


def _check_sizes(args: argparse.Namespace, episodes: int) -> None:
    """Refuse seeds outside ``uint32`` (the low half of a rollout id) and sizes below 1."""
    last = args.seed + episodes - 1
    if args.seed < 0 or last >= 2**32:
        raise UsageError(f"seeds must lie in 0 .. 2^32 - 1, got {args.seed} .. {last}")
    for option in ("batch", "max_policy_steps", "threads", "jobs"):
        value = getattr(args, option)
        if value is not None and value < 1:
            raise UsageError(f"--{option.replace('_', '-')} must be at least 1, got {value}")


def _runner(args: argparse.Namespace, model_dir: Path, model: Model, setup: CollectSetup, detectors: tuple[str, ...],
            stack: ExitStack) -> Runner:
    """The runner of ``--ros`` (entered into ``stack``: it stops its suite; ``detectors``: those of the calibration,
    whose scoring nodes run) or the in-process one."""
    if setup.runner == IN_PROCESS and args.ray is not None:
        if args.jobs != 1 and args.ray != LOCAL:
            raise UsageError(f"--jobs sets the CPUs of a local Ray instance: the cluster at {args.ray} has its own")
        stack.enter_context(connected(args.ray, args.jobs if args.jobs != 1 else None))
        ray_runner = RayRunner(model.policy, setup, model_dir, args.threads)
        stack.callback(ray_runner.close)
        return ray_runner
    if setup.runner == IN_PROCESS:
        runner = InProcessRunner(model.policy, setup, args.jobs, model_dir, args.threads)
        stack.callback(runner.close)
        return runner
    if args.ray is not None:
        raise UsageError("--ray runs episodes as Ray tasks: --ros runs them through the one node suite")
    if args.jobs != 1:
        raise UsageError("--jobs runs episodes in worker processes: --ros runs them through the one node suite")
    from fiper_ros.client.live_collect import LiveSettings, RosRunner  # noqa: PLC0415 - rclpy only with --ros

    settings = LiveSettings(args.task, model_dir.resolve(), setup.batch, args.threads, setup.max_policy_steps,
                            args.calibration.resolve() if args.calibration else None, detectors)
    return stack.enter_context(RosRunner(settings, args.out, model.policy.config.exec_steps))


def _check_calibration(args: argparse.Namespace) -> None:
    """``--calibration`` only with ``--ros``."""
    if args.calibration is not None and not args.ros:
        raise UsageError("--calibration runs the scoring nodes: it needs --ros")


def run(args: argparse.Namespace) -> int:
    """``fiper collect``."""
    target = _target(args)
    scenarios = _scenarios(args.task, args.scenarios)
    _check_sizes(args, target.max_episodes)
    _check_calibration(args)
    torch.set_num_threads(args.threads)
    model_dir = args.model or default_model(args.task)
    model = load_model(model_dir, args.task)
    detectors: tuple[str, ...] = ()
    if args.calibration is not None:  # refused here with one line, not by scoring nodes that never configure
        detectors = calibration_for(args.calibration, [policy_layout(model.policy.config, model_dir)]).detectors
    setup = CollectSetup(args.task, model.hash, args.split, args.batch or model.policy.config.sample_batch,
                         args.max_policy_steps, ROS if args.ros else IN_PROCESS)
    with locked(args.out), ExitStack() as stack:
        index = open_index(args.out, setup, model)
        for name in scenarios:
            index.use_scenario(name, get_scenario(args.task, name).knobs)
        settings = {"scenarios": scenarios, "seed": args.seed, "episodes": args.episodes,
                    "successes": args.successes, "max_episodes": target.max_episodes}
        if args.calibration is not None:
            settings |= {"calibration": shown_path(args.calibration), "detectors": list(detectors)}
        index.add_run(settings)
        index.save(args.out)
        runner = _runner(args, model_dir, model, setup, detectors, stack)
        collector = Collector(runner, args.out, index, seed=args.seed, target=target,
                              status=runner.status if isinstance(runner, RayRunner) else None)
        print(f"collecting {args.task} {', '.join(scenarios)} with {model.path} (B = {setup.batch}, "
              f"{setup.runner}) into {args.out}", file=sys.stderr, flush=True)
        started = time.monotonic()
        counts = {scenario: collector.scenario(scenario, scenarios) for scenario in scenarios}
    for scenario, (episodes, successes) in counts.items():
        print(f"{scenario}: {episodes} rollouts (seeds {args.seed}-{args.seed + episodes - 1}), {successes} "
              f"successes ({successes / episodes:.2f}) in {args.out / scenario}")
    ran = collector.seconds
    per_episode = f", {sum(ran) / len(ran):.1f} s per episode" if ran else ""
    print(f"{len(ran)} new rollouts in {duration(time.monotonic() - started)}{per_episode}; index "
          f"{args.out / INDEX_FILE}")
    short = [(s, n, k) for s, (n, k) in counts.items() if target.successes is not None and k < target.successes]
    for scenario, episodes, successes in short:
        print(f"fiper collect: {scenario}: only {successes} of {target.successes} successes after {episodes} "
              f"episodes: --max-episodes {target.max_episodes} reached", file=sys.stderr)
    return 1 if short else 0
