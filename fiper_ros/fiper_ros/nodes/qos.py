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

#: Lease of the score streams' liveliness: a dead scoring process is noticed within this time.
SCORE_LEASE = Duration(seconds=1)
#: Lease of the alarm stream's liveliness, asserted every :data:`ALARM_HEARTBEAT_S` by the fusion node.
ALARM_LEASE = Duration(seconds=1)


def _latched(depth: int, liveliness: LivelinessPolicy = LivelinessPolicy.SYSTEM_DEFAULT,
             lease: Duration | None = None) -> QoSProfile:
    """RELIABLE + TRANSIENT_LOCAL + KEEP_LAST(``depth``), with a liveliness ``lease`` if given."""
    extra = {} if lease is None else {"liveliness": liveliness, "liveliness_lease_duration": lease}
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL, **extra)


INPUT = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.VOLATILE)
#: How often a scoring node asserts its liveliness (well inside the lease).
SCORE_HEARTBEAT_S = SCORE_LEASE.nanoseconds / 1e9 / 4
SCORE_PUB = _latched(50, LivelinessPolicy.MANUAL_BY_TOPIC, SCORE_LEASE)
SCORE_SUB = _latched(50, LivelinessPolicy.AUTOMATIC, SCORE_LEASE)
EVENT = _latched(10)
ALARM = _latched(1)
ALARM_HEARTBEAT_S = ALARM_LEASE.nanoseconds / 1e9 / 4
#: The fusion node's alarm publisher: :data:`ALARM` with liveliness (compatible with every ALARM subscriber).
ALARM_PUB = _latched(1, LivelinessPolicy.MANUAL_BY_TOPIC, ALARM_LEASE)
#: A supervisor's subscription: :data:`ALARM` asking for the lease, so its liveliness events count live publishers.
ALARM_LIVE = _latched(1, LivelinessPolicy.AUTOMATIC, ALARM_LEASE)
#: For a subscriber that needs every step's alarm, not only the latest state (the bag replay, benchmarks):
#: a heartbeat can follow a step's alarm within milliseconds, and a depth-1 reader keeps only the newer
#: of two samples that arrive before its callback runs. Compatible with :data:`ALARM` publishers.
ALARM_EVERY = _latched(1000)
DIAGNOSTICS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)
