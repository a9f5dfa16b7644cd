"""The nodes on an observation-only calibration, in one process over real DDS (loopback; issue #19): the policy
publishes embeddings only, the fusion node (reading the calibration's declared detectors) judges every step
by RND-OE alone at once, never waits for ACE scores nor reports that stream missing, and says the core's
verdict, also while a node it does not know publishes on scores/ace (a topic it reads nothing from); an
ace_node given that calibration stays unconfigured and says why in one line."""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import rclpy
import rclpy.node
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter

from fiper_msgs.msg import Score
from fiper_ros.core.calibration import load_calibration
from fiper_ros.core.detectors import OBSERVATION_ONLY
from fiper_ros.core.monitor import predict_rollout
from fiper_ros.interface import qos
from fiper_ros.interface.conversions import embedding_msg
from fiper_ros.runtime.alarm import ratio_text
from helpers.spin import spin_until
from helpers.suite import STATE, STEP_NS, PolicySideNode
from helpers.synthetic import FAIL_FROM, make_calibration, make_rollout

FAST = [Parameter("diagnostics_period_s", value=0.1), Parameter("configure_retry_s", value=0.5)]


def test_the_fusion_node_judges_rnd_oe_alone(ros_domain: int, tmp_path: Path) -> None:
    from fiper_ros.nodes.ace_node import AceNode
    from fiper_ros.nodes.fusion_node import FusionNode
    from fiper_ros.nodes.rnd_oe_node import RndOeNode

    directory = make_calibration(tmp_path / "calibration", detectors=OBSERVATION_ONLY)
    calibration = load_calibration(directory)
    context = Context()
    rclpy.init(context=context, domain_id=ros_domain)
    executor = SingleThreadedExecutor(context=context)
    params = [Parameter("calibration_dir", value=str(directory)), *FAST]
    nodes = [RndOeNode(context=context, namespace="/fiper", parameter_overrides=params),
             FusionNode(context=context, namespace="/fiper", parameter_overrides=params),
             AceNode(context=context, namespace="/fiper", parameter_overrides=params)]
    driver = PolicySideNode(context)
    # A node the suite does not know publishes on scores/ace: an observation-only fusion reads nothing there.
    intruder = rclpy.node.Node("intruder", context=context)
    intruder.create_publisher(Score, "/fiper/scores/ace", qos.SCORE_PUB)
    for node in [*nodes, driver, intruder]:
        executor.add_node(node)
    rnd_oe, fusion, ace = nodes
    try:
        def status(name: str) -> dict[str, str]:
            return driver.diagnostics.get(f"fiper: /fiper/{name}", {})

        assert spin_until(executor, lambda: rnd_oe.lifecycle_state() == fusion.lifecycle_state() == "active"
                          and status("ace_node").get("message", "").startswith("configure failed"), 20.0)
        assert status("ace_node")["message"] == (
            f"configure failed: calibration {directory} declares rnd_oe, not ace: nothing for ace_node to score; launch "
            "the suite of its detectors (fiper.launch.yaml)")
        assert ace.lifecycle_state() == "unconfigured" and fusion.fuser.detectors == OBSERVATION_ONLY
        assert int(status("ace_node")["configure_failures"]) >= 1 and status("ace_node")["level"] == "2"
        assert spin_until(executor, lambda: "intruder" in [i.node_name for i in
                                                          driver.get_publishers_info_by_topic("/fiper/scores/ace")])
        assert spin_until(executor, lambda: driver.embeddings.get_subscription_count() >= 1
                          and driver.events.get_subscription_count() >= 3)
        for rollout_id, fail in ((1, True), (2, False)):
            rollout = make_rollout(400 + rollout_id, fail=fail)
            prediction = predict_rollout(rollout, calibration)
            driver.start(rollout_id)
            assert spin_until(executor, lambda r=rollout_id: fusion.fuser.active_rollout == r)
            for step in range(rollout.length):  # at 10 Hz: a missing ACE stream would turn stale within 0.25 s
                began = time.monotonic()
                driver.embeddings.publish(embedding_msg(rollout_id, step, (step + 1) * STEP_NS, rollout.embeddings[step]))
                assert spin_until(executor, lambda s=step, r=rollout_id: s in driver.alarms_of(r)), step
                spin_until(executor, lambda: False, max(0.0, STEP_NS / 1e9 - (time.monotonic() - began)))
            driver.end(rollout_id, not fail)
            alarms = driver.alarms_of(rollout_id)
            latched = np.logical_or.accumulate(prediction.alarms)
            assert [STATE[alarms[t].state] for t in range(rollout.length)] == \
                ["alarm" if a else "ok" for a in latched]
            for t, msg in alarms.items():
                assert (msg.obs_exceeded, msg.act_exceeded, msg.combine) == (prediction.detectors["rnd_oe"].exceeded[t], False, "")
                assert (msg.eta_obs, msg.gamma_obs) == (np.float32(prediction.detectors["rnd_oe"].windowed[t]),
                                                        np.float32(prediction.detectors["rnd_oe"].thresholds[t]))
                assert math.isnan(msg.eta_act) and math.isnan(msg.gamma_act)
            assert (prediction.first_alarm_step is not None) == fail
            if fail:
                first = prediction.first_alarm_step
                since = first  # the first step of RND-OE's unbroken run of exceedances up to the alarm
                while since > 0 and prediction.detectors["rnd_oe"].exceeded[since - 1]:
                    since -= 1
                ratio = ratio_text(float(np.float32(prediction.detectors["rnd_oe"].windowed[first])),
                                   float(np.float32(prediction.detectors["rnd_oe"].thresholds[first])))
                assert alarms[first].reason == \
                    f"RND-OE {ratio} threshold since step {since}: exceeded (rnd_oe alone: combine does not apply)"
                assert first >= FAIL_FROM
        assert fusion.fuser.suspicion == "" and fusion.publisher_check.watch.findings == ()
        said = [m.reason for m in driver.alarms]  # verdicts and heartbeats: not a word about ACE
        assert len(said) >= 2 * 20 and not [r for r in said if "ace" in r], [r for r in said if "ace" in r][:3]
        driver.diagnostics.pop("fiper: /fiper/fusion_node", None)
        assert spin_until(executor, lambda: "detectors" in status("fusion_node"))
        assert (status("fusion_node")["detectors"], status("fusion_node")["lost_streams"]) == ("rnd_oe", "none")
    finally:
        for node in [*nodes, driver, intruder]:
            executor.remove_node(node)
            node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown(context=context)
