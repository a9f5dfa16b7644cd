"""The verdicts of a live suite for ``fiper launch --summary``: what the fusion node said of each rollout, against the
outcome its RolloutEvent END carries, and the closing table of TPR, TNR and detection steps
(:mod:`fiper_ros.evaluation.verdicts`, as ``fiper replay`` prints it).

:class:`LiveVerdicts` follows, in a session of its own on a thread of its own, the rollout events, every alarm
decision (heartbeats aside) and RND-OE's scores (every judged step has one). A rollout's line is printed once its
END arrived and its last scored step has its verdict (or :data:`SETTLE_S` after the END, whatever came), the table
when the launch stops: first :meth:`LiveVerdicts.settle` (before the nodes stop: verdicts still on their way
arrive), then :meth:`LiveVerdicts.close`. A rollout of which no verdict was seen (its START replayed from before
these nodes ran, TRANSIENT_LOCAL) is left out and counted. The alarm is KEEP_LAST(1) on the fusion node's side: a
decision published before this session's reader matched the fusion node is lost to it (discovery of a booting
process can take seconds), so the session reports its matches on ``/diagnostics`` (``/fiper_launch_summary``), and
a policy's ``wait_for_suite`` waits for it too. With ``--in-process`` the nodes' Ctrl-C ends this
session too (rclpy shuts every context down): nothing settles then, the table holds what had arrived.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

from rclpy.executors import ExternalShutdownException

from fiper_msgs.msg import FailureAlarm, RolloutEvent, Score
from fiper_ros.client.capture import report_matches
from fiper_ros.client.ros_session import RosSession
from fiper_ros.evaluation.results import RolloutResult, StepResult
from fiper_ros.evaluation.verdicts import in_sample_warning, rollout_line, table, tally
from fiper_ros.interface import qos
from fiper_ros.interface.messages import NO_ROLLOUT, outcome_name
from fiper_ros.interface.topics import ALARM_TOPIC, EVENTS_TOPIC, SCORE_RND_OE_TOPIC

#: Seconds after a rollout's END within which its last verdicts are waited for.
SETTLE_S = 5.0
#: Seconds the session may take to start.
START_S = 30.0
PREFIX = "[summary] "


class LiveVerdicts:
    """Follows a live suite's rollouts and verdicts on a thread; prints each rollout's line and, at the end, the table.

    Args:
        split: The ``split`` record of the suite's calibration (which rollouts it was fitted on), for the in-sample
            warning; empty when not known.
        domain: ROS domain (default: ``ROS_DOMAIN_ID``).
        say: Prints one line (the launcher's, which keeps lines whole among the nodes' output).
    """

    def __init__(self, split: Mapping[str, Any] | None = None, domain: int | None = None,
                 say: Callable[[str], None] = print) -> None:
        self.split = dict(split or {})
        self.domain = domain
        self.say = say
        self.results: dict[int, RolloutResult] = {}
        self._scored: dict[int, int] = {}
        self._ended: dict[int, float] = {}
        self._printed: set[int] = set()
        self._lock = threading.Lock()
        self._ready = threading.Event()
        self._stop = threading.Event()
        self._settle_until = 0.0
        self._thread = threading.Thread(target=self._run, name="fiper-summary", daemon=True)

    def start(self) -> None:
        """Start following (returns once subscribed)."""
        self._thread.start()
        if not self._ready.wait(START_S):
            raise RuntimeError(f"the summary's ROS session did not start within {START_S:g} s")

    def _run(self) -> None:
        with RosSession("fiper_launch_summary", self.domain) as session:
            node = session.node
            subscriptions = [node.create_subscription(RolloutEvent, EVENTS_TOPIC, self._on_event, qos.EVENT),
                             node.create_subscription(FailureAlarm, ALARM_TOPIC, self._on_alarm, qos.ALARM_EVERY),
                             node.create_subscription(Score, SCORE_RND_OE_TOPIC, self._on_score, qos.SCORE_SUB)]
            report_matches(node, lambda: {s.topic_name: s.get_publisher_count() for s in subscriptions})
            self._ready.set()
            try:
                while not self._stop.is_set() or (time.monotonic() < self._settle_until and not self._settled()):
                    session.spin_once(0.05)
                    self._print_settled()
            except ExternalShutdownException:
                pass  # --in-process: the nodes' Ctrl-C shut every rclpy context down, this one too

    # callbacks ----------------------------------------------------------------------------------------
    def _result(self, rollout_id: int) -> RolloutResult:
        return self.results.setdefault(rollout_id, RolloutResult(rollout_id))

    def _on_event(self, msg: RolloutEvent) -> None:
        with self._lock:
            result = self._result(int(msg.rollout_id))
            if msg.event == RolloutEvent.EVENT_START:
                result.task, result.scenario = msg.task, msg.scenario
            elif msg.event == RolloutEvent.EVENT_END:
                result.outcome = outcome_name(msg.outcome)
                self._ended.setdefault(result.rollout_id, time.monotonic())

    def _on_alarm(self, msg: FailureAlarm) -> None:
        if msg.heartbeat or msg.rollout_id == NO_ROLLOUT:
            return
        with self._lock:
            self._result(int(msg.rollout_id)).steps.setdefault(int(msg.step), StepResult.of_alarm(msg))

    def _on_score(self, msg: Score) -> None:
        with self._lock:
            rollout_id = int(msg.rollout_id)
            self._scored[rollout_id] = max(self._scored.get(rollout_id, -1), int(msg.step))

    # printing -----------------------------------------------------------------------------------------
    def _judged(self, rollout_id: int) -> bool:
        """Whether the last step scored of ``rollout_id`` has its verdict."""
        return self._scored.get(rollout_id, -1) in self.results[rollout_id].steps

    def _settled(self) -> bool:
        """Whether every ended rollout the suite scored or judged has its line, or its last verdict."""
        with self._lock:
            return all(self._judged(r) for r in self._ended if r not in self._printed
                       and (self.results[r].steps or r in self._scored))

    def _print_settled(self) -> None:
        now = time.monotonic()
        with self._lock:
            due = [r for r, ended in self._ended.items() if r not in self._printed and self.results[r].steps
                   and (self._judged(r) or now - ended >= SETTLE_S)]
            for rollout_id in due:
                self._printed.add(rollout_id)
                self.say(PREFIX + rollout_line(self.results[rollout_id]))

    def settle(self, timeout_s: float = SETTLE_S) -> None:
        """Stop following once the ended rollouts' last verdicts are in, at most ``timeout_s`` from now."""
        self._settle_until = time.monotonic() + timeout_s
        self._stop.set()
        self._thread.join(timeout_s + START_S)

    def close(self) -> list[RolloutResult]:
        """Print the lines not printed yet (rollouts still running: outcome unknown) and the closing table; the
        results with verdicts."""
        if self._thread.is_alive():
            self.settle(0.0)
        with self._lock:
            judged = [self.results[r] for r in sorted(self.results) if self.results[r].steps]
            for result in judged:
                if result.rollout_id not in self._printed:
                    self.say(PREFIX + rollout_line(result))
            unseen = len(self.results) - len(judged)
        lines = table(tally(judged))
        if unseen:
            lines.append(f"{unseen} rollout(s) without any verdict seen (from before these nodes ran?): left out")
        if warning := in_sample_warning(self.split, [r.rollout_id for r in judged]):
            lines.append(warning)
        for line in lines:
            self.say(PREFIX + line)
        return judged
