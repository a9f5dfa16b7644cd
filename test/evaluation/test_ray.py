"""``fiper evaluate --ray``: the scores and the sweep as Ray tasks on a local instance (2 CPUs), the single-process
run's results."""
from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from fiper_ros.cli import main
from fiper_ros.cluster import LOCAL
from fiper_ros.evaluation.data import Dataset, DatasetError
from fiper_ros.evaluation.engine import EngineSettings, score_all
from fiper_ros.evaluation.methods import MethodSettings

pytestmark = pytest.mark.slow

#: A tiny synthetic evaluation of two tasks and two seeds: 36 streams to score, 32 Ray tasks (the 4 that fit nothing
#: are read back from the cache for seed 1, as in the serial run).
ARGV = ["evaluate", "--synthetic", "sorting,push_t", "--synthetic-scale", "0.25", "--synthetic-test", "16", "--tiny",
        "--windows", "1-4", "--default-window", "2", "--deltas", "0.1,0.2", "--seeds", "0,1", "--no-plots"]


def _results(out: Path) -> dict[str, Any]:
    """results.json without its wall times (``timings_s``, the one key a Ray run changes)."""
    document = json.loads((out / "results.json").read_text())
    del document["timings_s"]
    return document


def _ray_running() -> bool:
    """Whether this process is still connected to a Ray instance (``ray`` is not imported here: importing it before
    :func:`fiper_ros.cluster.connected` would bind the local instance off loopback)."""
    ray = sys.modules.get("ray")
    return ray is not None and ray.is_initialized()


def test_ray_writes_the_single_process_results_and_cache(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    serial_run = ["--quiet", "--out", str(tmp_path / "serial"), "--cache-dir", str(tmp_path / "serial_cache"),
                  "--dump", str(tmp_path / "serial_dump")]
    assert main([*ARGV, *serial_run]) == 0
    capsys.readouterr()
    assert main([*ARGV, "--out", str(tmp_path / "ray"), "--cache-dir", str(tmp_path / "ray_cache"), "--ray",
                 "--ray-cpus", "2", "--dump", str(tmp_path / "ray_dump")]) == 0
    captured = capsys.readouterr()
    assert "scores [####################] 4/4" in captured.err and "| ray: 32 done, 0 running, 0 queued" in captured.err
    assert "sweep [####################] 4/4" in captured.err and "| ray: 2 done, 0 running, 0 queued" in captured.err
    assert "(cache 4 hit(s), 32 miss(es))" in captured.out  # the serial run's counts
    serial, distributed = _results(tmp_path / "serial"), _results(tmp_path / "ray")
    assert serial["score_cache"] == {"hits": 4, "misses": 32}
    assert distributed == serial
    assert (tmp_path / "ray" / "results.md").read_text() == (tmp_path / "serial" / "results.md").read_text()
    # the sweep's thresholds and first alarms, fitted in the seeds' Ray tasks: the same bytes
    dumped = sorted(p.name for p in (tmp_path / "serial_dump").iterdir())
    assert dumped == sorted(p.name for p in (tmp_path / "ray_dump").iterdir()) and "index.json" in dumped
    for name in dumped:
        assert (tmp_path / "ray_dump" / name).read_bytes() == (tmp_path / "serial_dump" / name).read_bytes(), name
    assert sorted(p.name for p in (tmp_path / "ray_cache").iterdir()) == \
        sorted(p.name for p in (tmp_path / "serial_cache").iterdir())
    assert not _ray_running()  # the local instance is stopped
    # a run the cache serves computes no score on the cluster, only the sweep (one task per seed), to the same results
    assert main([*ARGV, "--out", str(tmp_path / "ray_cached"), "--cache-dir", str(tmp_path / "ray_cache"), "--ray"]) == 0
    captured = capsys.readouterr()
    assert "(cache 36 hit(s), 0 miss(es))" in captured.out
    assert "push_t seed 1 (cached)" in captured.err and captured.err.count("| ray: ") == captured.err.count("sweep [")
    assert {k: v for k, v in _results(tmp_path / "ray_cached").items() if k != "score_cache"} == \
        {k: v for k, v in serial.items() if k != "score_cache"}
    assert not _ray_running()
    # the cache written under Ray serves a single-process run to the same results
    assert main([*ARGV, "--quiet", "--out", str(tmp_path / "cached"), "--cache-dir", str(tmp_path / "ray_cache")]) == 0
    assert "(cache 36 hit(s), 0 miss(es))" in capsys.readouterr().out
    assert {k: v for k, v in _results(tmp_path / "cached").items() if k != "score_cache"} == \
        {k: v for k, v in serial.items() if k != "score_cache"}


def test_a_data_error_in_a_ray_task_is_the_single_process_error(tiny_dataset: Dataset,
                                                                 tiny_settings: MethodSettings) -> None:
    # joint-space actions without a robot model: ACE's fit stops in the task (check_evaluation, skipped here, would
    # refuse it before any work)
    joint = Dataset(tiny_dataset.task, [replace(r, action_space="joint_position") for r in tiny_dataset.calibration],
                    [replace(r, action_space="joint_position") for r in tiny_dataset.test])
    settings = EngineSettings(methods=("elapsed", "ace"), method_settings=tiny_settings, progress=False)
    with pytest.raises(DatasetError) as serial:
        score_all([joint], settings, None)
    with pytest.raises(DatasetError) as distributed:
        score_all([joint], settings, None, LOCAL, 2)
    assert str(distributed.value) == str(serial.value)
    assert str(serial.value).startswith("task 'sorting' has joint_position actions: ACE needs the robot's URDF")
    assert not _ray_running()


@pytest.mark.parametrize(("extra", "message"), [
    (["--ray-cpus", "2"], "--ray-cpus sets the CPUs of the local Ray instance of --ray: give --ray too"),
    (["--ray", "auto", "--ray-cpus", "2"],
     "--ray-cpus sets the CPUs of a local Ray instance: the cluster at auto has its own"),
    (["--ray", "--ray-cpus", "0"], "--ray-cpus must be >= 1, got 0"),
])
def test_ray_options_are_checked_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str],
                                             message: str) -> None:
    assert main([*ARGV, "--no-cache", "--out", str(tmp_path / "out"), *extra]) == 2
    assert capsys.readouterr().err == f"fiper evaluate: {message}\n"
