"""QoS profiles of the suite's topics (docs/alarm-contract.md).

Inputs are RELIABLE and VOLATILE (a policy starts publishing once the detectors are matched).
Scores, rollout events and the alarm are TRANSIENT_LOCAL: a late-joining node or supervisor still
gets the latest ones, and a score published while the fusion node's reader was still being
discovered (start-up) is not lost. Score publishers offer MANUAL_BY_TOPIC
liveliness and assert it from a timer (a heartbeat: Fast DDS did not keep an idle AUTOMATIC writer
alive here), so the fusion node notices a scoring node that died or hangs within ``SCORE_LEASE``.
Score subscribers ask only for AUTOMATIC liveliness. The alarm publisher asserts MANUAL_BY_TOPIC liveliness
the same way, so a supervisor that asks for a lease (:data:`ALARM_LIVE`) counts the live publishers of the
alarm: the endpoint a killed fusion node leaves in the graph (until its DDS participant lease ends) is
then not taken for a second publisher (docs/reliability.md, "Who may speak").
"""
from __future__ import annotations

from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, LivelinessPolicy, QoSProfile, ReliabilityPolicy

from fiper_ros.interface import qos_spec
from fiper_ros.interface.qos_spec import ALARM_HEARTBEAT_S, SCORE_HEARTBEAT_S, QosSpec

__all__ = ["ALARM", "ALARM_EVERY", "ALARM_HEARTBEAT_S", "ALARM_LEASE", "ALARM_LIVE", "ALARM_PUB", "DIAGNOSTICS",
           "EVENT", "INPUT", "SCORE_HEARTBEAT_S", "SCORE_LEASE", "SCORE_PUB", "SCORE_SUB", "VIEW_IMAGE", "profile"]

#: Lease of the score streams' liveliness: a dead scoring process is noticed within this time.
SCORE_LEASE = Duration(nanoseconds=qos_spec.SCORE_LEASE_NS)
#: Lease of the alarm stream's liveliness, asserted every :data:`ALARM_HEARTBEAT_S` by the fusion node.
ALARM_LEASE = Duration(nanoseconds=qos_spec.ALARM_LEASE_NS)


def profile(spec: QosSpec) -> QoSProfile:
    """The rclpy profile of ``spec``: RELIABLE + KEEP_LAST(depth), its durability, and its liveliness if it
    has a lease (else the system default, as rclpy leaves it)."""
    extra: dict[str, object] = {}
    if spec.durability != qos_spec.SYSTEM_DEFAULT:
        extra["durability"] = DurabilityPolicy[spec.durability]
    if spec.lease_ns:
        extra["liveliness"] = LivelinessPolicy[spec.liveliness]
        extra["liveliness_lease_duration"] = Duration(nanoseconds=spec.lease_ns)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=spec.depth, reliability=ReliabilityPolicy.RELIABLE,
                      **extra)


INPUT = profile(qos_spec.INPUT)
SCORE_PUB = profile(qos_spec.SCORE_PUB)
SCORE_SUB = profile(qos_spec.SCORE_SUB)
EVENT = profile(qos_spec.EVENT)
ALARM = profile(qos_spec.ALARM)
#: The fusion node's alarm publisher: :data:`ALARM` with liveliness (compatible with every ALARM subscriber).
ALARM_PUB = profile(qos_spec.ALARM_PUB)
#: A supervisor's subscription: :data:`ALARM` asking for the lease, so its liveliness events count live publishers.
ALARM_LIVE = profile(qos_spec.ALARM_LIVE)
#: Every step's alarm, not only the latest state (the bag replay, benchmarks): see :data:`.qos_spec.ALARM_EVERY`.
ALARM_EVERY = profile(qos_spec.ALARM_EVERY)
DIAGNOSTICS = profile(qos_spec.DIAGNOSTICS)
#: A viewer's camera subscription (``fiper view``): BEST_EFFORT, the newest frame only. A reader that falls
#: behind loses frames instead of asking the publisher to resend them (compatible with RELIABLE publishers).
VIEW_IMAGE = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT,
                        durability=DurabilityPolicy.VOLATILE)
