"""A node whose parameters do not fit its calibration, over real DDS (loopback): the fusion node asked for a combine
the calibration was not calibrated for refuses in configure with a user error (``NodeError``), stays alive and
UNCONFIGURED, counts every failed attempt (``configure_failures``, retried every ``configure_retry_s``) and says why in
one line at level ERROR on /diagnostics."""
from __future__ import annotations

from pathlib import Path

import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter

from fiper_ros.nodes.errors import NodeError
from helpers.spin import spin_until
from helpers.suite import PolicySideNode
from helpers.synthetic import make_calibration

FAST = [Parameter("diagnostics_period_s", value=0.1), Parameter("configure_retry_s", value=0.2)]


def test_a_combine_the_calibration_lacks_fails_configure_in_one_line(ros_domain: int, tmp_path: Path) -> None:
    from fiper_ros.nodes.fusion_node import FusionNode

    directory = make_calibration(tmp_path / "calibration")  # combine "and"
    context = Context()
    rclpy.init(context=context, domain_id=ros_domain)
    executor = SingleThreadedExecutor(context=context)
    fusion = FusionNode(context=context, namespace="/fiper", parameter_overrides=[
        Parameter("calibration_dir", value=str(directory)), Parameter("combine", value="or"), *FAST])
    driver = PolicySideNode(context)
    for node in (fusion, driver):
        executor.add_node(node)
    expected = (f"configure failed: parameter combine is 'or', but calibration {directory} was calibrated for 'and': "
                "set combine 'calibration', or calibrate for it")
    try:
        def status() -> dict[str, str]:
            return driver.diagnostics.get("fiper: /fiper/fusion_node", {})

        # two failed attempts said: the first at start-up, one retry (the node lives on, UNCONFIGURED)
        assert spin_until(executor, lambda: int(status().get("configure_failures", "0")) >= 2, 20.0), status()
        said = status()
        assert (said["message"], said["level"], said["lifecycle_state"]) == (expected, "2", "unconfigured")
        assert fusion.lifecycle_state() == "unconfigured" and fusion.config_error == expected
        with pytest.raises(NodeError, match="^parameter combine is 'or', but calibration "):
            fusion.configure()
    finally:
        for node in (fusion, driver):
            executor.remove_node(node)
            node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown(context=context)
