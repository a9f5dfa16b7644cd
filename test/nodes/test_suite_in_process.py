"""The FIPER nodes in one process over real DDS (loopback): alarms equal the core's vectorised
prediction step for step, and bad input is rejected, reported and survived."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fiper_msgs.msg import FailureAlarm
from fiper_ros.core.calibration import load_calibration
from fiper_ros.core.monitor import predict_rollout
from helpers.suite import Suite
from helpers.synthetic import FAIL_FROM, make_rollout

STATE = {FailureAlarm.STATE_OK: "ok", FailureAlarm.STATE_ALARM: "alarm", FailureAlarm.STATE_UNKNOWN: "unknown"}


def _expected_states(prediction) -> list[str]:  # noqa: ANN001
    latched = np.logical_or.accumulate(prediction.alarms)
    return ["alarm" if a else "ok" for a in latched]


@pytest.mark.parametrize(("seed", "fail"), [(200, True), (201, False)])
def test_node_alarms_equal_the_vectorised_core(suite: Suite, calibration_dir: Path, seed: int, fail: bool) -> None:
    rollout = make_rollout(seed, fail=fail)
    prediction = predict_rollout(rollout, load_calibration(calibration_dir))
    alarms = suite.run(rollout, rollout_id=seed)
    states = [STATE[alarms[t].state] for t in range(rollout.length)]
    assert states == _expected_states(prediction)
    if fail:
        assert prediction.first_alarm_step == FAIL_FROM  # the scripted failure crosses both thresholds here
        first = alarms[FAIL_FROM]
        assert first.obs_exceeded and first.act_exceeded and first.latched and first.combine == "and"
    for t in range(rollout.length):
        assert alarms[t].eta_obs == pytest.approx(prediction.obs_windowed[t], rel=1e-6)
        assert alarms[t].eta_act == pytest.approx(prediction.act_windowed[t], rel=1e-6)
        assert alarms[t].gamma_obs == pytest.approx(prediction.obs_thresholds[t], rel=1e-6)


def test_start_resets_the_latch_and_the_windows(suite: Suite) -> None:
    failing = suite.run(make_rollout(300, fail=True), rollout_id=1)
    assert failing[FAIL_FROM].state == FailureAlarm.STATE_ALARM
    fine = suite.run(make_rollout(301), rollout_id=2)
    assert all(fine[t].state == FailureAlarm.STATE_OK for t in fine)


def test_reset_service_clears_a_latched_alarm(suite: Suite) -> None:
    from std_srvs.srv import Trigger  # noqa: PLC0415

    rollout = make_rollout(302, fail=True)
    suite.run(rollout, rollout_id=5, end=False)
    assert suite.fusion.fuser.latched
    client = suite.driver.create_client(Trigger, "/fiper/fusion_node/reset")
    assert suite.spin_until(client.service_is_ready)
    future = client.call_async(Trigger.Request())
    assert suite.spin_until(future.done)
    assert future.result().success and "cleared" in future.result().message
    assert not suite.fusion.fuser.latched


def test_inputs_that_overtake_their_start_wait_for_it(suite: Suite) -> None:
    rollout = make_rollout(303)
    drv = suite.driver
    drv.step(9, 0, rollout.embeddings[0], rollout.actions[0], rollout.exec_steps)  # before the START
    assert suite.spin_until(lambda: len(suite.rnd_oe.pending) == 1 and len(suite.ace.pending) == 1)
    drv.start(9)
    assert suite.spin_until(lambda: 0 in drv.alarms_of(9))
    assert drv.alarms_of(9)[0].state == FailureAlarm.STATE_OK
    assert suite.rnd_oe.rejected["unknown_rollout"] == 0
