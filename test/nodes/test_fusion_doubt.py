"""The fusion node's ``scores_in_doubt`` says whether the scores can be attributed to the suite now, or could not
during the running rollout; an ended rollout's doubt is not reported (it kept a respawned fusion node's report from
ever saying ``no`` before the next START: ``test_faults[fusion_node]`` waited for it in vain)."""
from __future__ import annotations

import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter

from fiper_ros.nodes.fusion_node import FusionNode
from fiper_ros.runtime.alarm import DetectorScore

REASON = "/fiper/scores/rnd_oe: 1 publisher(s) of a node the graph does not name yet"


def test_an_ended_rollouts_doubt_is_not_reported_but_a_running_ones_is(ros_domain: int) -> None:
    context = Context()
    rclpy.init(context=context, domain_id=ros_domain)
    node = FusionNode(context=context, namespace="/fiper", parameter_overrides=[Parameter("autostart", value=False)])
    try:
        node.trigger_configure()
        fuser = node.fuser
        fuser.start(2, 0)
        fuser.suspect(REASON)  # a respawned fusion node: its graph does not name the scorer yet
        fuser.add(DetectorScore("rnd_oe", 2, 0, 0.1, 1.0, 0), 1)  # taken in doubt: rollout 2 is tainted
        fuser.suspect("")  # the graph names it now
        assert fuser.tainted == REASON
        assert node.diagnostic_values()["scores_in_doubt"] == REASON  # rollout 2 still runs: doubted
        fuser.end(2)
        assert fuser.tainted == REASON  # its late steps stay doubted
        assert node.diagnostic_values()["scores_in_doubt"] == "no"  # nothing in doubt about the suite now
        fuser.suspect(REASON)
        assert node.diagnostic_values()["scores_in_doubt"] == REASON  # doubt now is always reported
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
