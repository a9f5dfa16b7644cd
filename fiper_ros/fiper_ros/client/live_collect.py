"""``fiper collect --ros``: the episodes through the live node suite, each recorded from DDS into its own bag.

The suite is ``launch/demo.launch.yaml`` cut down (one source of the node parameters), read with the launch
arguments ``model:=`` and the calibration's (``calibration_dir:=``, ``observation_only:=true`` for an
observation-only one): the sim bridge (fast, sim time, images on, ``max_policy_steps`` = the collect's cap) and
the policy node with the collect's model, batch and threads; with a calibration also the scoring node of each
detector it declares (RND-OE and ACE, or RND-OE alone) and fusion on it (the bags then hold those scores and the
alarms); never the supervisor, which would halt rollouts. Every node is ``required``, so a node that dies stops
the launcher and the collect with it. The suite starts on the first episode that
is not collected yet, in a ROS domain of its own; its launch file and output go to ``DIR/.collect-ros/``
(removed at the end unless the suite failed).

Per episode: a bag is opened, the :class:`~fiper_ros.client.driver.SimSuiteDriver` resets the bridge into
``(scenario, seed)`` and follows the rollout to its END, then waits until the rollout's messages landed
in the bag; the collector indexes the episode and finishes the bag. One
:class:`~fiper_ros.client.record.Recorder` serves all episodes, so its subscriptions never miss the start of
a rollout. The bags hold the bag schema's topics as received (log time = receive time); the rollout
id is the bridge's.
"""
from __future__ import annotations

import math
import sys
import time
from collections.abc import Iterable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from types import TracebackType
from typing import Any

from sim_bridge.robot import URDF_PATH
from sim_bridge.tasks import TASKS

from fiper_ros.bagio.atomic import remove
from fiper_ros.bagio.collect_index import RanEpisode
from fiper_ros.client.driver import SETTLE_S, SimSuiteDriver, SuiteFailed
from fiper_ros.client.errors import ClientError
from fiper_ros.client.record import Recorder
from fiper_ros.client.ros_session import RosSession
from fiper_ros.client.suite_process import (SuiteProcess, declared_of, detector_topics, installed_launch,
                                            scoring_modules, suite_arguments, suite_topics)
from fiper_ros.client.trace import RolloutTrace
from fiper_ros.core.detectors import judged_by
from fiper_ros.interface.topics import ACTIONS_TOPIC, EMBEDDING_TOPIC, EVENTS_TOPIC, INPUT_TOPICS
from fiper_ros.launcher.config import LaunchConfig, LaunchError, dump_launch, load_launch
from fiper_ros.launcher.overrides import Overrides, apply
from fiper_ros.platform.dds import allocate_domain

SOURCE = "fiper collect (sim, ROS)"
#: The node of ``fiper collect --ros`` (in the root namespace; its SROS2 enclave, docs/security.md).
NODE_NAME = "fiper_collect"
#: Nodes of ``demo.launch.yaml`` the collect always runs (with a calibration also those of :func:`scoring_modules`).
POLICY_NODES = ("bridge_node", "policy_node")
#: Hidden folder of the suite's launch file and output, inside the collect folder.
WORK_DIR = ".collect-ros"
#: Seconds for every node to become active.
READY_TIMEOUT_S = 90.0
#: Seconds one rollout may take in all (a stalled one fails after ``driver.STALL_TIMEOUT_S``).
ROLLOUT_TIMEOUT_S = 600.0
#: Seconds spun after that, for the fusion node's last alarm.
CATCH_UP_S = 0.2


@dataclass(frozen=True)
class LiveSettings:
    """What the suite of a ``--ros`` collect runs.

    Attributes:
        task: Sim task.
        model: Policy model folder (absolute).
        batch: ``B``, chunks sampled per policy step.
        threads: The policy node's torch threads.
        max_policy_steps: The bridge's policy-step cap (None: the task's time limit).
        calibration: Calibration folder of the scoring nodes and fusion (absolute); None: no scoring nodes.
        detectors: The detectors ``calibration`` declares (empty without one): their scoring nodes run.
    """

    task: str
    model: Path
    batch: int
    threads: int
    max_policy_steps: int | None
    calibration: Path | None
    detectors: tuple[str, ...]


def collect_config(source: Path, settings: LiveSettings) -> LaunchConfig:
    """The nodes of ``source`` (``demo.launch.yaml``) a collect runs, with its settings, all required: the policy
    nodes, and with a calibration the scoring nodes of its detectors and the fusion node."""
    scored = settings.calibration is not None
    arguments = {"model": str(settings.model),
                 **(suite_arguments(settings.calibration, settings.detectors) if scored else {})}
    try:
        config = load_launch(source, arguments)
    except LaunchError as error:
        raise LaunchError(f"launch file {source}: {error}") from error
    modules = scoring_modules(settings.detectors) if scored else ()
    keep = POLICY_NODES + tuple(spec.name for spec in config.nodes if spec.module in modules)
    names, present = {spec.name for spec in config.nodes}, {spec.module for spec in config.nodes}
    missing = (set(POLICY_NODES) - names) | (set(modules) - present)
    if missing:
        raise LaunchError(f"launch file {source}: no {', '.join(sorted(missing))} node")
    bridge = {"task": settings.task, "max_policy_steps": settings.max_policy_steps or 0}
    policy = {"batch": settings.batch, "torch_threads": settings.threads}
    ace = {"urdf_path": str(URDF_PATH)}  # the sim's arm: ACE's FK for joint-space (Stacking) actions
    parameters = {"bridge_node": bridge, "policy_node": policy, "ace_node": ace}
    return apply(config, Overrides(by_name=parameters, keep=keep, required=True))


def operator(session: RosSession, suite: SuiteProcess, settings: LiveSettings) -> tuple[Recorder, SimSuiteDriver]:
    """The collect's side of ``session``: a recorder of the bag schema's inputs (scored: the topics of its
    detectors' suite) and the driver."""
    topics = suite_topics(settings.detectors) if settings.calibration is not None else INPUT_TOPICS
    recorder = Recorder(session, topics, source=SOURCE)
    return recorder, SimSuiteDriver(session, suite, settings.task, settings.detectors, recorder=recorder)


class RosRunner:
    """Runs ``fiper collect`` episodes through the live suite (a collect runner; use as a context manager).

    Args:
        settings: What the suite runs.
        out: The collect folder (for the suite's work folder).
        exec_steps: ``h`` of the model: a rollout of ``c`` control steps has ``ceil(c / h)`` policy steps.
    """

    source = SOURCE

    def __init__(self, settings: LiveSettings, out: Path, exec_steps: int) -> None:
        self.settings = settings
        self.work = out / WORK_DIR
        self.exec_steps = exec_steps
        self.period_ns = round(1e9 / TASKS[settings.task].control_hz)
        self.scored = settings.calibration is not None
        self.failed = False
        self._stack = ExitStack()
        self._driver: SimSuiteDriver | None = None
        self._recorder: Recorder | None = None

    def __enter__(self) -> RosRunner:
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self._stack.close()  # the open bag dropped, the session closed, the suite stopped
        if not self.failed:
            remove(self.work)

    def prepare(self) -> None:
        """Start the suite (once) and wait until every node is active and the recorder subscribed."""
        if self._driver is not None:
            return
        started = time.monotonic()
        remove(self.work)
        self.work.mkdir(parents=True)
        config = collect_config(installed_launch("demo.launch.yaml"), self.settings)
        launch = dump_launch(config, self.work / "launch.yaml")
        domain = self._stack.enter_context(allocate_domain())
        suite = SuiteProcess(launch, domain, echo=False, log=self.work / "suite.log")
        self._stack.callback(suite.stop)
        session = self._stack.enter_context(RosSession(NODE_NAME, domain))
        recorder, driver = operator(session, suite, self.settings)
        self._stack.callback(recorder.abort)
        names = ", ".join(spec.name for spec in config.nodes)
        combine = declared_of(self.settings.calibration).combine if self.scored else ""
        judged = f"; judged by {judged_by(self.settings.detectors, combine)}" if self.scored else ""
        print(f"starting {names} in ROS domain {domain} (loopback only){judged} ...", file=sys.stderr, flush=True)
        with self._reported():
            driver.wait_ready([spec.fqn for spec in config.nodes], READY_TIMEOUT_S)
        print(f"all nodes active after {time.monotonic() - started:.1f} s", file=sys.stderr, flush=True)
        self._driver, self._recorder = driver, recorder

    def ahead(self, scenario: str, seeds: Iterable[int]) -> None:
        """Nothing: the episodes run one at a time through the one suite."""

    def run(self, scenario: str, seed: int, path: Path, fields: dict[str, Any]) -> RanEpisode:
        """Record ``(scenario, seed)`` into a bag at ``path``, from the reset to the last message after its END."""
        driver, recorder = self._driver, self._recorder
        assert driver is not None and recorder is not None, "prepare() first"
        recorder.start(path)
        with self._reported():
            trace = driver.reset(scenario, seed)
            driver.follow(trace, ROLLOUT_TIMEOUT_S)
            control_steps = round((trace.ended_ns - trace.started_ns) / self.period_ns)
            steps = math.ceil(control_steps / self.exec_steps)  # one command of h actions per policy step
            complete = driver.settle(lambda: self._landed(trace, steps, recorder, scored=True), SETTLE_S)
            if not complete and not self._landed(trace, steps, recorder, scored=False):  # scores: best effort
                raise SuiteFailed(f"rollout {trace.rollout_id} ({scenario} seed {seed}): {steps} policy steps, "
                                  f"but the bag got only {recorder.counts[EMBEDDING_TOPIC]} embeddings, "
                                  f"{recorder.counts[ACTIONS_TOPIC]} action batches and "
                                  f"{recorder.counts[EVENTS_TOPIC]} events within {SETTLE_S:g} s of its END")
            driver.spin(CATCH_UP_S)

        def write() -> None:
            recorder.finish(replace(recorder.info, **fields))

        return RanEpisode(trace.outcome == "success", steps, control_steps, trace.rollout_id, write)

    @staticmethod
    def _landed(trace: RolloutTrace, steps: int, recorder: Recorder, scored: bool) -> bool:
        """Whether the open bag holds START, END, and an embedding and an action batch (and, if ``scored``,
        the scores of the trace's detectors) for each of the rollout's ``steps`` steps. A scoring node drops a
        step that comes after the END it saw, so the last scores may never come."""
        counts = recorder.counts
        scores = tuple(detector_topics(d)[2] for d in trace.detectors) if scored else ()
        stepwise = (EMBEDDING_TOPIC, ACTIONS_TOPIC, *scores)
        return trace.ended and counts[EVENTS_TOPIC] >= 2 and all(counts[topic] >= steps for topic in stepwise)

    @contextmanager
    def _reported(self) -> Iterator[None]:
        """Turn a :class:`SuiteFailed` into a one-line :class:`ClientError` that names the suite's output file."""
        try:
            yield
        except SuiteFailed as error:
            self.failed = True
            raise ClientError(f"{error}; the nodes' output: {self.work / 'suite.log'}") from error
