#!/usr/bin/env python3
"""Compare the snapshots ``tools/memtrace/sitecustomize.py`` wrote: per process, VmRSS and the traced Python heap
at each dump, then the allocation sites that grew most from the second dump (after warm-up) to the last.

    python tools/memtrace/compare.py DIR [TOP]
"""
from __future__ import annotations

import sys
import tracemalloc
from collections import defaultdict
from pathlib import Path


def main(argv: list[str]) -> int:
    """Print the table and the top growth per process."""
    if not argv:
        print(__doc__, file=sys.stderr)
        return 2
    folder, top = Path(argv[0]), int(argv[1]) if len(argv) > 1 else 15
    by_pid: dict[str, list[Path]] = defaultdict(list)
    for path in sorted(folder.glob("*.snapshot")):
        by_pid[path.name.split("-")[0]].append(path)
    for pid, paths in by_pid.items():
        print(f"process {pid}: dump, VmRSS MB, traced Python heap MB")
        for path in paths:
            stamp, rss_kb, traced = path.with_suffix(".rss").read_text().split()
            print(f"  {path.stem}  {int(rss_kb) / 1024:8.1f}  {int(traced) / 2**20:8.1f}")
        if len(paths) < 3:
            continue
        first, last = (tracemalloc.Snapshot.load(str(p)) for p in (paths[1], paths[-1]))
        print(f"  growth by site, {paths[1].stem} -> {paths[-1].stem}:")
        for stat in last.compare_to(first, "traceback")[:top]:
            print(f"    {stat.size_diff / 1024:+9.1f} kB {stat.count_diff:+7d} blocks  {stat.traceback.format()[-1].strip()}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
