"""Under use_sim_time every time the nodes use comes from /clock: staleness follows simulated time."""
from __future__ import annotations

from pathlib import Path

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock

from fiper_msgs.msg import FailureAlarm
from fiper_ros.interface import qos
from fiper_ros.interface.conversions import to_stamp
from helpers.suite import Suite
from helpers.synthetic import make_rollout

S = 1_000_000_000


def test_deadline_runs_on_sim_time_not_wall_time(ros_domain: int, calibration_dir: Path) -> None:
    sim = [Parameter("use_sim_time", value=True)]
    suite = Suite(ros_domain, str(calibration_dir), extra=sim, fusion=[*sim, Parameter("deadline_s", value=1.0)])
    clock = suite.driver.create_publisher(Clock, "/clock", 10)
    fusion_reports: list[DiagnosticStatus] = []
    suite.driver.create_subscription(DiagnosticArray, "/diagnostics", lambda m: fusion_reports.extend(
        status for status in m.status if status.name.endswith("/fusion_node")), qos.DIAGNOSTICS)

    def tick(ns: int) -> None:
        clock.publish(Clock(clock=to_stamp(ns)))
        suite.spin_until(lambda: suite.fusion.now_ns() == ns, timeout=5.0)

    try:
        suite.wait_active()
        tick(100 * S)
        rollout = make_rollout(600)
        suite.driver.start(4)
        assert suite.spin_until(lambda: suite.fusion.fuser.rollout_id == 4)
        suite.driver.step(4, 0, rollout.embeddings[0], rollout.actions[0], rollout.exec_steps)
        assert suite.spin_until(lambda: 0 in suite.driver.alarms_of(4))
        assert suite.driver.alarms_of(4)[0].state == FailureAlarm.STATE_OK
        # The fusion node's /diagnostics run on its steady clock: three more reports span at least two
        # periods (2 s) of the node's own wall time, twice the deadline, while no sim time passes.
        reports = len(fusion_reports)
        assert suite.spin_until(lambda: len(fusion_reports) >= reports + 3, timeout=15.0)
        assert suite.fusion.now_ns() == 100 * S
        stale = [m for m in suite.driver.alarms if m.state == FailureAlarm.STATE_UNKNOWN and "older than" in m.reason]
        assert not stale
        tick(102 * S)  # two simulated seconds later: both streams are stale
        assert suite.spin_until(lambda: any(m.state == FailureAlarm.STATE_UNKNOWN and "older than" in m.reason
                                            for m in suite.driver.alarms), timeout=5.0)
        unknown = next(m for m in suite.driver.alarms if "older than" in m.reason)
        assert unknown.header.stamp.sec == 102
    finally:
        suite.close()
