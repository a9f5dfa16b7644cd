"""tools/heldout.py: the held-out false-alarm check of a calibration, by hand."""
from __future__ import annotations

import importlib.util
import math
from pathlib import Path

from helpers.states import ALARM, OK, UNKNOWN

from fiper_ros.evaluation.results import RolloutResult, StepResult


ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("heldout", ROOT / "tools" / "heldout.py")
assert _spec is not None and _spec.loader is not None
heldout = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(heldout)


def rollout(scenario: str, outcome: str, states: list[str]) -> RolloutResult:
    steps = {t: StepResult(s, (False, False), (0.0, 0.0)) for t, s in enumerate(states)}
    return RolloutResult(1, "sorting", scenario, outcome, steps)


def test_counts_and_the_promise_by_hand() -> None:
    results = [rollout("id", "success", [OK, OK]), rollout("id", "success", [OK, ALARM]),
               rollout("id", "success", [OK, UNKNOWN]), rollout("id", "failure", [ALARM]),
               rollout("id", "failure", [OK]), rollout("lighting", "success", [ALARM])]
    counts = heldout.tally(results)
    assert counts["id"] == dict(successes=3, false_alarms=1, failures=2, detected=1, with_unknown=1)
    assert counts["lighting"] == dict(successes=1, false_alarms=1, failures=0, detected=0, with_unknown=0)
    lines = heldout.report(counts, 0.05, "id")
    bound = 0.05 + 2 * math.sqrt(0.05 * 0.95 / 3)  # 0.302: 1 of 3 (0.333) is above it
    assert lines[2] == f"| id | 3 | 1 | 0.333 | {bound:.3f} | **no** | 2 | 0.50 | 1 |"
    assert lines[3] == "| lighting | 1 | 1 | 1.000 | 0.486 |  | 0 |  | 0 |"  # not judged: not the promised scenario
    assert lines[4].startswith("| all | 4 | 2 | 0.500 |")
