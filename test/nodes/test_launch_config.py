"""`LaunchConfig.with_parameters`: the one way the demo, collect and replay rewrite a launch file."""
from __future__ import annotations

from pathlib import Path

import yaml

from fiper_ros.launch import NodeSpec, dump_config, load_config


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
