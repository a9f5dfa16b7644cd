"""Benchmarks of the fiper-ros suite (``make bench-*``), one module each."""
from __future__ import annotations

from pathlib import Path

__all__ = ["EVERY_ALARM", "memory_mb", "core_bench", "eval_bench", "nodes_bench", "null_suite", "policy_bench",
           "soak_bench"]


#: The alarm contract keeps only the newest state (KEEP_LAST(1)); to count every step's alarm a benchmark
#: deepens the fusion node's history with the standard QoS override parameter.
EVERY_ALARM = {"qos_overrides./fiper/alarm.publisher.depth": 1000}


def memory_mb(pid: int, field: str = "VmRSS") -> float:
    """A memory figure of ``/proc/PID/status`` in MB: ``VmRSS`` (resident now) or ``VmHWM`` (peak resident); NaN
    if the process is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(f"{field}:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")
