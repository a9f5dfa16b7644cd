#!/usr/bin/env python3
"""Compare a ``fiper evaluate`` run's configurations at equal promise rather than at equal delta per threshold.

    python tools/equal_promise.py RUN_DIR... [--promises 0.08,0.1]

For each run (its ``results.json``) and promise ``p``, the best mean TWA over the run's tasks of each (method,
combine) among the guaranteed threshold kinds, an OR of N thresholds read at delta ``p / N`` per threshold (the
union bound, Proposition 1: N = 2 for FIPER's pair, a combination's number of detectors) and every other
configuration at delta ``p``; a delta the run did not sweep, or a cell that is undefined on a task (+inf threshold),
leaves the configuration out at that promise.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from fiper_ros.core.detectors import DETECTORS
from fiper_ros.core.fusion import Combine
from fiper_ros.core.thresholds import GUARANTEED_KINDS


def best_at_promise(sweep: list[dict[str, Any]], deltas: list[float], combinations: dict[str, list[str]],
                    promise: float) -> dict[tuple[str, str], tuple[float, str, str]]:
    """(method, combine) -> (best mean TWA, window, kind) at ``promise``; ``combinations``: each combination
    method's detectors (FIPER's joins its pair); the promise per delta is :meth:`Combine.promised_multiple`'s."""
    best: dict[tuple[str, str], tuple[float, str, str]] = {}
    for row in sweep:
        if row["threshold"] not in GUARANTEED_KINDS:
            continue
        detectors = len(combinations.get(row["method"], DETECTORS))
        delta = round(promise / Combine.parse(row["combine"] or "and").promised_multiple(detectors), 6)
        matches = [i for i, d in enumerate(deltas) if abs(d - delta) < 1e-9]
        if not matches:
            continue
        values = [metrics["twa"][matches[0]] for metrics in row["metrics"].values()]
        if any(v is None for v in values):
            continue
        mean = sum(values) / len(values)
        key = (row["method"], row["combine"])
        if key not in best or mean > best[key][0]:
            best[key] = (mean, str(row["window"]), row["threshold"])
    return best


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="fiper evaluate output folders")
    parser.add_argument("--promises", default="0.08,0.1", help="comma list of promised false-alarm rates")
    args = parser.parse_args(argv)
    promises = [float(p) for p in args.promises.split(",")]
    for run in args.runs:
        results = json.loads((run / "results.json").read_text())
        deltas = [float(d) for d in results["settings"]["deltas"]]
        print(f"{run} ({', '.join(results['tasks'])})")
        for promise in promises:
            ranked = sorted(best_at_promise(results["sweep"], deltas, results["settings"]["combinations"],
                                                    promise).items(), key=lambda kv: -kv[1][0])
            print(f"  promise {promise:g}: " + "; ".join(f"{m} {c or '-'} {v:.3f} (w {w}, {k})" for (m, c), (v, w, k) in ranked))
    return 0


if __name__ == "__main__":
    sys.exit(main())
