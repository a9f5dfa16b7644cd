"""Python-heap tracing of chosen processes of a run (a by-hand diagnostic of the soak, docs/benchmarks.md).

Put this folder first on ``PYTHONPATH`` and set ``FIPER_MEMTRACE=DIR``: every Python process of the run whose
command line contains ``FIPER_MEMTRACE_MATCH`` (default ``sim_bridge.bridge_node``) traces its allocations
(``tracemalloc``, 8 frames) and writes ``DIR/<pid>-<n>.snapshot`` every ``FIPER_MEMTRACE_S`` seconds (default
300) together with its VmRSS, so that Python-level growth can be told from native growth (DDS, the allocator):
``python tools/memtrace/compare.py DIR`` prints both. Other processes are left alone.

    PYTHONPATH=tools/memtrace:$PYTHONPATH FIPER_MEMTRACE=runs/memtrace python -m fiper_ros.bench.soak_bench ...
"""
from __future__ import annotations

import os
import sys
import threading
import time
import tracemalloc
from pathlib import Path


def _rss_kb() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return -1


def _dump_forever(folder: Path, period_s: float) -> None:
    count = 0
    while True:
        time.sleep(period_s)
        count += 1
        stem = folder / f"{os.getpid()}-{count:03d}"
        tracemalloc.take_snapshot().dump(str(stem) + ".snapshot")
        traced, _ = tracemalloc.get_traced_memory()
        stem.with_suffix(".rss").write_text(f"{time.time():.0f} {_rss_kb()} {traced}\n")


def _start() -> None:
    target = os.environ.get("FIPER_MEMTRACE")
    command = " ".join(sys.orig_argv)  # sys.argv is not set yet for `python -m MODULE`
    if not target or os.environ.get("FIPER_MEMTRACE_MATCH", "sim_bridge.bridge_node") not in command:
        return
    folder = Path(target)
    folder.mkdir(parents=True, exist_ok=True)
    tracemalloc.start(8)
    threading.Thread(target=_dump_forever, args=(folder, float(os.environ.get("FIPER_MEMTRACE_S", "300"))),
                     daemon=True, name="memtrace").start()


_start()
