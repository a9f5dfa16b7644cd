"""The QoS of the suite's streams as plain values, without rclpy (docs/alarm-contract.md).

One home for the numbers: :mod:`fiper_ros.interface.qos` builds the rclpy profiles the nodes use from
these, and :mod:`fiper_ros.bagio.schema` the offered QoS a bag records. Every stream is RELIABLE and
KEEP_LAST; what differs is the depth, the durability and the liveliness (see :mod:`.qos` for why).
"""
from __future__ import annotations

from dataclasses import dataclass

#: Durability and liveliness kinds, named as in rclpy's ``DurabilityPolicy`` / ``LivelinessPolicy``.
VOLATILE, TRANSIENT_LOCAL, SYSTEM_DEFAULT = "VOLATILE", "TRANSIENT_LOCAL", "SYSTEM_DEFAULT"
AUTOMATIC, MANUAL_BY_TOPIC = "AUTOMATIC", "MANUAL_BY_TOPIC"

#: Lease of the score streams' liveliness: a dead scoring process is noticed within this time.
SCORE_LEASE_NS = 1_000_000_000
#: Lease of the alarm stream's liveliness, asserted every :data:`ALARM_HEARTBEAT_S` by the fusion node.
ALARM_LEASE_NS = 1_000_000_000
#: How often a scoring node asserts its liveliness (well inside the lease).
SCORE_HEARTBEAT_S = SCORE_LEASE_NS / 1e9 / 4
ALARM_HEARTBEAT_S = ALARM_LEASE_NS / 1e9 / 4


@dataclass(frozen=True)
class QosSpec:
    """One RELIABLE, KEEP_LAST profile.

    Attributes:
        depth: History depth.
        durability: :data:`VOLATILE`, :data:`TRANSIENT_LOCAL` or :data:`SYSTEM_DEFAULT`.
        liveliness: :data:`SYSTEM_DEFAULT`, :data:`AUTOMATIC` or :data:`MANUAL_BY_TOPIC`.
        lease_ns: Liveliness lease duration; 0: none (liveliness left at the system default).
    """

    depth: int
    durability: str = SYSTEM_DEFAULT
    liveliness: str = SYSTEM_DEFAULT
    lease_ns: int = 0


def _latched(depth: int, liveliness: str = SYSTEM_DEFAULT, lease_ns: int = 0) -> QosSpec:
    """TRANSIENT_LOCAL + KEEP_LAST(``depth``), with a liveliness lease if given."""
    return QosSpec(depth, TRANSIENT_LOCAL, liveliness, lease_ns)


INPUT = QosSpec(100, VOLATILE)
SCORE_PUB = _latched(50, MANUAL_BY_TOPIC, SCORE_LEASE_NS)
SCORE_SUB = _latched(50, AUTOMATIC, SCORE_LEASE_NS)
EVENT = _latched(10)
ALARM = _latched(1)
#: The fusion node's alarm publisher: :data:`ALARM` with liveliness (compatible with every ALARM subscriber).
ALARM_PUB = _latched(1, MANUAL_BY_TOPIC, ALARM_LEASE_NS)
#: A supervisor's subscription: :data:`ALARM` asking for the lease, so its liveliness events count live publishers.
ALARM_LIVE = _latched(1, AUTOMATIC, ALARM_LEASE_NS)
#: For a subscriber that needs every step's alarm, not only the latest state (the bag replay, benchmarks):
#: a heartbeat can follow a step's alarm within milliseconds, and a depth-1 reader keeps only the newer
#: of two samples that arrive before its callback runs. Compatible with :data:`ALARM` publishers.
ALARM_EVERY = _latched(1000)
DIAGNOSTICS = QosSpec(10)
