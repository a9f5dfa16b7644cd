#!/usr/bin/env python3
"""Check a calibration's promise (Prop. 1) on held-out rollouts, with the offline oracle.

    python tools/heldout.py CALIBRATION BAG_OR_DIR... [--urdf URDF] [--json OUT]

Every rollout of the bags is judged by the core (``fiper replay --offline``'s ``predict_bag``); the
report gives, per scenario, the false-alarm rate on its successes (an alarm at any step of a successful
rollout) beside the promised rate ``r`` (``delta``; ``2 delta`` with OR: ``core.calibration.promised_rate``)
and ``r + 2 sigma`` (sigma = sqrt(r (1 - r) / n), the binomial spread of n held-out successes), and the alarm rate on its failures (TPR), then the same over all scenarios.
Prop. 1 promises the rate only for successes from the calibration's distribution (``--id``, default the
``id`` scenario); other scenarios' rates are shown, not judged. Rollouts used to fit or calibrate the
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

from fiper_ros.bagio.reader import find_bags
from fiper_ros.commands.options import add_robot_arguments
from fiper_ros.commands.options import fk_of, robot_from
from fiper_ros.core.calibration import guarantee, promised_rate
from fiper_ros.errors import FiperError
from fiper_ros.evaluation.offline import bag_layout, calibration_for, predict_bag


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


def report(counts: dict[str, dict[str, int]], rate: float, promised: str) -> list[str]:
    """Markdown table lines: one row per scenario, then all of them."""
    lines = ["| scenario | successes | false alarms | rate | promise + 2 sigma | kept | failures | TPR | rollouts with UNKNOWN |",
             "| --- | ---: | ---: | ---: | ---: | --- | ---: | ---: | ---: |"]
    total = {key: sum(row[key] for row in counts.values()) for key in next(iter(counts.values()), {})}
    for scenario, row in [*sorted(counts.items()), ("all", total)]:
        n = row["successes"]
        observed = row["false_alarms"] / n if n else math.nan
        bound = rate + 2 * math.sqrt(rate * (1 - rate) / n) if n else math.nan
        kept = "" if not n or scenario != promised else ("yes" if observed <= bound else "**no**")
        tpr = f"{row['detected'] / row['failures']:.2f}" if row["failures"] else ""
        lines.append(f"| {scenario} | {n} | {row['false_alarms']} | {observed:.3f} | {bound:.3f} | {kept} | "
                     f"{row['failures']} | {tpr} | {row['with_unknown']} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("calibration", type=Path)
    parser.add_argument("bags", type=Path, nargs="+")
    parser.add_argument("--id", default="id", help="the scenario whose successes Prop. 1 covers (default id)")
    parser.add_argument("--json", type=Path, help="also write the counts per scenario as JSON")
    add_robot_arguments(parser)
    args = parser.parse_args(argv)
    try:
        bags = find_bags(args.bags)
        calibration = calibration_for(args.calibration, [bag_layout(bag) for bag in bags[:1]])
        fk = fk_of(robot_from(args))
        results = [r for bag in bags for r in predict_bag(bag, calibration, fk)]
    except FiperError as error:
        print(f"heldout: {error}", file=sys.stderr)
        return 1
    counts = tally(results)
    rate = promised_rate(calibration.settings)
    print(f"{args.calibration}: delta {calibration.settings.delta:g}, {calibration.settings.combine}, promise: "
          f"{guarantee(calibration.settings)}; {len(results)} rollouts in {len(bags)} bags")
    print("\n".join(report(counts, rate, args.id)))
    if args.json:
        args.json.write_text(json.dumps({"calibration": str(args.calibration), "promised_rate": rate, "scenarios": counts},
                                        indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
