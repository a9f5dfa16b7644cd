"""The nodes report their DDS matches on /diagnostics, and missing_matches reads them (real DDS)."""
from __future__ import annotations

from collections import Counter
from pathlib import Path

from rclpy.parameter import Parameter

from fiper_ros.runtime.wiring import missing_matches
from helpers.suite import Suite

NODES = ("/fiper/rnd_oe_node", "/fiper/ace_node", "/fiper/fusion_node")


def test_nodes_report_matches_and_the_suite_is_wired(ros_domain: int, calibration_dir: Path) -> None:
    suite = Suite(ros_domain, str(calibration_dir), extra=[Parameter("diagnostics_period_s", value=0.1)],
                  fusion=[Parameter("diagnostics_period_s", value=0.1)])
    try:
        suite.wait_active()
        by_node = {}

        def wired() -> bool:
            by_node.clear()
            by_node.update({n: suite.driver.diagnostics.get(f"fiper: {n}", {}) for n in NODES})
            own = Counter(s.topic_name for s in suite.driver.subscriptions)
            return all(by_node.values()) and not missing_matches(by_node, NODES, own)

        assert suite.spin_until(wired), missing_matches(by_node, NODES, {})
        rnd_oe, fusion = by_node["/fiper/rnd_oe_node"], by_node["/fiper/fusion_node"]
        assert int(rnd_oe["matched_publishers./fiper/observation_embedding"]) == 1  # the test driver
        # the fusion node and the test driver read the scores
        assert int(rnd_oe["matched_subscribers./fiper/scores/rnd_oe"]) == 2
        assert int(fusion["matched_publishers./fiper/scores/ace"]) == 1
        assert not any(key.startswith(("matched_subscribers./rosout", "matched_publishers./parameter_events"))
                       for key in rnd_oe)
        # a reader that goes away is no longer matched: the publisher's count drops
        suite.executor.remove_node(suite.fusion)
        suite.fusion.destroy_node()
        suite.nodes.remove(suite.fusion)
        assert suite.spin_until(lambda: suite.driver.diagnostics["fiper: /fiper/rnd_oe_node"]
                                ["matched_subscribers./fiper/scores/rnd_oe"] == "1")
    finally:
        suite.close()
