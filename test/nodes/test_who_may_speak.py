"""Only the suite speaks for the suite (issue #26), over real DDS on loopback: a second publisher of the alarm,
a foreign publisher of a score, a second suite in the same domain, and resets as deliberate acts."""
from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from fiper_msgs.msg import FailureAlarm
from fiper_msgs.srv import ResetAlarm
from fiper_ros.core.rollout import Rollout
from fiper_ros.runtime.trusted_publishers import FOREIGN, SEVERAL
from helpers.dds import spawn_python, stop
from helpers.intruder import MARK_LATENCY_MS
from helpers.suite import Suite
from helpers.synthetic import FAIL_FROM, make_rollout

#: A 10 Hz policy.
PERIOD_S = 0.1
#: The promise: an unexpected publisher is noticed within this many seconds of its appearance in the graph.
NOTICED_WITHIN_S = 1.0
ERROR = str(int.from_bytes(DiagnosticStatus.ERROR, "little"))


class Paced:
    """Publishes a long rollout at 10 Hz into a suite while waiting for something to happen."""

    def __init__(self, suite: Suite, rollout_id: int, seed: int = 900) -> None:
        self.suite = suite
        self.rollout_id = rollout_id
        self.rollout: Rollout = make_rollout(seed, length=400)
        self.step = 0
        suite.driver.start(rollout_id)
        assert suite.spin_until(lambda: suite.fusion.fuser is not None and suite.fusion.fuser.rollout_id == rollout_id)

    def until(self, condition: Callable[[], bool], timeout: float = 30.0) -> float:
        """Go on publishing steps until ``condition()``; the monotonic time it first held."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            began = time.monotonic()
            self.suite.driver.step(self.rollout_id, self.step, self.rollout.embeddings[self.step],
                                   self.rollout.actions[self.step], self.rollout.exec_steps)
            self.step += 1
            if self.suite.spin_until(condition, timeout=max(0.0, PERIOD_S - (time.monotonic() - began))):
                return time.monotonic()
        raise AssertionError(f"not within {timeout:g} s (step {self.step})")

    def states(self, since_step: int = 0) -> list[int]:
        """The per-step states of the rollout from ``since_step`` on."""
        alarms = self.suite.driver.alarms_of(self.rollout_id)
        return [alarms[t].state for t in sorted(alarms) if t >= since_step]


def _intruder(domain: int, name: str, namespace: str, topic: str, rollout_id: int):  # noqa: ANN202
    return spawn_python(["-m", "helpers.intruder", "--name", name, "--namespace", namespace, "--topic", topic,
                         "--rollout", str(rollout_id)], domain)


def _publishers(suite: Suite, topic: str) -> list[str]:
    return [f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in suite.driver.get_publishers_info_by_topic(topic)]


@pytest.fixture
def supervised(suite: Suite) -> Iterator[tuple[Suite, object, list[float]]]:
    """The in-process suite with the example supervisor (deadline 0.5 s) and a halt service that records calls."""
    from fiper_ros.nodes.supervisor_node import SupervisorNode

    halts: list[float] = []

    def on_halt(request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        del request
        halts.append(time.monotonic())
        response.success = True
        return response

    suite.driver.create_service(Trigger, "/test/halt", on_halt)
    supervisor = SupervisorNode(context=suite.context, namespace="/fiper", parameter_overrides=[
        Parameter("halt_service", value="/test/halt"), Parameter("deadline_s", value=0.5)])
    suite.executor.add_node(supervisor)
    try:
        assert suite.spin_until(lambda: supervisor._halt.service_is_ready())
        yield suite, supervisor, halts
    finally:
        suite.executor.remove_node(supervisor)
        supervisor.destroy_node()


@pytest.mark.parametrize(("name", "namespace", "kinds"), [("stale_fusion_node", "/old_launch", [FOREIGN, SEVERAL]),
                                                          ("fusion_node", "/fiper", [SEVERAL])])
def test_a_second_process_publishing_ok_on_the_alarm_makes_the_supervisor_report_it_and_halt(
        supervised: tuple[Suite, object, list[float]], ros_domain: int, name: str, namespace: str,
        kinds: list[str]) -> None:
    suite, supervisor, halts = supervised
    paced = Paced(suite, 21)
    paced.until(lambda: len(paced.states()) >= 3)
    assert set(paced.states()) == {FailureAlarm.STATE_OK} and not halts
    intruder = _intruder(ros_domain, name, namespace, "/fiper/alarm", 21)
    try:
        seen = paced.until(lambda: len(_publishers(suite, "/fiper/alarm")) == 2)
        found = paced.until(lambda: bool(supervisor.logic.suspicion))
        assert found - seen <= NOTICED_WITHIN_S, found - seen
        assert suite.spin_until(lambda: [f.kind for f in supervisor.publisher_check.watch.findings] == kinds)
        halted = paced.until(lambda: bool(halts))
        print(f"{namespace}/{name}: in doubt {found - seen:.2f} s after the graph showed it, halted "
              f"{halted - found:.2f} s later (deadline 0.5 s)")
        assert halted - found <= 0.5 + NOTICED_WITHIN_S, halted - found  # its deadline, and the clock of its timer
        assert "cannot be attributed" in supervisor.halts[-1].reason, supervisor.halts[-1]
        assert set(paced.states()) == {FailureAlarm.STATE_OK}  # the suite itself judged every step OK
        key = "fiper: /fiper/supervisor_node"

        def reported() -> bool:
            status = suite.driver.diagnostics.get(key, {})
            message = status.get("message", "")
            return status.get("level") == ERROR and f"{namespace}/{name}" in message and "2 publishers" in message

        assert suite.spin_until(reported, timeout=5.0), suite.driver.diagnostics.get(key)
    finally:
        stop(intruder)


def test_a_foreign_publisher_on_a_score_topic_is_reported_and_the_fusion_never_says_ok_while_its_data_may_count(
        suite: Suite, ros_domain: int) -> None:
    paced = Paced(suite, 31)
    paced.until(lambda: len(paced.states()) >= 3)
    assert set(paced.states()) == {FailureAlarm.STATE_OK}
    scores = next(s for s in suite.fusion.subscriptions if s.topic_name == "/fiper/scores/rnd_oe")
    intruder = _intruder(ros_domain, "intruder", "/", "/fiper/scores/rnd_oe", 31)
    try:
        matched = paced.until(lambda: scores.get_publisher_count() == 2)
        ok_at_match, step_at_match = suite.fusion.states["ok"], paced.step
        found = paced.until(lambda: suite.fusion.fuser.suspicion != "")
        assert found - matched <= NOTICED_WITHIN_S, found - matched
        named = paced.until(lambda: "/intruder" in suite.fusion.fuser.suspicion)  # its node's name may come later
        print(f"foreign score publisher: in doubt {found - matched:.2f} s after the fusion's subscription matched "
              f"it, named {named - matched:.2f} s after")
        assert named - matched <= NOTICED_WITHIN_S + 1.0, named - matched  # the grace of a node not named yet
        level, message = suite.fusion.diagnostic_level()
        assert level == DiagnosticStatus.ERROR and "/intruder" in message, message
        paced.until(lambda: any(s.latency_ms == MARK_LATENCY_MS for s in suite.driver.scores))  # its data arrives
        paced.until(lambda: paced.step >= step_at_match + 10)
    finally:
        stop(intruder)
    cleared = paced.until(lambda: suite.fusion.fuser.suspicion == "")  # gone: a clean exit leaves the graph at once
    paced.until(lambda: time.monotonic() > cleared + 1.0)  # the rest of the rollout stays in doubt
    assert suite.fusion.states["ok"] == ok_at_match, "an OK was published after the foreign publisher matched"
    later = paced.states(since_step=step_at_match + 1)
    assert later and set(later) == {FailureAlarm.STATE_UNKNOWN}
    last = suite.driver.alarms_of(31)[max(suite.driver.alarms_of(31))]
    assert "could not be attributed" in last.reason and "/fiper/scores/rnd_oe" in last.reason, last.reason
    suite.driver.end(31, True)
    fine = suite.run(make_rollout(901), rollout_id=32)  # the next rollout is judged normally
    assert {m.state for m in fine.values()} == {FailureAlarm.STATE_OK}
    assert suite.fusion.publisher_check.watch.findings == ()


def test_a_second_suite_in_the_same_domain_and_namespace_is_reported_by_both(
        suite: Suite, ros_domain: int, calibration_dir: Path) -> None:
    first = suite
    began = time.monotonic()
    second = Suite(ros_domain, str(calibration_dir))
    spinning = threading.Event()
    spinning.set()

    def spin_second(executor: SingleThreadedExecutor = second.executor) -> None:
        while spinning.is_set():
            executor.spin_once(timeout_sec=0.02)

    thread = threading.Thread(target=spin_second, daemon=True)
    thread.start()
    try:
        topics = {"/fiper/scores/rnd_oe", "/fiper/scores/ace"}

        def reported(s: Suite) -> bool:
            return topics <= {f.topic for f in s.fusion.publisher_check.watch.findings if f.kind == SEVERAL}

        seen: dict[int, float] = {}
        told: dict[int, float] = {}

        def watch() -> bool:
            now = time.monotonic()
            for i, s in enumerate((first, second)):
                if i not in seen and len(_publishers(s, "/fiper/scores/rnd_oe")) == 2:  # DDS discovered the other
                    seen[i] = now
                if i not in told and reported(s):
                    told[i] = now
            return len(seen) == len(told) == 2

        assert first.spin_until(watch, timeout=30.0), (seen, told)
        print(f"the suites discovered each other {seen[0] - began:.2f} / {seen[1] - began:.2f} s after the second "
              f"started; each reported it {told[0] - seen[0]:.2f} / {told[1] - seen[1]:.2f} s later")
        assert all(told[i] - seen[i] <= NOTICED_WITHIN_S for i in (0, 1)), (seen, told)
        for s in (first, second):
            level, message = s.fusion.diagnostic_level()
            assert level == DiagnosticStatus.ERROR and "2 publishers" in message and "/fiper/rnd_oe_node" in message
            # no OK from this data (the second suite spins in its thread)
            assert first.spin_until(lambda s=s: s.fusion.fuser.suspicion != "")
            for detector in (s.rnd_oe, s.ace):  # the two drivers: two publishers of each input
                assert first.spin_until(lambda d=detector: d.diagnostic_level()[0] == DiagnosticStatus.ERROR)
    finally:
        spinning.clear()
        thread.join()
        second.close()
    assert first.spin_until(lambda: first.fusion.publisher_check.watch.findings == ())
    fine = first.run(make_rollout(902), rollout_id=41)
    assert {m.state for m in fine.values()} == {FailureAlarm.STATE_OK}


def _reset(suite: Suite, requester: str, reason: str) -> ResetAlarm.Response:
    client = suite.driver.create_client(ResetAlarm, "/fiper/fusion_node/reset")
    assert suite.spin_until(client.service_is_ready)
    future = client.call_async(ResetAlarm.Request(requester=requester, reason=reason))
    assert suite.spin_until(future.done)
    return future.result()


def _latch(suite: Suite, rollout_id: int) -> None:
    rollout = make_rollout(rollout_id, fail=True)
    suite.run(rollout, rollout_id=rollout_id, end=False)
    assert suite.driver.alarms_of(rollout_id)[FAIL_FROM].state == FailureAlarm.STATE_ALARM
    assert suite.fusion.fuser.latched


def _diagnostics(suite: Suite, key: str, value: str) -> bool:
    return suite.spin_until(lambda: suite.driver.diagnostics.get("fiper: /fiper/fusion_node", {}).get(key) == value,
                            timeout=5.0)


def test_a_reset_clears_the_latch_and_is_logged_with_who_and_why(suite: Suite,
                                                                 capfd: pytest.CaptureFixture[str]) -> None:
    _latch(suite, 51)
    response = _reset(suite, "operator jane", "gripper freed by hand, rollout goes on")
    assert response.success and "cleared" in response.message, response.message
    assert not suite.fusion.fuser.latched
    assert _diagnostics(suite, "resets.accepted", "1") and _diagnostics(suite, "resets.refused", "0")
    log = capfd.readouterr().err
    assert "~/reset by 'operator jane', reason 'gripper freed by hand, rollout goes on'" in log, log[-2000:]
    refused = _reset(suite, "", "no name given")  # a reset names who asks
    assert not refused.success and "requester empty" in refused.message
    assert _diagnostics(suite, "resets.refused", "1")


def test_a_reset_is_refused_and_counted_when_switched_off(ros_domain: int, calibration_dir: Path) -> None:
    suite = Suite(ros_domain, str(calibration_dir), fusion=[Parameter("allow_reset", value=False)])
    try:
        suite.wait_active()
        _latch(suite, 52)
        response = _reset(suite, "operator jane", "want to go on")
        assert not response.success and "switched off" in response.message, response.message
        assert suite.fusion.fuser.latched  # only the next START clears it
        assert _diagnostics(suite, "resets.refused", "1") and _diagnostics(suite, "resets.accepted", "0")
        fine = suite.run(make_rollout(53), rollout_id=53)
        assert {m.state for m in fine.values()} == {FailureAlarm.STATE_OK}
    finally:
        suite.close()
