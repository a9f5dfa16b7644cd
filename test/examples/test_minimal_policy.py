"""The example policy (``python -m fiper_ros.examples.minimal_policy``, issue #25) started at the same moment as the
suite (``fiper launch fiper.launch.yaml calibration_dir:=...``), both cold: it waits for the suite's scoring nodes
(``FiperPublisher.wait_for_suite``) and then publishes at once; every step of every rollout gets its verdict, the
first rollout's first steps included (published before the suite matched, they would be lost: the inputs are
VOLATILE). The test's alarm listener is named in ``--wait-for`` (helpers/alarms.py): the alarm is KEEP_LAST(1) at the
fusion node, and a listener the example does not wait for missed the first rollout's verdicts under load.

That every step was judged is read from the fusion node's own account (its END line per rollout: every step fused,
none missing), not from the listener hearing every step's verdict: the alarm writer keeps the latest state only
(RELIABLE KEEP_LAST(1)), so a verdict a busy reader has not acknowledged yet can be replaced by the next one. What
the listener did hear must never be UNKNOWN."""
from __future__ import annotations

import os
import re
from pathlib import Path

import pytest
from helpers.alarms import AlarmListener
from helpers.dds import spawn_python, stop
from helpers.example_policy import STEPS, example_calibration
from helpers.launch import Launch

from fiper_msgs.msg import FailureAlarm
from fiper_ros.examples.minimal_policy import failing_rollouts

LAUNCH = Path(os.environ["FIPER_ROOT"]) / "fiper_ros" / "launch" / "fiper.launch.yaml"
ROLLOUTS, FAILURES = 3, 1


@pytest.mark.slow
def test_the_example_started_with_the_suite_loses_no_step(tmp_path: Path, ros_domain: int) -> None:
    calibration = example_calibration(tmp_path / "calibration")
    listener = AlarmListener(ros_domain)
    launch = Launch(LAUNCH, ros_domain, {"calibration_dir": str(calibration)})
    # The test's own listener must hear the fusion node before the policy starts, or it misses verdicts the suite
    # gave (its discovery took seconds under load in a full run: rollout 1's verdicts all unheard); the policy
    # still starts cold against scoring nodes that have not matched its publishers.
    assert listener.spin_until(lambda: bool(listener.alarms), 180), launch.lines[-30:]
    policy = spawn_python(["-m", "fiper_ros.examples.minimal_policy", "--rollouts", str(ROLLOUTS), "--failures",
                           str(FAILURES), "--seed", "0", "--wait", "240", "--wait-for", "suite", "/test_alarms"],
                          ros_domain)
    try:
        # spun meanwhile: the listener reports its match, which the example waits for (see helpers/alarms.py)
        assert listener.spin_until(lambda: policy.poll() is not None, 300), "the example did not finish"
        output, _ = policy.communicate(timeout=30)
        assert policy.returncode == 0, output + "\n".join(launch.lines[-30:])
        ids = [int(i) for i in re.findall(rf"rollout (\d+): {STEPS} steps", output)]
        assert len(ids) == ROLLOUTS, output

        def summarised() -> bool:
            return all(any(f"fusion: rollout {i} " in line for line in launch.lines) for i in ids)

        assert listener.spin_until(summarised, 60), [line for line in launch.lines if ": rollout " in line]
    finally:
        stop(policy)
        launch.interrupt()
        listener.close()
    assert "waiting for suite" in output
    summaries = {i: next(line for line in launch.lines if f"fusion: rollout {i} " in line) for i in ids}
    heard = listener.verdicts()
    for index, rollout_id in enumerate(ids):
        summary = summaries[rollout_id]
        assert f": {STEPS} steps, 0 missing, " in summary, summary
        if index in failing_rollouts(ROLLOUTS, FAILURES):
            assert "alarm step none" not in summary, summary
        assert heard.get(rollout_id), (index, "no verdict of the rollout heard")
        unknown = [(t, m.reason) for t, m in sorted(heard[rollout_id].items()) if m.state == FailureAlarm.STATE_UNKNOWN]
        assert not unknown, (index, unknown)
