"""Benchmarks of the fiper-ros suite (``make bench-*``), one module each."""
from __future__ import annotations

__all__ = ["EVERY_ALARM", "core_bench", "eval_bench", "nodes_bench", "policy_bench", "soak_bench"]


#: The alarm contract keeps only the newest state (KEEP_LAST(1)); to count every step's alarm a benchmark
#: deepens the fusion node's history with the standard QoS override parameter.
EVERY_ALARM = {"qos_overrides./fiper/alarm.publisher.depth": 1000}
