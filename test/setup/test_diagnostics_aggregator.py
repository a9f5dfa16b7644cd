"""fiper_ros/config/diagnostics_aggregator.yaml (#21): the status every node of the suite publishes on /diagnostics
is matched by exactly one analyzer under /FIPER, also with a remapped namespace; other statuses are left alone."""
from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from ament_index_python.packages import get_package_share_directory
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from helpers.aggregator import CONFIG, analyzers_of
from helpers.fuzz import private_context
from rclpy.context import Context
from rclpy.node import Node

from fiper_ros.interface.cdr import codec
from fiper_ros.launcher.config import load_launch
from fiper_ros.nodes.base import diagnostic_array

#: The demo's node set: every node of the suite and the sim bridge, in their namespaces.
DEMO = CONFIG.parents[1] / "launch" / "demo.launch.yaml"
GROUPS = {"rnd_oe_node": "/FIPER/Detectors", "ace_node": "/FIPER/Detectors", "fusion_node": "/FIPER/Fusion",
          "supervisor_node": "/FIPER/Supervisor", "policy_node": "/FIPER/Policy", "bridge_node": "/FIPER/Simulation"}


@pytest.fixture
def context(ros_domain: int) -> Iterator[Context]:
    with private_context(ros_domain) as ctx:
        yield ctx


def status_name(context: Context, name: str, namespace: str) -> str:
    """The name of the status a node called ``name`` in ``namespace`` publishes (the nodes' own function)."""
    node = Node(name, namespace=namespace, context=context)
    try:
        return codec(DiagnosticArray).decode(diagnostic_array(node, DiagnosticStatus.OK, "running", {})).status[0].name
    finally:
        node.destroy_node()


def test_each_node_of_the_suite_is_matched_by_exactly_one_analyzer(context: Context) -> None:
    specs = load_launch(DEMO).nodes
    assert {spec.name for spec in specs} == set(GROUPS)
    for spec in specs:
        name = status_name(context, spec.name, spec.namespace)
        assert name == f"fiper: {spec.fqn}"
        assert analyzers_of(name) == [GROUPS[spec.name]], name


def test_a_remapped_namespace_still_lands_in_its_group_and_other_statuses_in_none(context: Context) -> None:
    assert analyzers_of(status_name(context, "fusion_node", "/robot2/fiper")) == ["/FIPER/Fusion"]
    assert analyzers_of(status_name(context, "view_node", "/fiper")) == ["/FIPER/View"]  # the live view (#22)
    assert analyzers_of(status_name(context, "ace_node", "/")) == ["/FIPER/Detectors"]
    for other in ("motor: /arm/ace_node", "/fiper/fusion_node", "fiper: /fiper/fusion_node_2", "fiper: /x/my_policy_node"):
        assert analyzers_of(other) == [], other


def test_the_analyzers_are_installed_with_the_package() -> None:
    installed = Path(get_package_share_directory("fiper_ros")) / "config" / CONFIG.name
    assert installed.read_text() == CONFIG.read_text()
