"""Example safety supervisor: subscribes to /fiper/alarm as the contract says and halts the robot
(a std_srvs/Trigger service, the sim bridge's ``halt``) on ALARM, and on UNKNOWN or silence that
lasts longer than its own ``deadline_s``. While the alarm topic has a publisher other than
``alarm_publishers``, or more than one live publisher, the stream cannot be attributed to the suite: an OK
counts as UNKNOWN (reported as an ERROR on /diagnostics).

A halt is done when the service's reply says ``success`` (:mod:`fiper_ros.runtime.halt_delivery`): a service
that is not available, refuses or does not answer within ``halt_timeout_s`` is asked again every
``halt_retry_s`` until it confirms, and meanwhile the supervisor reports an ERROR on /diagnostics saying why.
"""
from __future__ import annotations

import sys
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from std_srvs.srv import Trigger

from fiper_msgs.msg import FailureAlarm, RolloutEvent
from fiper_ros.interface import qos
from fiper_ros.interface.conversions import stamp_ns
from fiper_ros.interface.messages import AlarmStateName
from fiper_ros.interface.topics import ALARM_TOPIC, DIAGNOSTICS_TOPIC, EVENTS_TOPIC, SIM_HALT_SERVICE
from fiper_ros.nodes.base import PUBLISHER_CHECK_PERIOD_S, describe, diagnostic_array, parameter_values
from fiper_ros.nodes.graph_watch import PublisherCheck
from fiper_ros.nodes.settings import SupervisorSettings, supervisor_settings
from fiper_ros.platform.process import run_node, run_reported
from fiper_ros.runtime.halt_delivery import HaltDelivery
from fiper_ros.runtime.stats import DEADLINE_PERIODS
from fiper_ros.runtime.supervision import HALTED_MEMORY, HaltDecision, SupervisorLogic
from fiper_ros.runtime.trusted_publishers import Expected, resolve_node

#: How often the supervisor looks at its pending halt (a reply, the reply timeout, the retry time), steady clock.
HALT_POLL_S = 0.02
#: The shortest interval between two error lines about one pending halt (every failure is counted on /diagnostics).
HALT_LOG_PERIOD_S = 5.0
#: How often the supervisor checks for silence and lasting UNKNOWN (seconds, on the node clock).
CHECK_PERIOD_S = 0.02


class SupervisorNode(Node):
    """Halts the robot when the failure monitor says so or stops saying anything."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("supervisor_node", **kwargs)
        self.declare_parameter("alarm_topic", ALARM_TOPIC, describe("FailureAlarm topic", read_only=True))
        self.declare_parameter("halt_service", SIM_HALT_SERVICE, describe("std_srvs/Trigger that halts the robot",
                                                                      read_only=True))
        self.declare_parameter("deadline_s", 2.0, describe("tolerated UNKNOWN; tolerated silence while no rollout "
                                                           "runs or its period is not measured yet",
                                                           low=0.05, high=600.0))
        self.declare_parameter("silence_periods", DEADLINE_PERIODS,
                               describe("tolerated silence during a rollout, in measured policy periods (0: deadline_s)",
                                        low=0.0, high=1000.0))
        self.declare_parameter("silence_floor_s", 0.1,
                               describe("the period-based silence deadline is never shorter", low=0.0, high=600.0))
        self.declare_parameter("events_topic", EVENTS_TOPIC,
                               describe("RolloutEvent topic: which rollout is running", read_only=True))
        self.declare_parameter("alarm_publishers", ["/fiper/fusion_node"], describe(
            "nodes that may publish the alarm topic, one publisher each (relative names: in this node's namespace)",
            read_only=True))
        self.declare_parameter("diagnostics_period_s", 1.0,
                               describe("period of /diagnostics messages", read_only=True, low=0.05, high=60.0))
        self.declare_parameter("halt_timeout_s", 1.0,
                               describe("longest wait for the halt service's reply; then the halt counts as unanswered",
                                        read_only=True, low=0.01, high=60.0))
        self.declare_parameter("halt_retry_s", 0.5,
                               describe("wait before asking again for a halt the service did not confirm (not available, "
                                        "refused, unanswered)", read_only=True, low=0.01, high=60.0))
        self.settings: SupervisorSettings = supervisor_settings(parameter_values(self))
        settings = self.settings
        self.logic = SupervisorLogic(settings.deadline_ns, settings.silence_periods, settings.silence_floor_ns)
        self.halts: list[HaltDecision] = []
        #: Halts decided since the start (``halts`` keeps only the recent ones).
        self.halted = 0
        self.delivery = HaltDelivery(settings.halt_timeout_ns, settings.halt_retry_ns)
        self._halt_future: Any = None
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._halt = self.create_client(Trigger, settings.halt_service)
        # The contract: TRANSIENT_LOCAL, so a supervisor that starts late still gets the latest state; with the
        # lease, liveliness counts the live publishers of the alarm.
        self.alarm_topic = self.resolve_topic_name(settings.alarm_topic)
        self.publisher_check = PublisherCheck(self, self._expected, PUBLISHER_CHECK_PERIOD_S, self._on_publishers)
        self.create_subscription(FailureAlarm, self.alarm_topic, self._on_alarm, qos.ALARM_LIVE,
                                 event_callbacks=SubscriptionEventCallbacks(
                                     liveliness=lambda info: self.publisher_check.set_liveliness(
                                         self.alarm_topic, info.not_alive_count)))
        self.create_subscription(RolloutEvent, settings.events_topic, self._on_event, qos.EVENT)
        self.create_timer(CHECK_PERIOD_S, self._on_clock)
        self.create_timer(HALT_POLL_S, self._deliver, clock=self._steady)
        self._diagnostics = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, qos.DIAGNOSTICS)
        self.create_timer(settings.diagnostics_period_s, self._publish_diagnostics, clock=self._steady)

    def _now(self) -> int:
        return self.get_clock().now().nanoseconds

    def _on_alarm(self, msg: FailureAlarm) -> None:
        decision = self.logic.on_state(msg.rollout_id, AlarmStateName.of_code(msg.state), msg.reason, self._now(),
                                       msg.step, msg.heartbeat, self._steady.now().nanoseconds,
                                       stamp_ns(msg.header.stamp))
        if msg.state == FailureAlarm.STATE_ALARM and decision is not None:
            scores = ", ".join(f"{d} {eta:.3g} > {gamma:.3g} = {exceeded}"
                               for d, eta, gamma, exceeded in zip(msg.detectors, msg.eta, msg.gamma, msg.exceeded))
            self.get_logger().warning(f"ALARM rollout {msg.rollout_id} step {msg.step}: {scores}")
        self._act(decision)

    def _expected(self) -> list[Expected]:
        names = self.settings.alarm_publishers
        return [Expected(self.alarm_topic, frozenset(resolve_node(n, self.get_namespace()) for n in names))]

    def _on_publishers(self) -> None:
        self._act(self.logic.suspect(self.publisher_check.watch.doubt((self.alarm_topic,)), self._now(),
                                     self._steady.now().nanoseconds))

    def _publish_diagnostics(self) -> None:
        error = "; ".join(e for e in (self.delivery.error(), self.publisher_check.error()) if e)
        values = ({"halts": str(self.halted)} | self.delivery.diagnostic_values()
                  | self.publisher_check.diagnostic_values())
        self._diagnostics.publish(diagnostic_array(self, DiagnosticStatus.ERROR if error else DiagnosticStatus.OK,
                                                   error or "watching", values))

    def _on_event(self, msg: RolloutEvent) -> None:
        self.logic.on_event(msg.rollout_id, msg.event == RolloutEvent.EVENT_START)

    def _on_clock(self) -> None:
        self._act(self.logic.on_clock(self._now(), self._steady.now().nanoseconds))

    def _act(self, decision: HaltDecision | None) -> None:
        if decision is None:
            return
        self.halts.append(decision)
        self.halted += 1
        del self.halts[:-HALTED_MEMORY]  # the recent ones: one per new rollout id would grow without end
        self.get_logger().warning(f"halting the robot (rollout {decision.rollout_id}): {decision.reason}")
        self.delivery.decide(decision, self._steady.now().nanoseconds)
        self._deliver()

    def _deliver(self) -> None:
        """Take the reply to the halt request in flight, give up waiting for it past ``halt_timeout_s``, and send
        the pending halt when it is due."""
        delivery, now = self.delivery, self._steady.now().nanoseconds
        future = self._halt_future
        if future is not None and future.done():
            self._halt_future = None
            response = future.result()
            confirmed = delivery.replied(response.success, response.message, now)
            if confirmed is not None:
                self.get_logger().info(f"halt of rollout {confirmed.decision.rollout_id} confirmed after "
                                       f"{confirmed.attempts} request(s): {response.message}")
            else:
                self._report_unconfirmed()
        elif future is not None and delivery.timed_out(now):
            self._halt.remove_pending_request(future)  # a late reply is not taken: the halt is asked again
            self._halt_future = None
            self._report_unconfirmed()
        if not delivery.due(now):
            return
        if self._halt.service_is_ready():
            self._halt_future = self._halt.call_async(Trigger.Request())
            delivery.sent(now)
        else:
            delivery.unavailable(self._halt.srv_name, now)
            self._report_unconfirmed()

    def _report_unconfirmed(self) -> None:
        """Log why the pending halt is not confirmed: one call site, so one throttle for every kind of failure."""
        self.get_logger().error(self.delivery.error(), throttle_duration_sec=HALT_LOG_PERIOD_S)


#: The node class, for in-process launching.
NODE_CLASS = SupervisorNode


def main(args: list[str] | None = None) -> int:
    """Entry point: ``python -m fiper_ros.nodes.supervisor_node --ros-args ...``."""
    return run_reported("supervisor_node", run_node, SupervisorNode, args)


if __name__ == "__main__":
    sys.exit(main())
