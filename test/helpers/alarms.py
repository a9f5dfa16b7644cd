"""/fiper/alarm in a test: every FailureAlarm the fusion node published, in the test's own context."""
from __future__ import annotations

from fiper_msgs.msg import FailureAlarm
from fiper_ros.interface import qos
from fiper_ros.interface.topics import ALARM
from helpers.spin import Listener


class AlarmListener(Listener):
    """Every alarm message (ALARM_EVERY: no step's decision skipped), in arrival order."""

    def __init__(self, domain: int) -> None:
        super().__init__(domain, "test_alarms")
        self.alarms: list[FailureAlarm] = []
        self.node.create_subscription(FailureAlarm, ALARM, self.alarms.append, qos.ALARM_EVERY)

    def verdicts(self) -> dict[int, dict[int, FailureAlarm]]:
        """Per rollout, the first decision (not a heartbeat) of each step."""
        out: dict[int, dict[int, FailureAlarm]] = {}
        for msg in self.alarms:
            if not msg.heartbeat:
                out.setdefault(msg.rollout_id, {}).setdefault(msg.step, msg)
        return out
