"""The shipped Foxglove layout (issue #22): valid JSON, regenerated identically by its generator, installed with the
package; it refers only to topics the suite publishes and the view serves, and to fields their messages have;
it has the panels the issue asks for."""
from __future__ import annotations

import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from ament_index_python.packages import get_package_share_directory

from fiper_msgs.msg import FailureAlarm
from fiper_ros.core.detectors import CALIBRATED
from fiper_ros.interface.messages import message_class
from fiper_ros.interface.topics import CAMERA_TOPICS, DIAGNOSTICS_TOPIC, EVENTS_TOPIC, TOPICS, score_topic
from fiper_ros.nodes.view_node import JSON_TOPICS
from fiper_ros.view.layout import LAYOUT_FILE, layout_json, main, topics_of

ROOT = Path(os.environ["FIPER_ROOT"])
SHIPPED = ROOT / "fiper_ros" / LAYOUT_FILE
#: What the suite publishes: its outputs, the policy's rollout events, every node's diagnostics, the sim's cameras.
#: Every detector a calibration may declare has its score topic (the suite's detector nodes).
SCORES = [score_topic(d) for d in CALIBRATED]
PUBLISHED = {t for t, spec in TOPICS.items() if not spec.input} | {EVENTS_TOPIC, DIAGNOSTICS_TOPIC, *CAMERA_TOPICS,
                                                                   *SCORES}
#: Message type of every published topic that is not a camera.
TYPES = {t: spec.msgtype for t, spec in TOPICS.items()} | {DIAGNOSTICS_TOPIC: "diagnostic_msgs/msg/DiagnosticArray"} | \
    {t: "fiper_msgs/msg/Score" for t in SCORES}


def _panels(node: Any) -> Iterator[dict[str, Any]]:
    if isinstance(node, dict):
        if node.get("type") == "panel":
            yield node
        for value in node.values():
            yield from _panels(value)
    elif isinstance(node, list):
        for value in node:
            yield from _panels(value)


def _paths(node: Any) -> Iterator[str]:
    """Every message path (``/topic.field``) in the layout."""
    if isinstance(node, dict):
        for value in node.values():
            yield from _paths(value)
    elif isinstance(node, list):
        for value in node:
            yield from _paths(value)
    elif isinstance(node, str) and node.startswith("/") and "." in node:
        yield node


def test_the_shipped_layout_is_valid_json_and_what_the_generator_makes(tmp_path: Path) -> None:
    text = SHIPPED.read_text()
    assert json.loads(text)["version"] == 1
    assert text == layout_json(), f"regenerate: python -m fiper_ros.view.layout fiper_ros/{LAYOUT_FILE}"
    assert main([str(tmp_path / "again" / "fiper.layout.json")]) == 0
    assert (tmp_path / "again" / "fiper.layout.json").read_text() == text
    installed = Path(get_package_share_directory("fiper_ros")) / LAYOUT_FILE
    assert installed.read_text() == text


def test_it_refers_only_to_topics_the_suite_publishes_and_the_view_serves_and_to_fields_they_have() -> None:
    layout = json.loads(SHIPPED.read_text())
    served = ({name if name.startswith("/") else f"/fiper/{name}" for name in JSON_TOPICS} | set(CAMERA_TOPICS)
              | set(SCORES))
    used = topics_of(layout)
    assert used <= PUBLISHED and used <= served, (used - PUBLISHED, used - served)
    assert used >= {*SCORES, "/fiper/alarm", DIAGNOSTICS_TOPIC, *CAMERA_TOPICS}
    for path in _paths(layout):
        topic, field = path.split(".", 1)
        assert field.split(".")[0] in message_class(TYPES[topic]).get_fields_and_field_types(), path


def test_topics_of_reads_message_paths_and_plain_topics_and_nothing_else() -> None:
    assert topics_of({"a": ["/x/y.z", {"b": "/camera/c"}], "c": "not /a topic", "d": 3, "e": []}) == \
        {"/x/y", "/camera/c"}


def test_it_has_the_panels_the_view_is_for() -> None:
    panels = list(_panels(json.loads(SHIPPED.read_text())))
    by_type: dict[str, list[dict[str, Any]]] = {}
    for panel in panels:
        by_type.setdefault(panel["panelType"], []).append(panel)
    plots = [[p["value"] for p in panel["config"]["paths"]] for panel in by_type["Plot"]]
    assert plots == [[f"{t}.windowed_score", f"{t}.threshold"] for t in SCORES]  # FIPER's pair first, then the others
    (states,) = by_type["StateTransitions"]
    alarm = states["config"]["paths"][0]
    assert alarm["value"] == "/fiper/alarm.state"
    named = {s["value"]: s["label"] for s in alarm["customStates"]["states"] if s["operator"] == "="}
    assert named == {FailureAlarm.STATE_OK: "OK", FailureAlarm.STATE_ALARM: "ALARM",
                     FailureAlarm.STATE_UNKNOWN: "UNKNOWN"}
    assert sorted(p["config"]["imageMode"]["imageTopic"] for p in by_type["Image"]) == sorted(CAMERA_TOPICS)
    assert [p["config"]["topicToRender"] for p in by_type["DiagnosticsSummary"]] == [DIAGNOSTICS_TOPIC]
    markdown = {p["config"]["renderMode"]: p["config"] for p in by_type["Markdown"]}
    assert markdown["message"]["messagePath"] == "/fiper/alarm.reason"
    assert "What you see" in markdown["static"]["markdown"]
