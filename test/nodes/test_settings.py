"""The nodes' settings (``fiper_ros.nodes.settings``): each builder from plain values by hand, its refusals in one
line, the values frozen; over DDS, a parameter set through the parameter service is refused (every parameter is
read-only, none is live) and a node whose value its builder refuses stays UNCONFIGURED saying why."""
from __future__ import annotations

import dataclasses
import subprocess
import sys
from typing import Any

import pytest
import rclpy
from rcl_interfaces.srv import SetParameters
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from fiper_ros.nodes.errors import NodeError
from fiper_ros.nodes.settings import (FROM_CALIBRATION, ace_settings, detector_settings, fusion_settings,
                                      policy_settings, shell_settings, supervisor_settings, view_settings)
from helpers.spin import spin_until

DETECTOR = {"detector": "rnd_oe", "calibration_dir": "cal", "auto_start_rollouts": False, "max_elements": 1000,
            "max_abs_value": 1e6, "max_step_gap": 100, "start_wait_s": 1.5, "start_wait_max_elements": 4096,
            "allowed_publishers": None}
ACE = DETECTOR | {"detector": "ace", "urdf_path": "", "ee_frame": "panda_hand", "joint_state_topic": "/joint_states",
                  "joint_names": ["j1", "j2"], "joint_state_wait_s": 0.25}
FUSION = {"combine": FROM_CALIBRATION, "calibration_dir": "", "deadline_s": 1.0, "deadline_periods": 2.5,
          "deadline_floor_s": 0.1, "check_period_s": 0.02, "heartbeat_s": 0.5, "buffer_size": 64, "start_wait_s": 1.0,
          "allow_reset": True, "score_publishers": ["a", ""], "allowed_publishers": []}
POLICY = {"model": "models/sorting", "batch": 0, "torch_threads": 1, "start_wait_s": 1.0, "events_topic": "e",
          "wrist_image_topic": "w", "third_image_topic": "t", "proprio_topic": "p", "embedding_topic": "o",
          "action_chunks_topic": "a", "action_topic": "c"}
SUPERVISOR = {"alarm_topic": "/fiper/alarm", "halt_service": "/sim/halt", "deadline_s": 2.0, "silence_periods": 2.5,
              "silence_floor_s": 0.1, "events_topic": "/fiper/rollout_events", "alarm_publishers": ["/fiper/fusion_node"],
              "diagnostics_period_s": 1.0, "halt_timeout_s": 1.0, "halt_retry_s": 0.5}
VIEW = {"host": "127.0.0.1", "port": 0, "backlog": 8, "detectors": ["rnd_oe", "signal_x"], "cameras": ["/c"],
        "diagnostics_period_s": 1.0, "on_demand": True}
SHELL = {"autostart": True, "configure_retry_s": 2.0, "diagnostics_period_s": 1.0, "log_period_s": 10.0}


def test_a_scoring_nodes_settings_are_its_values_with_what_the_detector_reads_and_the_waits_in_ns() -> None:
    settings = detector_settings(DETECTOR | {"detector": "signal_force"})
    assert (settings.detector, settings.reads, settings.calibration_dir) == ("signal_force", "signal", "cal")
    assert (settings.max_elements, settings.max_step_gap, settings.start_wait_max_elements) == (1000, 100, 4096)
    assert settings.start_wait_ns == 1_500_000_000 and settings.allowed_publishers == ()
    assert detector_settings(DETECTOR).reads == "embedding"
    ace = ace_settings(ACE)
    assert (ace.reads, ace.joint_names, ace.joint_state_wait_ns) == ("actions", ("j1", "j2"), 250_000_000)


@pytest.mark.parametrize("detector", ["", "bogus", "signal_"])
def test_a_detector_no_calibration_can_declare_is_refused_in_one_line(detector: str) -> None:
    expected = (f"parameter detector is {detector!r}: name a detector of the calibration (rnd_oe, ace, logpzo, "
                "pca_kmeans, progress, consistency, elapsed, signal_<name>)")
    for build, values in ((detector_settings, DETECTOR), (ace_settings, ACE)):
        with pytest.raises(NodeError) as refused:
            build(values | {"detector": detector})
        assert str(refused.value) == expected


def test_the_fusion_settings_take_a_combine_and_refuse_one_that_is_none() -> None:
    settings = fusion_settings(FUSION)
    assert (settings.combine, settings.score_publishers, settings.allowed_publishers) == (FROM_CALIBRATION, ("a",), ())
    assert (settings.deadline_ns, settings.deadline_floor_ns, settings.heartbeat_ns, settings.start_wait_ns) == (
        1_000_000_000, 100_000_000, 500_000_000, 1_000_000_000)
    assert [fusion_settings(FUSION | {"combine": c}).combine for c in ("and", "or", "max", "kth:2")] == \
        ["and", "or", "max", "kth:2"]
    for combine, reason in (("xor", "unknown combine 'xor'; expected one of and, or, max, kth:K"),
                            ("kth:0", "combine 'kth:0': kth:K needs an integer K >= 1 (e.g. kth:2)"),
                            ("or:2", "combine 'or:2': only kth takes a count (kth:K)")):
        with pytest.raises(NodeError) as refused:
            fusion_settings(FUSION | {"combine": combine})
        assert str(refused.value) == f"parameter combine: {reason}"


def test_the_view_settings_refuse_a_detector_no_suite_scores() -> None:
    settings = view_settings(VIEW)
    assert (settings.detectors, settings.cameras, settings.port, settings.on_demand) == (
        ("rnd_oe", "signal_x"), ("/c",), 0, True)
    with pytest.raises(NodeError) as refused:
        view_settings(VIEW | {"detectors": ["rnd_oe", "stac"]})
    assert str(refused.value) == ("parameter detectors: 'stac' is not a detector a suite scores (rnd_oe, ace, "
                                  "logpzo, pca_kmeans, progress, consistency, elapsed or signal_<name>)")


def test_the_other_nodes_settings_are_their_values() -> None:
    supervisor = supervisor_settings(SUPERVISOR)
    assert (supervisor.alarm_publishers, supervisor.deadline_ns, supervisor.silence_floor_ns,
            supervisor.halt_timeout_ns, supervisor.halt_retry_ns) == (
        ("/fiper/fusion_node",), 2_000_000_000, 100_000_000, 1_000_000_000, 500_000_000)
    policy = policy_settings(POLICY)
    assert (policy.model, policy.batch, policy.start_wait_ns, policy.wrist_image_topic) == (
        "models/sorting", 0, 1_000_000_000, "w")
    assert shell_settings(SHELL).configure_retry_s == 2.0


@pytest.mark.parametrize("settings", [detector_settings(DETECTOR), ace_settings(ACE), fusion_settings(FUSION),
                                      policy_settings(POLICY), supervisor_settings(SUPERVISOR), view_settings(VIEW),
                                      shell_settings(SHELL)], ids=lambda s: type(s).__name__)
def test_settings_are_frozen(settings: Any) -> None:
    name = dataclasses.fields(settings)[0].name
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(settings, name, None)


def test_the_settings_import_without_rclpy() -> None:
    code = ("import sys; sys.modules['rclpy'] = None; import fiper_ros.nodes.settings; "
            "assert not any(m.startswith('rclpy') and sys.modules[m] for m in sys.modules)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr


def _set(node: Node, executor: SingleThreadedExecutor, service: str, parameter: Parameter) -> Any:
    """Set ``parameter`` through ``service`` (the parameter service of another node) and return its result."""
    client = node.create_client(SetParameters, service)
    assert spin_until(executor, client.service_is_ready, 10.0)
    future = client.call_async(SetParameters.Request(parameters=[parameter.to_parameter_msg()]))
    assert spin_until(executor, future.done, 10.0)
    (result,) = future.result().results
    return result


def test_a_parameter_set_through_the_service_is_refused_and_a_refused_value_fails_configure(ros_domain: int) -> None:
    from fiper_ros.nodes.detector_node import DetectorNode
    from fiper_ros.nodes.fusion_node import FusionNode

    context = Context()
    rclpy.init(context=context, domain_id=ros_domain)
    executor = SingleThreadedExecutor(context=context)
    fusion = FusionNode(context=context, namespace="/settings")
    refused = DetectorNode(context=context, namespace="/settings", parameter_overrides=[
        Parameter("detector", value="bogus"), Parameter("autostart", value=False)])
    caller = Node("caller", namespace="/settings", context=context)
    for node in (fusion, refused, caller):
        executor.add_node(node)
    try:
        assert spin_until(executor, lambda: fusion.lifecycle_state() == "active", 10.0)
        before = fusion.settings
        result = _set(caller, executor, "/settings/fusion_node/set_parameters", Parameter("heartbeat_s", value=0.25))
        assert not result.successful and "read-only" in result.reason, result.reason
        assert fusion.settings is before and fusion.settings.heartbeat_s == 0.5
        assert fusion.get_parameter("heartbeat_s").value == 0.5
        assert refused.settings is None
        assert refused.trigger_configure() != rclpy.lifecycle.TransitionCallbackReturn.SUCCESS
        assert refused.config_error == ("configure failed: parameter detector is 'bogus': name a detector of the "
                                        "calibration (rnd_oe, ace, logpzo, pca_kmeans, progress, consistency, "
                                        "elapsed, signal_<name>)")
        assert refused.lifecycle_state() == "unconfigured"
    finally:
        executor.shutdown()
        for node in (fusion, refused, caller):
            node.destroy_node()
        rclpy.try_shutdown(context=context)
