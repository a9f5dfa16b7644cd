"""QoS profiles of the suite's topics (docs/alarm-contract.md).

Inputs are RELIABLE and VOLATILE (a policy starts publishing once the detectors are matched).
Scores, rollout events and the alarm are TRANSIENT_LOCAL: a late-joining node or supervisor still
gets the latest ones, and a score published while the fusion node's reader was still being
discovered (start-up) is not lost. Score publishers offer MANUAL_BY_TOPIC
liveliness and assert it from a timer (a heartbeat: Fast DDS did not keep an idle AUTOMATIC writer
alive here), so the fusion node notices a scoring node that died or hangs within ``SCORE_LEASE``.
Score subscribers ask only for AUTOMATIC liveliness.
"""
from __future__ import annotations

from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, LivelinessPolicy, QoSProfile, ReliabilityPolicy

#: Lease of the score streams' liveliness: a dead scoring process is noticed within this time.
SCORE_LEASE = Duration(seconds=1)

INPUT = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.VOLATILE)
#: How often a scoring node asserts its liveliness (well inside the lease).
SCORE_HEARTBEAT_S = SCORE_LEASE.nanoseconds / 1e9 / 4
SCORE_PUB = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=50, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL, liveliness=LivelinessPolicy.MANUAL_BY_TOPIC,
                       liveliness_lease_duration=SCORE_LEASE)
SCORE_SUB = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=50, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL, liveliness=LivelinessPolicy.AUTOMATIC,
                       liveliness_lease_duration=SCORE_LEASE)
EVENT = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.TRANSIENT_LOCAL)
ALARM = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: For a subscriber that needs every step's alarm, not only the latest state (the bag replay, benchmarks):
#: a heartbeat can follow a step's alarm within milliseconds, and a depth-1 reader keeps only the newer
#: of two samples that arrive before its callback runs. Compatible with :data:`ALARM` publishers.
ALARM_EVERY = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
DIAGNOSTICS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)
