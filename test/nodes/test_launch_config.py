"""A node of a launch file built in-process (``fiper launch --in-process``, ``fiper security``) gets what its
process would: the parameter files' entries for it (by its name or ``/**``), a file without one is no error, the
inline parameters after the files win, remaps, and the ``--log-level`` of ``ros_args``; a container's entry builds
each of its nodes."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
import rclpy
import rclpy.logging
import yaml
from helpers.launch import node_entry, write_launch
from rclpy.context import Context

from fiper_ros.launcher.config import LaunchError, load_launch
from fiper_ros.launcher.processes import build_node, build_nodes


def test_an_in_process_node_gets_its_parameter_file_entries_parameters_remaps_and_log_level(
        tmp_path: Path, ros_domain: int) -> None:
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {"deadline_floor_s": 0.2}},
                                      "/fiper/fusion_node": {"ros__parameters": {"heartbeat_s": 0.25,
                                                                                 "combine": "and"}}}))
    other = tmp_path / "other.yaml"
    other.write_text(yaml.safe_dump({"/elsewhere/node": {"ros__parameters": {"x": 1}}}))
    files = [{"from": str(params)}, {"from": str(other)}]
    config = load_launch(write_launch(
        tmp_path / "suite.launch.yaml",
        node_entry("fusion_node", ros_args="--log-level debug", remap=[{"from": "alarm", "to": "alarm_b"}],
                   param=[*files, {"name": "combine", "value": "or"}]),
        node_entry("supervisor_node", param=[*files, {"name": "use_sim_time", "value": True}])))
    fusion_spec, supervisor_spec = config.nodes
    context = Context()
    rclpy.init(context=context, domain_id=ros_domain)
    nodes = []
    try:
        nodes.append(build_node(fusion_spec, context))
        nodes.append(build_node(supervisor_spec, context))
        fusion, supervisor = nodes
        assert fusion.get_parameter("heartbeat_s").value == 0.25  # the file's entry for this node
        assert fusion.get_parameter("deadline_floor_s").value == 0.2  # the file's /** entry
        assert fusion.get_parameter("combine").value == "or"  # inline, after the file, wins
        assert "/fiper/alarm_b" in [p.topic_name for p in fusion.publishers]
        assert fusion.get_logger().get_effective_level() == rclpy.logging.LoggingSeverity.DEBUG
        assert supervisor.get_parameter("use_sim_time").value is True
        assert supervisor.get_fully_qualified_name() == "/fiper/supervisor_node"
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_an_in_process_container_entry_builds_each_of_its_nodes_with_their_own_names(
        tmp_path: Path, ros_domain: int) -> None:
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"/fiper/fusion_node": {"ros__parameters": {"heartbeat_s": 0.25}}}))
    config = load_launch(write_launch(tmp_path / "composed.launch.yaml", {"node": {
        "pkg": "fiper_ros", "exec": "container", "args": "rnd_oe_node fusion_node", "namespace": "/fiper",
        "ros_args": "--log-level debug",
        "param": [{"from": str(params)}, {"name": "calibration_dir", "value": "/nowhere"}]}}))
    (spec,) = config.nodes
    context = Context()
    rclpy.init(context=context, domain_id=ros_domain)
    nodes = []
    try:
        nodes = build_nodes(spec, context)
        assert [node.get_fully_qualified_name() for node in nodes] == ["/fiper/rnd_oe_node", "/fiper/fusion_node"]
        rnd_oe, fusion = nodes
        assert rnd_oe.get_parameter("calibration_dir").value == fusion.get_parameter("calibration_dir").value \
            == "/nowhere"  # a name/value entry of the container: keyed /**, every node's
        assert fusion.get_parameter("heartbeat_s").value == 0.25  # the file's entry for this node only
        assert all(node.get_logger().get_effective_level() == rclpy.logging.LoggingSeverity.DEBUG for node in nodes)
        with pytest.raises(LaunchError, match="node container: unknown node 'policy_node'"):
            build_nodes(replace(spec, arguments=("policy_node",)), context)
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)
