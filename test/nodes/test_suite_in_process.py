"""The FIPER nodes in one process over real DDS (loopback): alarms equal the core's vectorised
prediction step for step, and bad input is rejected, reported and survived."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fiper_msgs.msg import FailureAlarm
from fiper_ros.core.calibration import load_calibration
from fiper_ros.core.monitor import predict_rollout
from helpers.suite import STATE, Suite
from helpers.synthetic import FAIL_FROM, make_calibration, make_rollout


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
        assert alarms[t].eta_obs == pytest.approx(prediction.detectors["rnd_oe"].windowed[t], rel=1e-6)
        assert alarms[t].eta_act == pytest.approx(prediction.detectors["ace"].windowed[t], rel=1e-6)
        assert alarms[t].gamma_obs == pytest.approx(prediction.detectors["rnd_oe"].thresholds[t], rel=1e-6)


def test_start_resets_the_latch_and_the_windows(suite: Suite) -> None:
    failing = suite.run(make_rollout(300, fail=True), rollout_id=1)
    assert failing[FAIL_FROM].state == FailureAlarm.STATE_ALARM
    fine = suite.run(make_rollout(301), rollout_id=2)
    assert all(fine[t].state == FailureAlarm.STATE_OK for t in fine)


def test_inputs_that_overtake_their_start_wait_for_it(suite: Suite) -> None:
    rollout = make_rollout(303)
    drv = suite.driver
    drv.step(9, 0, rollout.embeddings[0], rollout.actions[0], rollout.exec_steps)  # before the START
    assert suite.spin_until(lambda: len(suite.rnd_oe.gate.waiting) == 1 and len(suite.ace.gate.waiting) == 1)
    drv.start(9)
    assert suite.spin_until(lambda: 0 in drv.alarms_of(9))
    assert drv.alarms_of(9)[0].state == FailureAlarm.STATE_OK
    assert suite.rnd_oe.rejected["unknown_rollout"] == 0


def test_a_cp_band_calibration_over_dds_equals_the_vectorised_core(ros_domain: int, tmp_path: Path) -> None:
    # The paper's default threshold (App. A.3): gamma_t = mu(t) + k s(t), different at every step. With
    # M2 = 6 band scores, delta = 0.2 is the smallest round level with a finite k (ceil(7 * 0.8) = 6).
    directory = make_calibration(tmp_path / "cp_band", threshold="cp_band", delta=0.2)
    calibration = load_calibration(directory)
    assert calibration.threshold("rnd_oe").kind == "cp_band" and np.isfinite(calibration.threshold("rnd_oe").values).all()
    assert len(set(calibration.threshold("rnd_oe").values[:LENGTH_CHECKED])) > 1, "a band varies over t"
    suite = Suite(ros_domain, str(directory))
    try:
        suite.wait_active()
        for rollout_id, rollout in ((1, make_rollout(210, fail=True)), (2, make_rollout(211))):
            prediction = predict_rollout(rollout, calibration)
            alarms = suite.run(rollout, rollout_id=rollout_id)
            assert [STATE[alarms[t].state] for t in range(rollout.length)] == _expected_states(prediction)
            for t in range(rollout.length):
                assert alarms[t].gamma_obs == np.float32(prediction.detectors["rnd_oe"].thresholds[t])
                assert alarms[t].gamma_act == np.float32(prediction.detectors["ace"].thresholds[t])
            assert (prediction.first_alarm_step is not None) == (rollout_id == 1)
    finally:
        suite.close()


#: Steps over which the band's values are compared (the synthetic rollouts' length).
LENGTH_CHECKED = 20


def test_a_repeated_start_keeps_the_latch_and_the_windows(suite: Suite, calibration_dir: Path) -> None:
    rollout = make_rollout(304, fail=True)
    prediction = predict_rollout(rollout, load_calibration(calibration_dir))
    drv = suite.driver
    drv.start(7)
    assert suite.spin_until(lambda: suite.fusion.fuser.rollout_id == 7)
    half = FAIL_FROM + 2
    for step in range(half):
        drv.step(7, step, rollout.embeddings[step], rollout.actions[step], rollout.exec_steps)
        assert suite.spin_until(lambda s=step: s in drv.alarms_of(7)), step
    assert drv.alarms_of(7)[FAIL_FROM].state == FailureAlarm.STATE_ALARM
    events = suite.rnd_oe.gate.active
    drv.start(7)  # the START again (a restarted policy node, a replayed event): nothing is reset
    assert suite.spin_until(lambda: (suite.rnd_oe.gate.repeated_starts, suite.ace.gate.repeated_starts,
                                     suite.fusion.fuser.gate.repeated_starts) == (1, 1, 1))  # each node has seen it
    assert suite.rnd_oe.gate.active is events and suite.fusion.fuser.latched
    for step in range(half, rollout.length):
        drv.step(7, step, rollout.embeddings[step], rollout.actions[step], rollout.exec_steps)
        assert suite.spin_until(lambda s=step: s in drv.alarms_of(7)), step
    alarms = drv.alarms_of(7)
    assert all(alarms[t].state == FailureAlarm.STATE_ALARM and alarms[t].latched for t in range(FAIL_FROM, rollout.length))
    for t in range(half, rollout.length):  # the windows went on where they were: the same numbers as offline
        assert alarms[t].eta_obs == np.float32(prediction.detectors["rnd_oe"].windowed[t])
        assert alarms[t].eta_act == np.float32(prediction.detectors["ace"].windowed[t])


def test_a_rollout_started_again_after_its_end_is_judged_afresh(suite: Suite) -> None:
    # Found by test/nodes/test_fuzz.py: the fusion node took a START of the rollout id that had just ended for a
    # repeated START and ignored it, while the scoring nodes began the rollout again from step 0. The new run was
    # then judged with the old one's latch and step bookkeeping: all ALARM after a failed run, and OK after a gap
    # of steps the new run never had judged (the old run had judged them).
    drv = suite.driver
    failing = make_rollout(307, fail=True)
    assert suite.run(failing, rollout_id=13)[FAIL_FROM].state == FailureAlarm.STATE_ALARM  # ends with END
    drv.start(13)
    assert suite.spin_until(lambda: suite.rnd_oe.gate.active is not None and suite.ace.gate.active is not None
                            and (suite.fusion.fuser.active_rollout == 13 or suite.fusion.fuser.gate.repeated_starts == 1))
    fine = make_rollout(308)
    steps = [0, 1, 5, 6, 7, 8]  # steps 2-4 never come
    for step in steps:
        drv.step(13, step, fine.embeddings[step], fine.actions[step], fine.exec_steps)
        assert suite.spin_until(lambda s=step: sum(m.step == s for m in drv.alarms if m.rollout_id == 13
                                                   and not m.heartbeat) == 2), step  # this run's verdict too
    again = {m.step: m for m in drv.alarms if m.rollout_id == 13 and not m.heartbeat}  # the later verdict per step
    assert [again[t].state for t in (0, 1)] == [FailureAlarm.STATE_OK] * 2, [again[t].reason for t in (0, 1)]
    assert [again[t].state for t in steps[2:]] == [FailureAlarm.STATE_UNKNOWN] * 4, [again[t].reason for t in steps]
    assert suite.fusion.fuser.gate.repeated_starts == 0


def test_after_the_end_of_a_latched_rollout_the_heartbeat_names_it(suite: Suite) -> None:
    suite.run(make_rollout(305, fail=True), rollout_id=11)  # ends with END
    assert suite.fusion.fuser.active_rollout is None
    count = len(suite.driver.alarms)
    assert suite.spin_until(lambda: any(m.heartbeat for m in suite.driver.alarms[count:]), timeout=5.0)
    beats = [m for m in suite.driver.alarms[count:] if m.heartbeat]
    # the old heartbeat said rollout 0, "no active rollout", with state ALARM: an alarm of no rollout
    assert all(m.rollout_id == 11 and m.state == FailureAlarm.STATE_ALARM and m.latched for m in beats), beats[0]


def test_the_last_step_of_a_rollout_is_judged_even_when_its_end_overtakes_it(suite: Suite) -> None:
    # The bridge's END and the policy's last step travel on different topics; a busy node can take the END
    # first (the demo's CI run of this session: "26 policy steps, only 25 scored"). The step is judged anyway.
    rollout = make_rollout(306)
    drv = suite.driver
    drv.start(12)
    assert suite.spin_until(lambda: suite.fusion.fuser.rollout_id == 12)
    last = rollout.length - 1
    for step in range(last):
        drv.step(12, step, rollout.embeddings[step], rollout.actions[step], rollout.exec_steps)
        assert suite.spin_until(lambda s=step: s in drv.alarms_of(12)), step
    drv.end(12, True)
    assert suite.spin_until(lambda: suite.rnd_oe.gate.active is None and suite.ace.gate.active is None
                            and suite.fusion.fuser.active_rollout is None)  # every node took the END
    drv.step(12, last, rollout.embeddings[last], rollout.actions[last], rollout.exec_steps)
    assert suite.spin_until(lambda: last in drv.alarms_of(12)), "the overtaken step got no verdict"
    assert drv.alarms_of(12)[last].state == FailureAlarm.STATE_OK
    assert suite.rnd_oe.rejected["unknown_rollout"] == suite.ace.rejected["unknown_rollout"] == 0


def test_a_rollout_of_another_task_than_the_calibrations_is_never_judged_ok(suite: Suite) -> None:
    from fiper_msgs.msg import RolloutEvent
    from fiper_ros.interface.conversions import rollout_event_msg

    assert load_calibration(suite.rnd_oe.get_parameter("calibration_dir").value).named_tasks == ("synthetic",)
    rollout = make_rollout(307)
    drv = suite.driver
    drv.events.publish(rollout_event_msg(13, RolloutEvent.EVENT_START, 0, task="pusht"))
    assert suite.spin_until(lambda: suite.fusion.fuser.rollout_id == 13)
    for step in range(3):
        drv.step(13, step, rollout.embeddings[step], rollout.actions[step], rollout.exec_steps)
        assert suite.spin_until(lambda s=step: s in drv.alarms_of(13)), step
    assert all(m.state == FailureAlarm.STATE_UNKNOWN for m in drv.alarms_of(13).values())
    assert suite.rnd_oe.rejected["task_mismatch"] == suite.ace.rejected["task_mismatch"] == 3
