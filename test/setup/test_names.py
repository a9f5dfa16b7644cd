"""Names (docs/architecture.md, "Names"): a name of the wire says what it names. A topic of
``interface/topics.py`` is ``*_TOPIC`` (a tuple of them ``*_TOPICS``), a service ``*_SERVICE``; a QoS profile of
``interface/qos.py`` / ``qos_spec.py`` is read with its module (``qos.ALARM_PUB``), never imported bare; and no
module renames an interface name on import (``import ALARM as ALARM_TOPIC``)."""
from __future__ import annotations

import ast
from pathlib import Path

from fiper_ros.interface import qos, qos_spec, topics

ROOT = Path(__file__).resolve().parents[2]
SOURCES = sorted(p for folder in ("fiper_ros/fiper_ros", "sim_bridge/sim_bridge", "test", "tools")
                 for p in (ROOT / folder).rglob("*.py") if "__pycache__" not in p.parts)
INTERFACE = {"fiper_ros.interface.topics": topics, "fiper_ros.interface.qos": qos,
             "fiper_ros.interface.qos_spec": qos_spec}


def _imports() -> list[tuple[str, str, str, str | None]]:
    """``(file, module, name, alias)`` of every ``from <interface module> import name [as alias]``."""
    found = []
    for path in SOURCES:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and node.module in INTERFACE:
                found += [(str(path.relative_to(ROOT)), node.module, a.name, a.asname) for a in node.names]
    return found


def test_topic_and_service_names_say_their_kind() -> None:
    wrong = []
    for name in topics.__all__:
        value = getattr(topics, name)
        if isinstance(value, str) and value.startswith(("/", "~")) and name != "NAMESPACE":
            wrong += [] if name.endswith(("_TOPIC", "_SERVICE")) else [name]
        elif isinstance(value, tuple) and value and all(isinstance(v, str) and v.startswith("/") for v in value):
            wrong += [] if name.endswith("_TOPICS") else [name]
    assert wrong == []


def test_qos_profiles_are_read_with_their_module() -> None:
    profiles = {module: {n for n, v in vars(INTERFACE[module]).items()
                         if isinstance(v, (qos.QoSProfile, qos_spec.QosSpec))}
                for module in ("fiper_ros.interface.qos", "fiper_ros.interface.qos_spec")}
    assert profiles["fiper_ros.interface.qos"] >= {"ALARM_PUB", "INPUT"}  # the check sees the profiles
    bare = [(where, f"{module}.{name}") for where, module, name, _ in _imports() if name in profiles.get(module, ())]
    assert bare == []


def test_no_interface_name_is_renamed_on_import() -> None:
    assert [(where, name, alias) for where, _, name, alias in _imports() if alias] == []
