#!/usr/bin/env python3
"""Check a calibration's promise (Prop. 1) on held-out rollouts, with the offline oracle.

    python tools/heldout.py CALIBRATION BAG_OR_DIR... [--urdf URDF] [--json OUT]

Every rollout of the bags is judged by the core (``fiper replay --offline``'s ``predict_bag``); the
report gives, per scenario, the false-alarm rate on its successes (an alarm at any step of a successful
rollout) beside ``delta`` and ``delta + 2 sigma`` (sigma = sqrt(delta (1 - delta) / n), the binomial spread
of n held-out successes), and the alarm rate on its failures (TPR). Rollouts used to fit or calibrate the
calibration must not be among the bags: the check is only meaningful on held-out rollouts.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

from fiper_ros.bags.errors import BagError
from fiper_ros.bags.offline import bag_layout, calibration_for, predict_bag
from fiper_ros.bags.reader import find_bags
from fiper_ros.bags.robot_options import add_arguments as add_robot_arguments
from fiper_ros.bags.robot_options import fk_of, robot_from


def tally(results: list[Any]) -> dict[str, dict[str, int]]:
    """scenario -> counts of successes, false alarms, failures, detected failures, rollouts with UNKNOWN."""
    counts: dict[str, dict[str, int]] = defaultdict(lambda: dict(successes=0, false_alarms=0, failures=0,
                                                                 detected=0, with_unknown=0))
    for result in results:
        row = counts[result.scenario or "?"]
        alarmed = result.first_alarm is not None
        if result.outcome == "success":
            row["successes"] += 1
            row["false_alarms"] += alarmed
        elif result.outcome == "failure":
            row["failures"] += 1
            row["detected"] += alarmed
        row["with_unknown"] += any(s.state == "unknown" for s in result.steps.values())
    return dict(counts)


def report(counts: dict[str, dict[str, int]], delta: float) -> list[str]:
    """Markdown table lines: one row per scenario."""
    lines = ["| scenario | successes | false alarms | rate | delta + 2 sigma | kept | failures | TPR | rollouts with UNKNOWN |",
             "| --- | ---: | ---: | ---: | ---: | --- | ---: | ---: | ---: |"]
    for scenario, row in sorted(counts.items()):
        n = row["successes"]
        rate = row["false_alarms"] / n if n else math.nan
        bound = delta + 2 * math.sqrt(delta * (1 - delta) / n) if n else math.nan
        kept = "" if not n else ("yes" if rate <= bound else "**no**")
        tpr = f"{row['detected'] / row['failures']:.2f}" if row["failures"] else ""
        lines.append(f"| {scenario} | {n} | {row['false_alarms']} | {rate:.3f} | {bound:.3f} | {kept} | "
                     f"{row['failures']} | {tpr} | {row['with_unknown']} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("calibration", type=Path)
    parser.add_argument("bags", type=Path, nargs="+")
    parser.add_argument("--json", type=Path, help="also write the counts per scenario as JSON")
    add_robot_arguments(parser)
    args = parser.parse_args(argv)
    try:
        bags = find_bags(args.bags)
        calibration = calibration_for(args.calibration, [bag_layout(bag) for bag in bags[:1]])
        fk = fk_of(robot_from(args))
        results = [r for bag in bags for r in predict_bag(bag, calibration, fk)]
    except BagError as error:
        print(f"heldout: {error}", file=sys.stderr)
        return 1
    counts = tally(results)
    delta = float(calibration.settings.delta)
    print(f"{args.calibration}: delta {delta:g}, {len(results)} rollouts in {len(bags)} bags")
    print("\n".join(report(counts, delta)))
    if args.json:
        args.json.write_text(json.dumps({"calibration": str(args.calibration), "delta": delta, "scenarios": counts},
                                        indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
