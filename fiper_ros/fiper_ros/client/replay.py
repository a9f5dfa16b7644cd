"""The player of ``fiper replay BAG...`` (:mod:`fiper_ros.commands.replay`): bags into the node suite, its alarms
per rollout back.

The policy-side topics of the bags (embeddings, action batches, step signals, rollout events, joint states) are
published in log-time order, bag after bag (a bag that starts before the previous one ended is shifted
later), with a ``/clock`` tick at each message's log time so nodes under ``use_sim_time`` see the
bag's time. Before the first message the player waits until the suite subscribes to every topic it reads
(the step signals are played without waiting for a reader: no node of the suite reads them).

Pacing: ``--rate K`` plays at K x real time, ``--fast`` as fast as possible. Either way the player is
flow-controlled while a fusion node publishes ``/fiper/alarm``: it sends a step's inputs only after
the alarm of the previous step arrived (or ``--step-timeout`` passed, which is reported), so no step
is dropped however fast the bag plays. A RolloutEvent START is waited on until every subscriber
acknowledged it, then ``--settle`` seconds more, so that the nodes have started the rollout before
its first step arrives.

By default the suite is started here (``fiper launch`` of ``--launch FILE``, default the installed
``fiper.launch.yaml``, with ``use_sim_time:=true``, ``calibration_dir:=`` ``--calibration DIR`` or the
``calibration/`` directory next to the bags, and ``observation_only:=true`` for an observation-only one) in a
private ROS domain; ``--no-launch`` plays into a suite already running in this shell's domain. With an
observation-only calibration no action batches or joint states are played (no node of that suite reads
them). ``--offline`` prints what the suite would say, computed without DDS by the core.
"""
from __future__ import annotations

import argparse
import collections
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock

from fiper_msgs.msg import FailureAlarm, RolloutEvent
from fiper_ros.bagio.errors import BagError
from fiper_ros.bagio.reader import BagReader
from fiper_ros.client.ros_session import RosSession
from fiper_ros.client.suite_process import SuiteProcess, detector_topics
from fiper_ros.core.detectors import DETECTORS
from fiper_ros.evaluation.results import RolloutResult, StepResult
from fiper_ros.evaluation.verdicts import rollout_line
from fiper_ros.interface import qos
from fiper_ros.interface.conversions import to_stamp
from fiper_ros.interface.messages import OUTCOME_NAMES, SUCCESS_OF, message_class
from fiper_ros.interface.topics import (ACTIONS_TOPIC, ALARM_TOPIC, CLOCK_TOPIC, EMBEDDING_TOPIC, EVENTS_TOPIC,
                                        INPUT_TOPICS, STEP_SIGNALS_TOPIC, TOPICS, topic_spec)

#: The node of ``fiper replay`` (in the root namespace; its SROS2 enclave, docs/security.md).
NODE_NAME = "fiper_replay"
#: Pause between "every endpoint is there" and the first message, for the nodes to match each other.
WARM_UP_S = 1.0
#: Policy-side topics played whether or not anything reads them: no node of the suite reads the step signals.
UNREAD_INPUTS = (STEP_SIGNALS_TOPIC,)


def readers_needed(topics: Sequence[str]) -> dict[str, int]:
    """Subscribers to wait for per played topic in a suite this process did not start: one, none for
    :data:`UNREAD_INPUTS`."""
    return {topic: 0 if topic in UNREAD_INPUTS else 1 for topic in topics}


def suite_subscribers(detectors: tuple[str, ...]) -> dict[str, int]:
    """Subscribers a launched suite of ``detectors`` has per topic: each scoring node its input (an input several
    detectors read has as many), the fusion node each score, every node the rollout events, none an input no
    declared detector reads (:data:`UNREAD_INPUTS`)."""
    needed = {**readers_needed(UNREAD_INPUTS), EVENTS_TOPIC: len(detectors) + 1}
    readers = collections.Counter(detector_topics(detector)[0] for detector in detectors)
    return needed | dict(readers) | {detector_topics(detector)[2]: 1 for detector in detectors}


def played_topics(detectors: tuple[str, ...]) -> tuple[str, ...]:
    """The policy-side topics replayed into a suite of ``detectors`` (none that only another detector reads)."""
    read = {t for d in detectors for t in (detector_topics(d)[0], *detector_topics(d)[1])}
    others = {t for d in DETECTORS if d not in detectors for t in (detector_topics(d)[0], *detector_topics(d)[1])}
    return tuple(t for t in INPUT_TOPICS if t not in others - read)


def find_calibration(bags: Sequence[Path]) -> Path | None:
    """A ``calibration/`` directory next to, or up to two levels above, the first bag that has one
    (``SET/calibration`` for ``SET/test_rollouts/BAG`` and for ``fiper collect``'s ``SET/test_rollouts/SCENARIO/BAG``)."""
    for bag in bags:
        for parent in list(bag.parents)[:3]:
            if (parent / "calibration" / "calibration.yaml").is_file():
                return parent / "calibration"
    return None


class Player:
    """Publishes bag messages with /clock, flow-controlled by the suite's alarms, and collects them."""

    def __init__(self, session: RosSession, args: argparse.Namespace) -> None:
        self.session = session
        self.node = session.node
        self.fast = args.fast
        self.rate = args.rate
        self.step_timeout = args.step_timeout
        self.settle_s = args.settle
        self.clock_period_ns = int(1e9 / args.clock_hz)
        self.publishers: dict[str, Any] = {}
        self.clock = self.node.create_publisher(Clock, CLOCK_TOPIC, QoSProfile(depth=1))
        self.alarms: dict[tuple[int, int], FailureAlarm] = {}
        self.node.create_subscription(FailureAlarm, ALARM_TOPIC, self._on_alarm, qos.ALARM_EVERY)
        self.results: dict[int, RolloutResult] = {}
        self.missing: list[tuple[int, int]] = []
        self.steps = 0
        self._sent: dict[tuple[int, int], set[str]] = {}
        self._pending: tuple[int, int] | None = None
        self._sim_ns = 0
        self.flow_controlled = False

    # set-up -------------------------------------------------------------------------------------------
    def _on_alarm(self, msg: FailureAlarm) -> None:
        if not msg.heartbeat:
            self.alarms.setdefault((int(msg.rollout_id), int(msg.step)), msg)

    def add_topic(self, topic: str, msgtype: str, transient: bool) -> None:
        """A publisher for ``topic``: the schema's QoS, else reliable (transient-local if recorded so)."""
        if topic in self.publishers:
            return
        if topic in TOPICS:
            profile = qos.profile(topic_spec(topic).qos)
        else:
            profile = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.TRANSIENT_LOCAL if transient else DurabilityPolicy.VOLATILE)
        try:
            kind = message_class(msgtype)
        except (ImportError, AttributeError, ValueError):
            print(f"fiper replay: skipping {topic}: message type {msgtype} is not importable here", file=sys.stderr)
            return
        self.publishers[topic] = self.node.create_publisher(kind, topic, profile)

    def wait_for_subscribers(self, needed: dict[str, int], timeout_s: float, suite: SuiteProcess | None) -> None:
        """Wait until every topic has its subscribers (and the suite's alarm publisher, if launched)."""
        node = self.node

        def ready() -> bool:
            counts = all(node.count_subscribers(t) >= n for t, n in needed.items())
            matched = all(p.get_subscription_count() >= needed.get(t, 1) for t, p in self.publishers.items())
            return counts and matched and (suite is None or node.count_publishers(ALARM_TOPIC) >= 1)

        if not self.session.spin_until(lambda: ready() or (suite is not None and not suite.alive()), timeout_s) \
                or not ready():
            have = {t: node.count_subscribers(t) for t in needed}
            detail = f"; suite output:\n{suite.output()}" if suite is not None else ""
            raise BagError(f"subscribers not there after {timeout_s:g} s (have {have}, need {needed}) "
                           f"in ROS domain {self.session.domain}{detail}")
        self.session.spin_until(lambda: False, WARM_UP_S)  # the nodes match each other's endpoints too
        own = 1 if ALARM_TOPIC in self.publishers else 0  # --all-topics replays recorded alarms itself
        self.flow_controlled = node.count_publishers(ALARM_TOPIC) > own


    # playing ------------------------------------------------------------------------------------------
    def _tick(self, sim_ns: int) -> None:
        if sim_ns > self._sim_ns:
            self._sim_ns = sim_ns
            self.clock.publish(Clock(clock=to_stamp(sim_ns)))

    def _pace(self, sim_ns: int) -> None:
        """Real-time pacing (not with --fast): sleep until the message is due, ticking /clock."""
        if self.fast or self._sim_ns == 0:
            return
        start_sim, start_wall = self._sim_ns, time.monotonic()
        due = start_wall + (sim_ns - start_sim) / 1e9 / self.rate
        while not self.session.stop.is_set():
            now = time.monotonic()
            if now >= due:
                return
            self.session.spin_once(min(self.clock_period_ns / 1e9 / self.rate, due - now))
            self._tick(min(sim_ns, start_sim + int((time.monotonic() - start_wall) * self.rate * 1e9)))

    def _wait_pending(self) -> None:
        key, self._pending = self._pending, None
        if key is None:
            return
        if not self.session.spin_until(lambda: key in self.alarms, self.step_timeout):
            if not self.session.stop.is_set():
                self.missing.append(key)
                print(f"fiper replay: no alarm for rollout {key[0]} step {key[1]} within {self.step_timeout:g} s",
                      file=sys.stderr)

    def play(self, bag: BagReader, shift_ns: int) -> int:
        """Publish the bag's played topics; returns the (shifted) log time of its last message."""
        last = 0
        step_topics = {EMBEDDING_TOPIC, ACTIONS_TOPIC} & set(self.publishers)  # a step is sent once all of them are
        keyed = step_topics | ({STEP_SIGNALS_TOPIC} & set(self.publishers))  # the messages of a step (rollout, step)
        for message in bag.messages([t for t in bag.topics if t in self.publishers]):
            if self.session.stop.is_set():
                break
            sim_ns = message.log_time_ns + shift_ns
            key, event = None, None
            if message.topic in keyed:
                msg = bag.decode(message)
                key = (int(msg.rollout_id), int(msg.step))
            elif message.topic == EVENTS_TOPIC:
                event = bag.decode(message)
            if self._pending is not None and key != self._pending:
                self._wait_pending()
            if event is not None and event.event == RolloutEvent.EVENT_END:
                self._finish(int(event.rollout_id), int(event.outcome))
            self._pace(sim_ns)
            self._tick(sim_ns)
            self.publishers[message.topic].publish(message.raw)
            last = sim_ns
            if event is not None and event.event == RolloutEvent.EVENT_START:
                self.results[int(event.rollout_id)] = RolloutResult(int(event.rollout_id), event.task, event.scenario)
                # Every node has the START (reliable: acknowledged) and a moment to act on it before step 0.
                self.publishers[EVENTS_TOPIC].wait_for_all_acked(Duration(seconds=self.step_timeout))
                self.session.spin_until(lambda: False, self.settle_s)
            if key is not None and message.topic in step_topics:
                sent = self._sent.setdefault(key, set())
                sent.add(message.topic)
                if len(sent) == len(step_topics):
                    self.steps += 1
                    if self.flow_controlled:
                        self._pending = key
        self._wait_pending()
        return last

    def _finish(self, rollout_id: int, outcome: int) -> None:
        """Print the rollout's line once its last step is answered."""
        result = self.results.setdefault(rollout_id, RolloutResult(rollout_id))
        result.outcome = OUTCOME_NAMES[SUCCESS_OF.get(outcome)]
        result.steps = self.steps_of(rollout_id)
        print(rollout_line(result), flush=True)

    def steps_of(self, rollout_id: int) -> dict[int, StepResult]:
        """The per-step states received for ``rollout_id``."""
        return {step: StepResult.of_alarm(m) for (rid, step), m in sorted(self.alarms.items()) if rid == rollout_id}

    def collect(self) -> list[RolloutResult]:
        """Every rollout's result, with the alarms that arrived until now."""
        self.session.spin_until(lambda: False, 0.3)
        for rollout_id in {rid for rid, _ in self._sent} | set(self.results):
            self.results.setdefault(rollout_id, RolloutResult(rollout_id)).steps = self.steps_of(rollout_id)
        return [self.results[r] for r in sorted(self.results)]
