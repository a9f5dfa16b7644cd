"""``fiper replay --offline --ray``: one Ray task per bag on a local instance, the serial run's rows and report."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from fiper_ros.cli import main

pytestmark = pytest.mark.slow

BAGS = Path(__file__).resolve().parents[2] / "bags" / "sorting_sim" / "test_rollouts"


def test_ray_replays_every_bag_as_the_serial_run_does(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    outputs, reports = [], []
    for name, extra in (("serial", []), ("ray", ["--ray"])):
        report = tmp_path / f"{name}.json"
        assert main(["replay", "--offline", str(BAGS), "--report", str(report), *extra]) == 0
        captured = capsys.readouterr()
        outputs.append([line for line in captured.out.splitlines() if " steps in " not in line])  # not the timing
        reports.append({key: value for key, value in json.loads(report.read_text()).items() if key != "seconds"})
        if extra:
            assert captured.err.splitlines()[-1].startswith("fiper replay: 9/9 bags | ray: 9 done, 0 running")
    assert outputs[0] == outputs[1] and len(outputs[0]) > 9
    assert reports[0] == reports[1]


def test_ray_needs_offline(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(BAGS), "--ray"]) == 2
    assert capsys.readouterr().err == "fiper replay: --ray runs the offline replay as Ray tasks: it needs --offline\n"
