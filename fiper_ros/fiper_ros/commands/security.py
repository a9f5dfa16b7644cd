"""``fiper security``: the SROS2 access-control policy of the suite, from the endpoints its nodes really create
(docs/security.md).

The nodes of a launch file, with its default launch arguments (default: the demo's, the whole suite with the sim
bridge, the policy and the example supervisor) are built in this process, in a ROS domain of their own on
loopback, and brought to ACTIVE; the ROS graph then says, per node, which topics it publishes and subscribes,
which services it offers and which it calls. That is the policy (SROS2's format 0.2.0): one enclave per node, named as the node (its fully
qualified name), every topic and service by its absolute name, no wildcard, nothing else allowed. ``--check``
compares the policy with a file and fails on any difference: a topic or service the code uses now and the
shipped policy does not name (or the other way round) is a policy to regenerate.
"""
from __future__ import annotations

import argparse
import sys
import time
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fiper_ros.launcher.config import LaunchConfig, LaunchError, load_launch
from fiper_ros.launcher.processes import build_node

#: SROS2's policy format.
POLICY_VERSION = "0.2.0"
#: What may be done on each kind of name: (XML element of the list, its attribute, element of one name).
GRANT_KINDS = {"publish": ("topics", "topic"), "subscribe": ("topics", "topic"),
               "reply": ("services", "service"), "request": ("services", "service")}
#: How long the nodes get to reach ACTIVE (a policy node loads its model, the bridge its scene).
ACTIVE_TIMEOUT_S = 60.0
#: The graph must stay the same this long before it is read (every endpoint of every node announced).
SETTLE_S = 0.5


@dataclass(frozen=True)
class Grants:
    """What one node does on the ROS graph, by absolute name: topics it publishes and subscribes, services it
    offers (``reply``) and calls (``request``)."""

    publish: frozenset[str] = field(default_factory=frozenset)
    subscribe: frozenset[str] = field(default_factory=frozenset)
    reply: frozenset[str] = field(default_factory=frozenset)
    request: frozenset[str] = field(default_factory=frozenset)

    def names(self, kind: str) -> list[str]:
        """The names of one kind (a key of :data:`GRANT_KINDS`), sorted."""
        return sorted(getattr(self, kind))


#: A policy: fully qualified node name -> its grants.
Policy = Mapping[str, Grants]


def split_node(fqn: str) -> tuple[str, str]:
    """``/ns/name`` -> (``/ns``, ``name``); the root namespace is ``/``."""
    namespace, _, name = fqn.rpartition("/")
    return namespace or "/", name


def resolve(name: str, namespace: str, node: str) -> str:
    """A name of a policy file made absolute as SROS2 does: ``/x`` as is, ``~x`` under the node, ``x`` under
    its namespace."""
    if name.startswith("/"):
        return name
    base = namespace.rstrip("/")
    return f"{base}/{node}/{name[1:].lstrip('/')}" if name.startswith("~") else f"{base}/{name}"


def policy_xml(policy: Policy, generated_by: str) -> str:
    """The SROS2 policy file of ``policy`` (nodes and names sorted, so that a regeneration is a clean diff)."""
    root = ET.Element("policy", version=POLICY_VERSION)
    enclaves = ET.SubElement(root, "enclaves")
    for fqn in sorted(policy):
        namespace, node = split_node(fqn)
        profiles = ET.SubElement(ET.SubElement(enclaves, "enclave", path=fqn), "profiles")
        profile = ET.SubElement(profiles, "profile", ns=namespace, node=node)
        for kind, (element, item) in GRANT_KINDS.items():
            names = policy[fqn].names(kind)
            if names:  # SROS2's schema wants at least one name in a list
                grant = ET.SubElement(profile, element, {kind: "ALLOW"})
                for name in names:
                    ET.SubElement(grant, item).text = name
    ET.indent(root, space="  ")
    return (f'<?xml version="1.0" encoding="UTF-8"?>\n<!-- {generated_by} (docs/security.md): regenerate, do not edit. '
            f'-->\n{ET.tostring(root, encoding="unicode")}\n')


def read_policy(text: str) -> dict[str, Grants]:
    """The grants a policy file gives, per enclave's node (ALLOW rules only; names made absolute)."""
    root = ET.fromstring(text)  # noqa: S314 - our own policy file
    if root.tag != "policy" or root.get("version") != POLICY_VERSION:
        raise ValueError(f"not an SROS2 policy of version {POLICY_VERSION}")
    policy: dict[str, dict[str, set[str]]] = {}
    for profile in root.iterfind("enclaves/enclave/profiles/profile"):
        namespace, node = profile.get("ns", "/"), profile.get("node", "")
        grants = policy.setdefault(f"{namespace.rstrip('/')}/{node}", {kind: set() for kind in GRANT_KINDS})
        for kind, (element, item) in GRANT_KINDS.items():
            for grant in profile.iterfind(f"{element}[@{kind}='ALLOW']"):
                grants[kind] |= {resolve((e.text or "").strip(), namespace, node) for e in grant.iterfind(item)}
    return {fqn: Grants(**{kind: frozenset(names) for kind, names in grants.items()}) for fqn, grants in policy.items()}


def differences(first: Policy, second: Policy, names: tuple[str, str] = ("the first", "the second")) -> list[str]:
    """What one policy allows and the other does not, one line each (``names``: how the lines call them)."""
    lines = [f"{fqn}: only in {names[0] if fqn in first else names[1]}" for fqn in sorted(set(first) ^ set(second))]
    for fqn in sorted(set(first) & set(second)):
        for kind in GRANT_KINDS:
            a, b = set(first[fqn].names(kind)), set(second[fqn].names(kind))
            lines += [f"{fqn} {kind} {name}: only in {names[0]}" for name in sorted(a - b)]
            lines += [f"{fqn} {kind} {name}: only in {names[1]}" for name in sorted(b - a)]
    return lines


def graph_grants(node: Any, fqn: str) -> Grants:
    """What the ROS graph, as ``node`` sees it, says node ``fqn`` does."""
    namespace, name = split_node(fqn)

    def names(query: Any) -> frozenset[str]:
        return frozenset(topic for topic, _ in query(name, namespace))

    return Grants(names(node.get_publisher_names_and_types_by_node), names(node.get_subscriber_names_and_types_by_node),
                  names(node.get_service_names_and_types_by_node), names(node.get_client_names_and_types_by_node))


def collect(config: LaunchConfig, domain: int, timeout_s: float = ACTIVE_TIMEOUT_S) -> dict[str, Grants]:
    """Build the nodes of ``config`` in this process in ``domain``, wait until every lifecycle node is ACTIVE
    and the graph has settled, and return what each node does (read from the graph)."""
    import rclpy  # noqa: PLC0415 - only this step needs rclpy
    from rclpy.context import Context  # noqa: PLC0415
    from rclpy.executors import SingleThreadedExecutor  # noqa: PLC0415

    context = Context()
    rclpy.init(context=context, domain_id=domain)
    executor = SingleThreadedExecutor(context=context)
    nodes: list[Any] = []
    try:
        for spec in config.nodes:
            nodes.append(build_node(spec, context))
            executor.add_node(nodes[-1])
        deadline = time.monotonic() + timeout_s

        def spin(condition: Any) -> None:
            while not condition():
                if time.monotonic() > deadline:
                    states = {n.get_fully_qualified_name(): _state(n) for n in nodes}
                    raise TimeoutError(f"the nodes did not all become active in {timeout_s:g} s: {states}")
                executor.spin_once(timeout_sec=0.02)

        spin(lambda: all(_state(n) == "active" for n in nodes))
        fqns = [n.get_fully_qualified_name() for n in nodes]
        seen: dict[str, Grants] = {}
        settled_at = [time.monotonic()]

        def settled() -> bool:
            now = {fqn: graph_grants(nodes[0], fqn) for fqn in fqns}
            if now != seen:
                seen.clear()
                seen.update(now)
                settled_at[0] = time.monotonic()
            return time.monotonic() - settled_at[0] >= SETTLE_S

        spin(settled)
        return dict(seen)
    finally:
        executor.shutdown()
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


def _state(node: Any) -> str:
    """A lifecycle node's state; ``active`` for a plain node (the example supervisor)."""
    return node.lifecycle_state() if hasattr(node, "lifecycle_state") else "active"


def default_config() -> Path:
    """The demo's launch file: every node of the suite."""
    from fiper_ros.client.suite_process import installed_launch  # noqa: PLC0415

    return installed_launch("demo.launch.yaml")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``fiper security``."""
    parser.add_argument("config", type=Path, nargs="?",
                        help="launch YAML whose nodes the policy is for, read with its default arguments (default: "
                             "the installed demo.launch.yaml, the whole suite)")
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("-o", "--output", type=Path, help="write the policy here")
    mode.add_argument("--check", type=Path, metavar="POLICY", help="compare with this policy file; exit 1 if it "
                                                                   "allows more or less than the nodes use")


def run(args: argparse.Namespace) -> int:
    """``fiper security``."""
    from fiper_ros.dds import allocate_domain  # noqa: PLC0415

    path = args.config or default_config()
    try:
        config = load_launch(path)
    except LaunchError as error:
        print(f"fiper security: {error}", file=sys.stderr)
        return 2
    with allocate_domain() as domain:
        policy = collect(config, domain)
    if args.check is not None:
        found = differences(read_policy(args.check.read_text()), policy, (str(args.check), "the code"))
        for line in found:
            print(f"fiper security: {line}")
        print(f"fiper security: {args.check} {'differs from' if found else 'is'} what the nodes of {path} use")
        return 1 if found else 0
    args.output.write_text(policy_xml(policy, f"fiper security {_shown(path)} -o {_shown(args.output)}"))
    print(f"fiper security: {len(policy)} enclaves written to {args.output}")
    return 0


def _shown(path: Path) -> str:
    """``path`` relative to the working directory where it lies below it (what the file's comment says)."""
    try:
        return str(path.resolve().relative_to(Path.cwd()))
    except ValueError:
        return str(path)
