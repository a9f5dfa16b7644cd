"""`LaunchConfig.with_parameters`: the one way the demo, collect and replay rewrite a launch file; a node's command
line and its in-process parameters."""
from __future__ import annotations

from pathlib import Path

import rclpy
import yaml
from rclpy.context import Context

from fiper_ros.launcher.config import NodeSpec, dump_config, load_config
from fiper_ros.launcher.processes import build_node


def test_with_parameters_merges_per_node_and_leaves_the_source_alone(tmp_path: Path) -> None:
    source = tmp_path / "suite.yaml"
    source.write_text(yaml.safe_dump({"nodes": {
        "a": {"module": "m.a", "parameters": {"x": 1, "y": 2}},
        "b": {"module": "m.b", "parameters": {"y": 3}},
        "c": {"module": "m.c"}}}))
    config = load_config(source)

    def extra(spec: NodeSpec) -> dict[str, int]:
        return {"y": 9, "z": 4} if spec.module != "m.c" else {}

    changed = config.with_parameters(extra)

    assert [spec.parameters for spec in changed.nodes] == [{"x": 1, "y": 9, "z": 4}, {"y": 9, "z": 4}, {}]
    assert [spec.parameters for spec in config.nodes] == [{"x": 1, "y": 2}, {"y": 3}, {}]
    reread = load_config(dump_config(changed, tmp_path / "out.yaml"))
    assert [spec.parameters for spec in reread.nodes] == [spec.parameters for spec in changed.nodes]


def test_a_node_runs_in_its_own_security_enclave_when_asked() -> None:
    spec = NodeSpec("fusion_node", "fiper_ros.nodes.fusion_node", "/fiper", ())
    assert "--enclave" not in spec.ros_args(False)
    args = spec.ros_args(False, enclave=True)
    assert args[args.index("--enclave") + 1] == spec.fqn == "/fiper/fusion_node"


def test_an_in_process_node_gets_its_parameter_file_entry_and_a_file_without_one_is_no_error(
        tmp_path: Path, ros_domain: int) -> None:
    params = tmp_path / "nodes.yaml"
    params.write_text(yaml.safe_dump({"/fiper/fusion_node": {"ros__parameters": {"heartbeat_s": 0.25,
                                                                                 "combine": "and"}}}))
    context = Context()
    rclpy.init(context=context, domain_id=ros_domain)
    nodes = []
    try:
        nodes.append(build_node(NodeSpec("fusion_node", "fiper_ros.nodes.fusion_node", "/fiper", (params,),
                                         {"combine": "or"}), False, context))
        nodes.append(build_node(NodeSpec("supervisor_node", "fiper_ros.nodes.supervisor_node", "/fiper", (params,)),
                                True, context))
        fusion, supervisor = nodes
        assert fusion.get_parameter("heartbeat_s").value == 0.25  # the file's
        assert fusion.get_parameter("combine").value == "or"  # inline wins
        assert supervisor.get_parameter("use_sim_time").value is True
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)
