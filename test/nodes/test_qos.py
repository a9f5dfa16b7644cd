"""QoS profiles over real DDS: a subscriber that must see every alarm gets a burst that arrives
before its callback runs (the fusion node's heartbeat can follow a step's alarm that closely)."""
from __future__ import annotations

from fiper_msgs.msg import FailureAlarm
from fiper_ros.client.ros_session import RosSession
from fiper_ros.interface import qos


def _burst_received(profile: object, domain: int, count: int = 20) -> list[int]:
    received: list[int] = []
    with RosSession("qos_probe", domain) as session:
        node = session.node
        publisher = node.create_publisher(FailureAlarm, "alarm_probe", qos.ALARM)  # the fusion node's profile
        node.create_subscription(FailureAlarm, "alarm_probe", lambda m: received.append(int(m.step)), profile)
        assert session.spin_until(lambda: publisher.get_subscription_count() == 1, 10)
        for step in range(count):  # no spinning in between: all arrive before the first callback
            publisher.publish(FailureAlarm(rollout_id=1, step=step))
        publisher.wait_for_all_acked()
        session.spin_until(lambda: len(received) >= count, 5)
    return received


def test_alarm_every_keeps_a_burst_that_the_latest_state_profile_collapses(ros_domain: int) -> None:
    assert _burst_received(qos.ALARM_EVERY, ros_domain) == list(range(20))
    assert _burst_received(qos.ALARM, ros_domain) == [19]  # depth 1: only the latest (why the replay needs ALARM_EVERY)
