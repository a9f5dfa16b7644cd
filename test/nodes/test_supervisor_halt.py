"""The example supervisor's halt over real DDS on loopback: it is done only when the halt service confirms it. A
service that refuses, does not answer or is not there is asked again until it confirms, and meanwhile the
supervisor says on /diagnostics why the robot is not halted."""
from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import pytest
import rclpy
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from fiper_msgs.msg import FailureAlarm
from fiper_ros.interface import qos
from helpers.spin import Listener

HALT = "/test/halt"
TIMEOUT_S, RETRY_S = 0.3, 0.1
STATUS = "fiper: /fiper/supervisor_node"


@dataclass
class HaltServer:
    """A std_srvs/Trigger halt service that refuses its first ``refusals`` requests."""

    refusals: int = 0
    requests: list[float] = field(default_factory=list)

    def __call__(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        del request
        self.requests.append(time.monotonic())
        response.success = len(self.requests) > self.refusals
        response.message = "halted" if response.success else "brakes busy"
        return response


class Bench:
    """The supervisor, an alarm publisher named as the suite's fusion node, and the supervisor's /diagnostics."""

    def __init__(self, domain: int) -> None:
        from fiper_ros.nodes.supervisor_node import SupervisorNode

        self.listener = Listener(domain, "test_halt")
        self.context = self.listener.context
        self.statuses: list[tuple[int, str, dict[str, str]]] = []
        self.listener.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, qos.DIAGNOSTICS)
        self.fusion = Node("fusion_node", namespace="/fiper", context=self.context)
        self.alarm = self.fusion.create_publisher(FailureAlarm, "/fiper/alarm", qos.ALARM_PUB)
        self.supervisor = SupervisorNode(context=self.context, namespace="/fiper", parameter_overrides=[
            Parameter("halt_service", value=HALT), Parameter("halt_timeout_s", value=TIMEOUT_S),
            Parameter("halt_retry_s", value=RETRY_S), Parameter("diagnostics_period_s", value=0.05)])
        for node in (self.fusion, self.supervisor):
            self.listener.executor.add_node(node)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name == STATUS:
                level = int.from_bytes(status.level, "little")
                self.statuses.append((level, status.message, {kv.key: kv.value for kv in status.values}))

    def spin_until(self, condition: Callable[[], bool], timeout: float = 10.0) -> bool:
        return self.listener.spin_until(condition, timeout)

    def raise_alarm(self, rollout_id: int) -> None:
        assert self.spin_until(lambda: self.alarm.get_subscription_count() >= 1)
        alarm = FailureAlarm(rollout_id=rollout_id, step=0, state=FailureAlarm.STATE_ALARM, heartbeat=False,
                             reason="both detectors exceed")
        alarm.header.stamp = Time(sec=1)
        self.alarm.publish(alarm)
        assert self.spin_until(lambda: self.supervisor.halted == 1)

    def latest(self) -> tuple[int, str, dict[str, str]]:
        count = len(self.statuses)
        assert self.spin_until(lambda: len(self.statuses) > count)
        return self.statuses[-1]

    def close(self) -> None:
        for node in (self.supervisor, self.fusion):
            self.listener.executor.remove_node(node)
            node.destroy_node()
        self.listener.close()


@pytest.fixture
def bench(ros_domain: int) -> Iterator[Bench]:
    made = Bench(ros_domain)
    try:
        yield made
    finally:
        made.close()


ERROR = int.from_bytes(DiagnosticStatus.ERROR, "little")
OK = int.from_bytes(DiagnosticStatus.OK, "little")


def test_a_refused_halt_is_asked_again_until_confirmed(bench: Bench) -> None:
    server = HaltServer(refusals=2)
    bench.listener.node.create_service(Trigger, HALT, server)
    assert bench.spin_until(lambda: bench.supervisor._halt.service_is_ready())
    bench.raise_alarm(7)
    assert bench.spin_until(lambda: len(server.requests) >= 2)
    level, message, values = bench.latest()
    assert level == ERROR and "halt of rollout 7 not confirmed" in message and "'brakes busy'" in message, message
    assert values["halt_pending"] == "7"
    assert bench.spin_until(lambda: len(server.requests) == 3 and bench.latest()[0] == OK)
    gaps = [b - a for a, b in zip(server.requests, server.requests[1:])]
    assert all(gap >= RETRY_S * 0.9 for gap in gaps), gaps  # asked again after the retry interval, not at once
    print(f"refused twice: requests {', '.join(f'{gap:.3f}' for gap in gaps)} s apart (retry {RETRY_S} s)")
    level, message, values = bench.latest()
    assert (values["halts_confirmed"], values["halt_refused"], values["halt_pending"]) == ("1", "2", "none")
    bench.spin_until(lambda: False, timeout=3 * RETRY_S)
    assert len(server.requests) == 3  # a confirmed halt is not asked again


def test_an_unanswered_halt_times_out_and_is_asked_again(bench: Bench) -> None:
    server, context = HaltServer(), Context()
    rclpy.init(context=context, domain_id=bench.context.get_domain_id())
    robot = Node("robot", context=context)
    robot.create_service(Trigger, HALT, server)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(robot)
    try:
        assert bench.spin_until(lambda: bench.supervisor._halt.service_is_ready())
        bench.raise_alarm(8)  # the robot's executor does not spin: nobody answers
        assert bench.spin_until(lambda: int(bench.latest()[2].get("halt_unanswered", 0)) >= 2)
        level, message, values = bench.latest()
        assert level == ERROR and f"no reply within {TIMEOUT_S:g} s" in message, message
        assert int(values["halt_unanswered"]) >= 2 and values["halts_confirmed"] == "0"
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and bench.latest()[0] != OK:
            executor.spin_once(timeout_sec=0.01)  # the robot answers now
        level, message, values = bench.latest()
        assert level == OK and values["halts_confirmed"] == "1" and values["halt_pending"] == "none", (message, values)
    finally:
        executor.shutdown()
        robot.destroy_node()
        rclpy.try_shutdown(context=context)


def test_a_halt_without_a_service_is_retried_and_done_once_the_service_appears(bench: Bench) -> None:
    bench.raise_alarm(9)
    assert bench.spin_until(lambda: int(bench.latest()[2].get("halt_unavailable", 0)) >= 3)
    level, message, values = bench.latest()
    assert level == ERROR and f"halt service {HALT} is not available" in message, message
    server = HaltServer()
    bench.listener.node.create_service(Trigger, HALT, server)
    assert bench.spin_until(lambda: server.requests and bench.latest()[0] == OK)
    assert len(server.requests) == 1 and bench.latest()[2]["halts_confirmed"] == "1"
