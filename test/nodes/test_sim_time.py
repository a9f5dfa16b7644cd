"""Under use_sim_time every time the nodes use comes from /clock: staleness follows simulated time."""
from __future__ import annotations

import time
from pathlib import Path

from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock

from fiper_msgs.msg import FailureAlarm
from fiper_ros.nodes.conversions import to_stamp
from helpers.suite import Suite
from helpers.synthetic import make_rollout

S = 1_000_000_000


def test_deadline_runs_on_sim_time_not_wall_time(ros_domain: int, calibration_dir: Path) -> None:
    sim = [Parameter("use_sim_time", value=True)]
    suite = Suite(ros_domain, str(calibration_dir), extra=sim, fusion=[*sim, Parameter("deadline_s", value=1.0)])
    clock = suite.driver.create_publisher(Clock, "/clock", 10)

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
        wall = time.monotonic()
        suite.spin_until(lambda: False, timeout=2.5)  # 2.5 s of wall time, no sim time passes
        assert time.monotonic() - wall >= 2.0
        stale = [m for m in suite.driver.alarms if m.state == FailureAlarm.STATE_UNKNOWN and "older than" in m.reason]
        assert not stale
        tick(102 * S)  # two simulated seconds later: both streams are stale
        assert suite.spin_until(lambda: any(m.state == FailureAlarm.STATE_UNKNOWN and "older than" in m.reason
                                            for m in suite.driver.alarms), timeout=5.0)
        unknown = next(m for m in suite.driver.alarms if "older than" in m.reason)
        assert unknown.header.stamp.sec == 102
    finally:
        suite.close()
