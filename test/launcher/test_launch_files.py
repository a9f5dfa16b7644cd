"""Reading ROS 2 launch YAML (fiper_ros/launcher/config.py): the schema subset ``fiper launch`` reads, by hand-written
files; the shipped launch files; ``fiper launch``'s one-line refusals (an unsupported tag, attribute or
substitution, an unknown or missing launch argument); ``name:=value`` arguments; writing a launch file back."""
from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
import yaml
from ament_index_python.packages import get_package_share_directory

from fiper_ros.cli import main
from fiper_ros.launcher.config import LaunchError, NodeSpec, dump_launch, load_launch, parse_arguments
from fiper_ros.launcher.overrides import Overrides, apply

ROOT = Path(os.environ["FIPER_ROOT"])
SHARE = Path(get_package_share_directory("fiper_ros"))
FIPER = ROOT / "fiper_ros" / "launch" / "fiper.launch.yaml"
DEMO = ROOT / "fiper_ros" / "launch" / "demo.launch.yaml"
SHIPPED = sorted([*(ROOT / "fiper_ros" / "launch").glob("*.launch.yaml"),
                  *(ROOT / "sim_bridge" / "launch").glob("*.launch.yaml")])


def write(path: Path, *entries: dict[str, Any]) -> Path:
    path.write_text(yaml.safe_dump({"launch": list(entries)}, sort_keys=False))
    return path


def node(name: str = "fusion_node", **attributes: Any) -> dict[str, Any]:
    return {"node": {"pkg": "fiper_ros", "exec": name, "name": name, **attributes}}


def refused(path: Path, arguments: dict[str, str] | None = None) -> str:
    with pytest.raises(LaunchError) as error:
        load_launch(path, arguments)
    message = str(error.value)
    assert "\n" not in message, message
    return message


def test_arguments_lets_and_substitutions_reach_the_nodes(tmp_path: Path) -> None:
    params = tmp_path / "params.yaml"
    params.write_text("/**:\n  ros__parameters: {heartbeat_s: 0.25}\n")
    path = write(tmp_path / "a.launch.yaml",
                 {"arg": {"name": "ns", "default": "/robot"}},
                 {"arg": {"name": "cal", "default": "$(find-pkg-share fiper_ros)/models/sorting/calibration"}},
                 {"let": {"name": "sim", "value": "true"}},
                 node(namespace="$(var ns)/fiper", respawn="true", respawn_delay=0.5, on_exit="shutdown",
                      ros_args="--log-level $(env FIPER_TEST_LEVEL warn)",
                      remap=[{"from": "alarm", "to": "$(var ns)/alarm"}],
                      param=[{"from": "$(dirname)/params.yaml"},
                             {"name": "calibration_dir", "value": "$(var cal)"},
                             {"name": "use_sim_time", "value": "$(var sim)"},
                             {"name": "buffer_size", "value": "$(env FIPER_TEST_UNSET 16)"},
                             {"name": "combine", "value": "or"},
                             {"name": "score_publishers", "value": ["a_node", "$(var ns)/b_node"]},
                             {"name": "qos_overrides", "param": [{"name": "depth", "value": 4}]}]))
    config = load_launch(path, {"ns": "/arm"}, env={})
    (spec,) = config.nodes
    assert (spec.package, spec.executable, spec.module) == ("fiper_ros", "fusion_node", "fiper_ros.nodes.fusion_node")
    assert spec.fqn == "/arm/fiper/fusion_node"
    assert spec.parameter_files == (params,)
    assert spec.parameters == {"calibration_dir": str(SHARE / "models" / "sorting" / "calibration"),
                               "use_sim_time": True, "buffer_size": 16, "combine": "or",
                               "score_publishers": ["a_node", "/arm/b_node"], "qos_overrides.depth": 4}
    assert spec.remaps == (("alarm", "/arm/alarm"),) and spec.ros_arguments == ("--log-level", "warn")
    assert spec.required and spec.respawn and spec.respawn_delay == 0.5
    assert config.values["sim"] == "true" and config.values["ns"] == "/arm"
    assert [a.name for a in config.arguments] == ["ns", "cal"]
    args = spec.ros_args(tmp_path)
    files = [Path(args[i + 1]) for i, arg in enumerate(args) if arg == "--params-file"]
    assert files == [params, tmp_path / "fusion_node.1.yaml"]  # in order; the name/values keyed by the node
    assert yaml.safe_load(files[1].read_text()) == {"/arm/fiper/fusion_node": {"ros__parameters": spec.parameters}}
    assert "alarm:=/arm/alarm" in args and args[-2:] == ["--log-level", "warn"]


def test_output_and_respawn_max_retries_are_read_as_launch_ros_means_them(tmp_path: Path) -> None:
    path = write(tmp_path / "o.launch.yaml", node("rnd_oe_node"), node("ace_node", output="log"),
                 node("fusion_node", output="both", respawn="true", respawn_max_retries=2),
                 node("supervisor_node", respawn="true", respawn_max_retries=0))
    plain, logged, both, never = load_launch(path).nodes
    assert [(s.output, s.to_screen, s.to_log) for s in (plain, logged, both)] == [
        ("screen", True, False), ("log", False, True), ("both", True, True)]
    assert plain.respawn_max_retries == -1 and both.respawn_max_retries == 2 and never.respawn_max_retries == 0
    assert [both.may_respawn(n) for n in range(4)] == [True, True, False, False]
    assert not never.may_respawn(0) and not plain.may_respawn(0)  # no respawn: true
    assert replace(plain, respawn=True).may_respawn(10 ** 6)  # -1: unlimited
    assert load_launch(dump_launch(load_launch(path), tmp_path / "out.launch.yaml")).nodes == load_launch(path).nodes


@pytest.mark.parametrize(("value", "expected"), [
    ("true", True), ("1", 1), ("1.5", 1.5), ("and", "and"), ("'1.0'", "1.0"), ("''", ""), ("[1, 2]", [1, 2]),
    (0.5, 0.5), (False, False), (["x", "y"], ["x", "y"]), ([1, 2], [1, 2]),
])
def test_a_value_is_typed_as_launch_ros_types_it(tmp_path: Path, value: Any, expected: Any) -> None:
    path = write(tmp_path / "t.launch.yaml", node(param=[{"name": "p", "value": value}]))
    got = load_launch(path).nodes[0].parameters["p"]
    assert got == expected and type(got) is type(expected)


def test_later_entries_win_and_conditions_skip_tags(tmp_path: Path) -> None:
    path = write(tmp_path / "c.launch.yaml",
                 {"arg": {"name": "alone", "default": "false"}},
                 node("rnd_oe_node", param=[{"name": "x", "value": 1}, {"name": "x", "value": 2}]),
                 node("ace_node", unless="$(var alone)"),
                 node("supervisor_node", **{"if": "$(var alone)"}))
    assert [s.name for s in load_launch(path).nodes] == ["rnd_oe_node", "ace_node"]
    assert load_launch(path).nodes[0].parameters == {"x": 2}
    assert [s.name for s in load_launch(path, {"alone": "True"}).nodes] == ["rnd_oe_node", "supervisor_node"]


def test_an_include_shares_the_scope_and_its_arguments_are_declared(tmp_path: Path) -> None:
    inner = write(tmp_path / "inner.launch.yaml", {"arg": {"name": "level", "default": "info"}},
                  {"arg": {"name": "cal", "default": "none"}},
                  node(param=[{"name": "calibration_dir", "value": "$(var cal)"}], ros_args="--log-level $(var level)"))
    outer = write(tmp_path / "outer.launch.yaml", {"arg": {"name": "model", "default": "/m"}},
                  {"include": {"file": "$(dirname)/inner.launch.yaml",
                               "arg": [{"name": "cal", "value": "$(var model)/calibration"}]}},
                  node("supervisor_node", param=[{"name": "alarm_topic", "value": "$(var cal)"}]))
    config = load_launch(outer, {"level": "debug"})
    assert [a.name for a in config.arguments] == ["model", "level", "cal"]
    fusion, supervisor = config.nodes
    assert fusion.parameters == {"calibration_dir": "/m/calibration"} and fusion.ros_arguments[-1] == "debug"
    assert supervisor.parameters == {"alarm_topic": "/m/calibration"}  # unscoped, as IncludeLaunchDescription
    assert inner.is_file()


@pytest.mark.parametrize(("entries", "message"), [
    ([{"group": {"scoped": True}}], "tag 'group' is not supported by fiper launch (it reads arg, let, include, node)"),
    ([{"executable": {"cmd": "ls"}}], "tag 'executable' is not supported"),
    ([node(**{"launch-prefix": "gdb"})], "attribute 'launch-prefix' is not supported by fiper launch (node takes args, "
                                       "exec, if, name,"),
    ([node(param=[{"name": "p", "value": "$(command ls)"}])], "substitution $(command ...) is not supported"),
    ([node(namespace="$(eval '1')")], "substitution $(eval ...) is not supported"),
    ([node(param=[{"name": "p", "value": "x", "type": "str"}])], "attribute 'type' is not supported"),
    ([node(output="own_log")], "output 'own_log' is not supported (one of screen, log, both)"),
    ([node(on_exit="restart")], "on_exit 'restart' is not supported (only shutdown)"),
    ([node(respawn="maybe")], "respawn must be true or false, got 'maybe'"),
    ([node(respawn_delay=-1)], "respawn_delay must be >= 0, got -1"),
    ([node(respawn_max_retries=-2)], "respawn_max_retries must be an integer >= -1 (-1: unlimited), got -2"),
    ([node(respawn_max_retries=1.5)], "respawn_max_retries must be an integer >= -1 (-1: unlimited), got 1.5"),
    ([node(param=[{"from": "params.yaml"}])], "param from 'params.yaml' is relative: write $(dirname)/params.yaml"),
    ([node(param=[{"from": "/no/such/params.yaml"}])], "param from: no such file /no/such/params.yaml"),
    ([node(param=[{"name": "p", "value": "$(var nothing)"}])], "$(var nothing): no launch argument or let named"),
    ([node(param=[{"name": "p", "value": ""}])], "is empty once substituted"),
    ([node(param=[{"name": "p", "value": []}])], "an empty list has no type ROS can infer"),
    ([node(param=[{"name": "p", "value": [1, "a"]}])], "a list's items must all be bool, all int"),
    ([node(), node()], "node 'fusion_node': a second node of this name"),
    ([node("no_such_node")], "package 'fiper_ros' has no executable 'no_such_node' (it has ace_node, container, detector_node, fiper,"),
    ([{"node": {"pkg": "rclpy", "exec": "x", "name": "x"}}], "package 'rclpy' has no Python executables installed"),
    ([{"node": {"pkg": "fiper_ros", "name": "fusion_node"}}], "needs 'exec'"),
    ([{"node": {"pkg": "fiper_ros", "exec": "container"}}, {"node": {"pkg": "fiper_ros", "exec": "container"}}],
     "node 'container': a second node of this name"),
    ([node(param=[{"name": "p", "value": "$(find-pkg-share no_such_pkg)"}])],
     "$(find-pkg-share no_such_pkg): no package 'no_such_pkg' on the ament index"),
    ([{"arg": {"name": "combine", "default": "xor", "choice": [{"value": "and"}, {"value": "or"}]}}],
     "launch argument combine:='xor' is not one of and, or"),
    ([{"arg": {"name": "calibration_dir"}}],
     "launch argument 'calibration_dir' has no default: give calibration_dir:="),
    ([{"include": {"file": "$(dirname)/self.launch.yaml"}}], "includes nested deeper than 8"),
])
def test_what_fiper_launch_cannot_run_is_refused_in_one_line(tmp_path: Path, entries: list[dict[str, Any]],
                                                              message: str) -> None:
    message_seen = refused(write(tmp_path / "self.launch.yaml", *entries))
    assert message in message_seen and str(tmp_path) in message_seen, message_seen


def test_files_that_are_not_launch_yaml_are_refused(tmp_path: Path) -> None:
    old = tmp_path / "suite.yaml"
    old.write_text(yaml.safe_dump({"namespace": "/fiper", "nodes": {"fusion_node": {"module": "m"}}}))
    assert "not a ROS 2 launch YAML: expected one top-level list 'launch:' (fiper's own format with 'nodes:' " \
           "is gone" in refused(old)
    broken = tmp_path / "broken.yaml"
    broken.write_text("launch: [\n")
    assert "not YAML" in refused(broken)
    assert refused(tmp_path / "missing.yaml") == f"launch file not found: {tmp_path / 'missing.yaml'}"


def test_an_unknown_argument_is_refused_with_the_declared_ones() -> None:
    assert refused(FIPER, {"calibraton_dir": "x"}) == (
        f"{FIPER}: unknown launch argument calibraton_dir (it declares: autostart, calibration_dir, combine, "
        "compose, consistency, elapsed, log_level, logpzo, namespace, observation_only, params_file, pca_kmeans, "
        "progress, rnd_oe, signal, use_signal, use_sim_time, view, view_host, view_port)")


def test_launch_arguments_on_the_command_line() -> None:
    assert parse_arguments(["a:=1", "b:=", "c:=x:=y"]) == {"a": "1", "b": "", "c": "x:=y"}
    for bad in ("a=1", ":=1", "a"):
        with pytest.raises(LaunchError, match="launch arguments are name:=value"):
            parse_arguments([bad])


def test_fiper_launch_says_what_it_refuses_in_one_line_and_exits_2(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    path = write(tmp_path / "g.launch.yaml", {"group": {}})
    assert main(["launch", str(path)]) == 2
    err = capsys.readouterr().err
    assert err == f"fiper launch: {path}: tag 'group' is not supported by fiper launch (it reads arg, let, include, " \
                  "node)\n"
    assert main(["launch", str(FIPER), "nope:=1"]) == 2
    assert capsys.readouterr().err.startswith(f"fiper launch: {FIPER}: unknown launch argument nope (it declares: ")
    assert main(["launch", str(FIPER), "--show-args", "combine:=or"]) == 0
    shown = capsys.readouterr().out
    assert "'combine': how the fusion node votes" in shown and "(default: 'calibration'), here 'or'" in shown


def test_the_shipped_launch_files_read_with_their_defaults() -> None:
    nodes = {path.name: {spec.name: spec for spec in load_launch(path).nodes} for path in SHIPPED}
    assert {name: set(specs) for name, specs in nodes.items()} == {
        "bridge.launch.yaml": {"bridge_node"},
        "demo.launch.yaml": {"bridge_node", "policy_node", "rnd_oe_node", "ace_node", "fusion_node", "supervisor_node"},
        "fiper.launch.yaml": {"rnd_oe_node", "ace_node", "fusion_node"},
        "policy.launch.yaml": {"policy_node"}}
    shipped = str(SHARE / "models" / "sorting" / "calibration")
    for name, spec in nodes["fiper.launch.yaml"].items():
        assert spec.parameters["calibration_dir"] == shipped and spec.parameters["use_sim_time"] is False, name
        assert spec.respawn and spec.namespace == "/fiper" and spec.parameter_files == (SHARE / "config/nodes.yaml",)
        assert spec.parameters["autostart"] is True, name
    demo = nodes["demo.launch.yaml"]
    assert {n for n, s in demo.items() if s.required} == {"bridge_node", "policy_node"}
    assert all(s.parameters["use_sim_time"] is True for n, s in demo.items() if n != "bridge_node")
    assert "use_sim_time" not in demo["bridge_node"].parameters  # the clock source
    assert demo["ace_node"].parameters["calibration_dir"] == shipped
    alone = load_launch(FIPER, {"observation_only": "true", "calibration_dir": "my_calibration"})
    assert [spec.name for spec in alone.nodes] == ["rnd_oe_node", "fusion_node"]
    assert all(spec.parameters["calibration_dir"] == "my_calibration" for spec in alone.nodes)
    composed = {spec.name: spec for spec in load_launch(FIPER, {"compose": "true", "combine": "or"}).nodes}
    assert set(composed) == {"ace_node", "container"}
    container = composed["container"]
    assert not container.named and container.arguments == ("rnd_oe_node", "fusion_node") and container.respawn
    assert container.module == "fiper_ros.nodes.container" and container.parameters["combine"] == "or"
    assert container.parameters["calibration_dir"] == shipped


def test_a_written_launch_file_reads_back_into_the_same_nodes(tmp_path: Path) -> None:
    demo = load_launch(DEMO, {"model": "/tmp/m x"})
    odd = {"text_like_a_number": "1.0", "text_like_a_bool": "true", "empty": "", "names": ["1", "a"]}
    changed = apply(demo, Overrides(by_name={"fusion_node": odd}, required=True))
    reread = load_launch(dump_launch(changed, tmp_path / "out.launch.yaml"))
    assert reread.nodes == changed.nodes
    assert reread.nodes[4].parameters["text_like_a_number"] == "1.0" and all(s.required for s in reread.nodes)
    with pytest.raises(LaunchError, match="would read as a substitution"):
        dump_launch(apply(demo, Overrides(by_name={"ace_node": {"urdf_path": "$(var x)"}})), tmp_path / "bad.yaml")


def test_overrides_select_nodes_and_set_parameters_after_their_own() -> None:
    config = load_launch(DEMO)
    changed = apply(config, Overrides(by_module={"fiper_ros.nodes.ace_node": {"urdf_path": "/r.urdf"}},
                                      by_name={"policy_node": {"batch": 4}}, keep=("policy_node", "ace_node")))
    assert [s.name for s in changed.nodes] == ["policy_node", "ace_node"]
    policy, ace = changed.nodes
    assert policy.parameters["batch"] == 4 and ace.parameters["urdf_path"] == "/r.urdf"
    own = config.nodes[3]
    assert ace.params == (*own.parameter_files, own.parameters | {"urdf_path": "/r.urdf"})  # after the file's own


def test_an_entry_without_a_name_leaves_the_names_to_its_process_and_passes_its_args(tmp_path: Path) -> None:
    path = write(tmp_path / "c.launch.yaml", {"node": {
        "pkg": "fiper_ros", "exec": "container", "args": "rnd_oe_node 'fusion_node'", "namespace": "/fiper",
        "param": [{"name": "calibration_dir", "value": "/c"}], "respawn": "true"}})
    (spec,) = load_launch(path).nodes
    assert (spec.name, spec.named, spec.arguments, spec.fqn) == ("container", False, ("rnd_oe_node", "fusion_node"),
                                                                   "/fiper/container")
    command = spec.command(tmp_path)
    assert command[1:6] == ["-m", "fiper_ros.nodes.container", "rnd_oe_node", "fusion_node", "--ros-args"]
    assert "__node:=container" not in command and "__ns:=/fiper" in command  # each node keeps its own name
    written = Path(command[command.index("--params-file") + 1])
    assert yaml.safe_load(written.read_text()) == {"/**": {"ros__parameters": {"calibration_dir": "/c"}}}
    reread = load_launch(dump_launch(load_launch(path), tmp_path / "out.launch.yaml"))
    assert reread.nodes == (spec,)
    with pytest.raises(LaunchError, match="without a name: under ROS_SECURITY_ENABLE=true each process runs in the "
                                          "enclave of its one node"):
        spec.command(tmp_path, enclave=True)


def test_fiper_launch_refuses_a_container_under_security_before_any_node_starts(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setenv("ROS_SECURITY_ENABLE", "true")
    assert main(["launch", str(FIPER), "compose:=true"]) == 2
    captured = capsys.readouterr()
    assert "fiper launch: node entry 'container' without a name" in captured.err
    assert "[launch] started" not in captured.out


def test_a_node_runs_in_its_own_security_enclave_when_asked() -> None:
    spec = NodeSpec("fusion_node", "fiper_ros", "fusion_node", "fiper_ros.nodes.fusion_node", "/fiper")
    assert "--enclave" not in spec.ros_args(Path("/nowhere"))
    args = spec.ros_args(Path("/nowhere"), enclave=True)
    assert args[args.index("--enclave") + 1] == spec.fqn == "/fiper/fusion_node"
    assert spec.command(Path("/nowhere"))[1:3] == ["-m", "fiper_ros.nodes.fusion_node"]
