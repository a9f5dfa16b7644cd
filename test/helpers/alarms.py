"""/fiper/alarm in a test: every FailureAlarm the fusion node published, in the test's own context. The listener
reports its match on /diagnostics as the tools do, so a policy that names it (``wait_for_suite(also=["/test_alarms"])``,
``--wait-for suite /test_alarms``) waits until it hears the fusion node (the alarm is KEEP_LAST(1) there: decisions
before the match are lost to a late reader). Spin it meanwhile."""
from __future__ import annotations

from fiper_msgs.msg import FailureAlarm
from fiper_ros.client.capture import report_matches
from fiper_ros.interface import qos
from fiper_ros.interface.topics import ALARM_TOPIC
from helpers.spin import Listener


class AlarmListener(Listener):
    """Every alarm message (ALARM_EVERY: no step's decision skipped), in arrival order."""

    def __init__(self, domain: int) -> None:
        super().__init__(domain, "test_alarms")
        self.alarms: list[FailureAlarm] = []
        subscription = self.node.create_subscription(FailureAlarm, ALARM_TOPIC, self.alarms.append, qos.ALARM_EVERY)
        report_matches(self.node, lambda: {ALARM_TOPIC: subscription.get_publisher_count()})

    def verdicts(self) -> dict[int, dict[int, FailureAlarm]]:
        """Per rollout, the first decision (not a heartbeat) of each step."""
        out: dict[int, dict[int, FailureAlarm]] = {}
        for msg in self.alarms:
            if not msg.heartbeat:
                out.setdefault(msg.rollout_id, {}).setdefault(msg.step, msg)
        return out
