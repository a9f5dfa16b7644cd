"""The operator of a live sim suite: waits for its nodes, resets the sim bridge, follows rollouts to their END.

Shared by ``fiper demo`` and ``fiper collect --ros``. It runs in one rclpy session beside a suite that
:class:`~fiper_ros.client.suite_process.SuiteProcess` started: it reads the nodes' lifecycle states from
``/diagnostics``, calls ``/sim/reset`` and keeps a :class:`~fiper_ros.client.trace.RolloutTrace` per
rollout it started (action batches, the scores of the detectors the calibration declares, the alarm, START /
END stamps, the outcome) from its own subscriptions, which take the declared detectors' scores only (with an
observation-only calibration, RND-OE's alone). A :class:`~fiper_ros.client.record.Recorder` given to it is
polled whenever it spins; an alarm display given to it sees every alarm decision. Before the first reset it waits until the nodes
are active and wired (:mod:`fiper_ros.runtime.wiring`). Nothing waits forever: a node process that
died (the launcher exited), a node that never became active, a reset that was not answered and a rollout
that stopped making progress end in :class:`SuiteFailed`; Ctrl-C / SIGTERM (the session's stop) in
:class:`KeyboardInterrupt`.
"""
from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Sequence

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from fiper_msgs.msg import ActionChunkBatch, FailureAlarm, RolloutEvent, Score
from fiper_msgs.srv import ResetRollout
from fiper_ros.client.errors import ClientError
from fiper_ros.client.record import Recorder
from fiper_ros.client.ros_session import RosSession
from fiper_ros.client.suite_process import SuiteProcess, detector_topics
from fiper_ros.client.trace import RolloutEvents, RolloutTrace
from fiper_ros.core.detectors import info
from fiper_ros.interface import messages, qos
from fiper_ros.interface.conversions import stamp_ns
from fiper_ros.interface.topics import ACTIONS_TOPIC, ALARM_TOPIC, DIAGNOSTICS_TOPIC, EVENTS_TOPIC, SIM_RESET_SERVICE
from fiper_ros.runtime.trusted_publishers import fully_qualified
from fiper_ros.runtime.wiring import missing_matches

#: Deep history for what the driver follows (the contract's KEEP_LAST(1) would skip steps here).
TRACE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=200, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: Seconds ``/sim/reset`` may take to answer.
RESET_TIMEOUT_S = 30.0
#: Seconds a running rollout may go without a new action-chunk batch.
STALL_TIMEOUT_S = 30.0
#: Seconds to wait after a rollout's END for what it left in flight (its last scores, its messages in a bag):
#: the wait ends as soon as they are in, so the bound only matters when something is lost (2 s was too short
#: under load 14: the last step's scores came later).
SETTLE_S = 10.0

#: Called with every alarm decision (not heartbeats) of a rollout the driver follows, after its bookkeeping.
AlarmDisplay = Callable[[RolloutTrace, FailureAlarm], None]


class SuiteFailed(ClientError):
    """A part of the live suite did not do its job.

    Args:
        message: What went wrong, one line.
        output: The last lines of the suite's output when they tell why (a node died), else empty.
    """

    def __init__(self, message: str, output: str = "") -> None:
        super().__init__(message)
        self.output = output


def alarm_line(msg: FailureAlarm) -> str:
    """One alarm decision on one line: each judged detector's windowed score against its threshold, the state."""
    scores = [f"{info(d).label} {eta:8.3f} / {gamma:8.3f} {'>' if exceeded else ' '}"
              for d, eta, gamma, exceeded in zip(msg.detectors, msg.eta, msg.gamma, msg.exceeded)]
    return " | ".join([f"step {msg.step:3d}", *scores, messages.AlarmStateName.of_code(msg.state).name])


class SimSuiteDriver:
    """Readiness, resets and rollouts of a live sim suite, in one rclpy session.

    Args:
        session: The rclpy session (its node subscribes and calls the bridge).
        suite: The suite's launcher process (checked whenever the driver spins).
        task: Sim task of the resets.
        detectors: The detectors the suite's calibration declares (none: a suite without scoring nodes).
        recorder: Polled for new topics whenever the driver spins (it records what the session receives).
        display: Sees every alarm decision.
    """

    def __init__(self, session: RosSession, suite: SuiteProcess, task: str, detectors: tuple[str, ...], *,
                 recorder: Recorder | None = None, display: AlarmDisplay | None = None) -> None:
        self.session = session
        self.suite = suite
        self.task = task
        self.detectors = detectors
        self.recorder = recorder
        self.display = display
        node = session.node
        assert node is not None
        self.node = node
        #: The latest /diagnostics key/values of each node (by fully qualified name).
        self.diagnostics: dict[str, dict[str, str]] = {}
        self.events = RolloutEvents()
        #: The followed rollouts' traces, by rollout id.
        self.traces = self.events.traces
        self._reset = node.create_client(ResetRollout, SIM_RESET_SERVICE)
        node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self._on_diagnostics, qos.DIAGNOSTICS)
        for detector in detectors:
            node.create_subscription(Score, detector_topics(detector)[2], self._on_score, TRACE_QOS)
        node.create_subscription(FailureAlarm, ALARM_TOPIC, self._on_alarm, TRACE_QOS)
        node.create_subscription(RolloutEvent, EVENTS_TOPIC, self._on_event, qos.EVENT)
        node.create_subscription(ActionChunkBatch, ACTIONS_TOPIC, self._on_actions, qos.INPUT)

    # callbacks ----------------------------------------------------------------------------------------
    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            self.diagnostics[status.hardware_id] = {v.key: v.value for v in status.values}

    def _route(self, rollout_id: int, apply: Callable[[RolloutTrace], None]) -> None:
        """``apply`` a message to its rollout's trace, or keep it for the trace the reset's answer brings."""
        trace = self.traces.get(rollout_id)
        if trace is None:
            self.events.defer(rollout_id, apply)
        else:
            apply(trace)

    def _on_score(self, msg: Score) -> None:
        def apply(trace: RolloutTrace) -> None:
            if msg.detector in trace.scores:
                trace.scores[msg.detector].add(msg.step, msg.windowed_score, msg.threshold, msg.exceeded)
        self._route(msg.rollout_id, apply)

    def _on_actions(self, msg: ActionChunkBatch) -> None:
        def apply(trace: RolloutTrace) -> None:
            trace.steps_started = max(trace.steps_started, msg.step + 1)
        self._route(msg.rollout_id, apply)

    def _on_event(self, msg: RolloutEvent) -> None:
        if msg.event == RolloutEvent.EVENT_START:
            self.events.start(msg.rollout_id, stamp_ns(msg.header.stamp))
        elif msg.event == RolloutEvent.EVENT_END:
            self.events.end(msg.rollout_id, stamp_ns(msg.header.stamp), messages.outcome_name(msg.outcome))

    def _on_alarm(self, msg: FailureAlarm) -> None:
        if msg.heartbeat:
            return

        def apply(trace: RolloutTrace) -> None:
            trace.combine = msg.combine
            state = messages.AlarmStateName.of_code(msg.state)
            if state == messages.AlarmStateName.UNKNOWN:
                trace.unknown_steps.add(msg.step)
            elif state == messages.AlarmStateName.ALARM and trace.alarm_step is None:
                trace.alarm_step = msg.step
                trace.alarm_text = alarm_line(msg)
            if self.display is not None:
                self.display(trace, msg)
        self._route(msg.rollout_id, apply)

    # driving ------------------------------------------------------------------------------------------
    def spin(self, seconds: float) -> None:
        """Spin (and record) for ``seconds``, failing if the suite died."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self._check()
            self.session.spin_once(0.02)

    def _check(self) -> None:
        if self.recorder is not None:
            self.recorder.poll()
        if not self.suite.alive():
            exits = "; ".join(self.suite.node_exits()) or "a required node died"
            raise SuiteFailed(f"the suite's launcher exited ({exits})", self.suite.output())
        if self.session.stop.is_set():
            raise KeyboardInterrupt

    def lifecycle_state(self, node: str) -> str:
        """The lifecycle state ``node`` (``/ns/name``) last reported on /diagnostics."""
        return self.diagnostics.get(node, {}).get("lifecycle_state", "no diagnostics")

    def wait_ready(self, managed: Sequence[str], timeout_s: float, plain: Sequence[str] = ()) -> None:
        """Until every ``managed`` node (``/ns/name``) reports ``active`` on /diagnostics, their topics are
        wired (:func:`~fiper_ros.runtime.wiring.missing_matches`, the driver's own subscriptions included),
        every ``plain`` node is in the graph, the bridge's reset is served and the recorder (if any)
        subscribed to all its topics."""
        deadline = time.monotonic() + timeout_s

        def missing() -> list[str]:
            names = {fully_qualified(namespace, name) for name, namespace in self.node.get_node_names_and_namespaces()}
            waiting = [n for n in managed if self.lifecycle_state(n) != "active"]
            own = Counter(s.topic_name for s in self.node.subscriptions)
            waiting += missing_matches(self.diagnostics, managed, own) if not waiting else []
            waiting += [n for n in plain if n not in names]
            waiting += ["/sim/reset service"] if not self._reset.service_is_ready() else []
            waiting += sorted(self.recorder.missing()) if self.recorder is not None else []
            return waiting

        while missing():
            if time.monotonic() > deadline:
                states = ", ".join(f"{n}: {self.lifecycle_state(n)}" for n in managed)
                raise SuiteFailed(f"not ready after {timeout_s:g} s, waiting for {', '.join(missing())} ({states})")
            self.spin(0.1)

    def reset(self, scenario: str, seed: int, label: str = "") -> RolloutTrace:
        """Reset the bridge into ``(task, scenario, seed)``; the trace of the new rollout."""
        future = self._reset.call_async(ResetRollout.Request(task=self.task, scenario=scenario, seed=seed))
        deadline = time.monotonic() + RESET_TIMEOUT_S
        while not future.done():
            if time.monotonic() > deadline:
                raise SuiteFailed(f"/sim/reset did not answer within {RESET_TIMEOUT_S:g} s")
            self.spin(0.02)
        response = future.result()
        if response is None or not response.success:
            raise SuiteFailed(f"/sim/reset refused {self.task}/{scenario} seed {seed}: "
                              f"{response.message if response else 'no response'}")
        return self.events.follow(RolloutTrace(label, scenario, seed, rollout_id=response.rollout_id,
                                               detectors=self.detectors, max_steps=response.max_steps))

    def follow(self, trace: RolloutTrace, timeout_s: float) -> None:
        """Spin until ``trace``'s rollout ended; fail after ``timeout_s`` or :data:`STALL_TIMEOUT_S` without
        a new action-chunk batch."""
        deadline = time.monotonic() + timeout_s
        last_progress, progress_at = -1, time.monotonic()
        while not trace.ended:
            if trace.steps_started != last_progress:
                last_progress, progress_at = trace.steps_started, time.monotonic()
            if time.monotonic() > deadline:
                raise SuiteFailed(f"rollout {trace.rollout_id} did not end within {timeout_s:g} s "
                                  f"({trace.steps_started} policy steps)")
            if time.monotonic() - progress_at > STALL_TIMEOUT_S:
                raise SuiteFailed(f"rollout {trace.rollout_id}: no action-chunk batch for {STALL_TIMEOUT_S:g} s "
                                  f"after step {trace.steps_started} (is the policy node running?)")
            self.spin(0.05)

    def settle(self, done: Callable[[], bool], timeout_s: float) -> bool:
        """Spin until ``done()`` (what a rollout left in flight landed) or ``timeout_s`` passed; ``done()``."""
        deadline = time.monotonic() + timeout_s
        while not done() and time.monotonic() < deadline:
            self.spin(0.05)
        return done()
