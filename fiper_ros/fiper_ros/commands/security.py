"""``fiper security``: the SROS2 access-control policy of the suite (docs/security.md).

The policy (SROS2's format 0.2.0) has one enclave per node and per tool, named as it (its fully qualified name),
holding exactly what :mod:`fiper_ros.commands.grants` derives it does: every topic it publishes and subscribes,
every service it offers and calls, by absolute name, no wildcard, nothing else allowed. Without a launch file it
is the shipped policy: every node of every suite the project starts and every tool. ``--check`` compares a
policy file with that and fails on any difference. ``--verify`` builds each distinct node of those suites in
this process, in ROS domains of its own on loopback, brings it to ACTIVE and checks from the ROS graph that it
does exactly what its grants say.
"""
from __future__ import annotations

import argparse
import gc
import json
import sys
import time
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterable, Mapping, Sequence
from contextlib import ExitStack
from pathlib import Path
from typing import Any

from fiper_ros.commands.errors import UsageError
from fiper_ros.commands.grants import (Deployment, Grants, Policy, effective_parameters, node_grants,
                                       nodes_policy, resolve, shipped_deployments, shipped_policy, split_node)
from fiper_ros.launcher.config import NodeSpec, load_launch
from fiper_ros.launcher.processes import build_node

#: SROS2's policy format.
POLICY_VERSION = "0.2.0"
#: What may be done on each kind of name: (XML element of the list, element of one name).
GRANT_KINDS = {"publish": ("topics", "topic"), "subscribe": ("topics", "topic"),
               "reply": ("services", "service"), "request": ("services", "service")}
#: How long the nodes get to reach ACTIVE (a policy node loads its model, the bridge its scene).
ACTIVE_TIMEOUT_S = 60.0
#: The graph must stay the same this long before it is read (every endpoint of every node announced).
SETTLE_S = 0.5
#: How long the graph may take to show every endpoint of a node: DDS discovers even a process's own endpoints on
#: its own threads, which lag under load.
DISCOVERY_TIMEOUT_S = 30.0
#: How often a group is built again, in a new ROS domain, when the graph did not list every granted endpoint of one
#: of its ACTIVE nodes within :data:`DISCOVERY_TIMEOUT_S` (seen in fresh-clone test runs: one node missing whole;
#: three nodes listed with ``/rosout`` and none of their later endpoints: the process's discovery of its own
#: endpoints lagging); what is still missing then, like anything more than the grants, is a mismatch.
LAGGING_RETRIES = 1


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


def read_policy(text: str, where: str = "policy") -> dict[str, Grants]:
    """The grants a policy file gives, per enclave's node (ALLOW rules only; names made absolute);
    :class:`UsageError` naming ``where`` (the file) for text that is no SROS2 policy of :data:`POLICY_VERSION`."""
    try:
        root = ET.fromstring(text)  # noqa: S314 - our own policy file
    except ET.ParseError as error:
        raise UsageError(f"{where}: not an SROS2 policy (not XML: {error})") from None
    if root.tag != "policy" or root.get("version") != POLICY_VERSION:
        raise UsageError(f"{where}: not an SROS2 policy of version {POLICY_VERSION}")
    policy: dict[str, dict[str, set[str]]] = {}
    for profile in root.iterfind("enclaves/enclave/profiles/profile"):
        namespace, node = profile.get("ns", "/"), profile.get("node", "")
        grants = policy.setdefault(f"{namespace.rstrip('/')}/{node}", {kind: set() for kind in GRANT_KINDS})
        for kind, (element, item) in GRANT_KINDS.items():
            for grant in profile.iterfind(f"{element}[@{kind}='ALLOW']"):
                grants[kind] |= {resolve((e.text or "").strip(), namespace, node) for e in grant.iterfind(item)}
    return {fqn: Grants.of(**grants) for fqn, grants in policy.items()}


def differences(first: Policy, second: Policy, names: tuple[str, str] = ("the first", "the second")) -> list[str]:
    """What one policy allows and the other does not, one line each (``names``: how the lines call them)."""
    lines = [f"{fqn}: only in {names[0] if fqn in first else names[1]}" for fqn in sorted(set(first) ^ set(second))]
    for fqn in sorted(set(first) & set(second)):
        for kind in GRANT_KINDS:
            a, b = set(first[fqn].names(kind)), set(second[fqn].names(kind))
            lines += [f"{fqn} {kind} {name}: only in {names[0]}" for name in sorted(a - b)]
            lines += [f"{fqn} {kind} {name}: only in {names[1]}" for name in sorted(b - a)]
    return lines


# what the nodes really do -----------------------------------------------------------------------------------
def graph_grants(node: Any, fqn: str) -> Grants:
    """What the ROS graph, as ``node`` sees it, says node ``fqn`` does."""
    namespace, name = split_node(fqn)

    def names(query: Any) -> frozenset[str]:
        return frozenset(topic for topic, _ in query(name, namespace))

    return Grants(names(node.get_publisher_names_and_types_by_node), names(node.get_subscriber_names_and_types_by_node),
                  names(node.get_service_names_and_types_by_node), names(node.get_client_names_and_types_by_node))


def settled_grants(node: Any, expected: Mapping[str, Grants], spin_once: Callable[[], None],
                   timeout_s: float = DISCOVERY_TIMEOUT_S) -> dict[str, Grants]:
    """What the graph, as ``node`` sees it, says each node of ``expected`` (by fully qualified name) does: once it
    does what ``expected`` says and nothing changed for :data:`SETTLE_S`, else what it says after ``timeout_s``
    (then its differences from ``expected`` name what is missing or more). ``spin_once`` lets callbacks run."""
    seen: dict[str, Grants] = {}
    since = time.monotonic()
    deadline = since + timeout_s
    while time.monotonic() < deadline:
        now = {fqn: _graph_or_none(node, fqn) for fqn in expected}
        if now != seen:
            seen, since = now, time.monotonic()
        elif seen == expected and time.monotonic() - since >= SETTLE_S:
            break
        spin_once()
    return seen


def _graph_or_none(node: Any, fqn: str) -> Grants:
    """:func:`graph_grants`, or no grants while the node is not in the graph yet."""
    from rclpy.node import NodeNameNonExistentError  # noqa: PLC0415

    try:
        return graph_grants(node, fqn)
    except NodeNameNonExistentError:
        return Grants()


def observe(specs: Sequence[NodeSpec], domain: int, timeout_s: float = ACTIVE_TIMEOUT_S) -> dict[str, Grants]:
    """Build the nodes ``specs`` (distinct names) in this process in ``domain``, wait
    until every lifecycle node is ACTIVE and the graph shows what its grants say (:func:`settled_grants`), and
    return what each node does (read from the graph)."""
    import rclpy  # noqa: PLC0415 - only this step needs rclpy
    from rclpy.context import Context  # noqa: PLC0415
    from rclpy.executors import SingleThreadedExecutor  # noqa: PLC0415

    from fiper_ros.platform.process import use_discovery_profile  # noqa: PLC0415

    use_discovery_profile()  # as the nodes' own processes
    context = Context()
    rclpy.init(context=context, domain_id=domain)
    executor = SingleThreadedExecutor(context=context)
    nodes: list[Any] = []
    try:
        for spec in specs:
            nodes.append(build_node(spec, context))
            executor.add_node(nodes[-1])
        deadline = time.monotonic() + timeout_s

        def spin(condition: Any) -> None:
            while not condition():
                if time.monotonic() > deadline:
                    states = {n.get_fully_qualified_name(): _state(n) for n in nodes}
                    raise TimeoutError(f"the nodes did not all become active in {timeout_s:g} s: {states}")
                executor.spin_once(timeout_sec=0.02)  # noqa: F821 - called before the `del` below

        spin(lambda: all(_state(n) == "active" for n in nodes))
        expected = {spec.fqn: node_grants(spec) for spec in specs}
        return settled_grants(nodes[0], expected, lambda: executor.spin_once(timeout_sec=0.02))  # noqa: F821
    finally:
        while nodes:
            executor.remove_node(nodes[-1])
            nodes.pop().destroy_node()
        executor.shutdown()
        # A lifecycle node's state machine (its services, ~/transition_event, and so its rcl node) and the DDS
        # participant live on until collected, and this frame must hold none of them: gone now, so no later
        # participant in this domain meets a node of this name.
        del executor
        gc.collect()
        rclpy.try_shutdown(context=context)
        context.destroy()


def _state(node: Any) -> str:
    """A lifecycle node's state; ``active`` for a plain node (the example supervisor)."""
    return node.lifecycle_state() if hasattr(node, "lifecycle_state") else "active"


def distinct_nodes(deployments: Iterable[Deployment]) -> list[tuple[NodeSpec, list[str]]]:
    """Each distinct node of ``deployments`` (module, name, parameters, remaps and ROS arguments) and the origins
    of the deployments it runs in."""
    found: dict[str, tuple[NodeSpec, list[str]]] = {}
    for deployment in deployments:
        for spec in deployment.config.nodes:
            key = json.dumps([spec.module, spec.fqn, effective_parameters(spec), spec.remaps, spec.ros_arguments],
                             sort_keys=True, default=str)
            found.setdefault(key, (spec, []))[1].append(deployment.origin)
    return list(found.values())


def batches(nodes: Iterable[tuple[NodeSpec, list[str]]]) -> list[list[tuple[NodeSpec, list[str]]]]:
    """``nodes`` in groups that hold each node name at most once (one group's nodes run side by side)."""
    groups: list[list[tuple[NodeSpec, list[str]]]] = []
    for node in nodes:
        group = next((g for g in groups if all(s.fqn != node[0].fqn for s, _ in g)), None)
        if group is None:
            groups.append(group := [])
        group.append(node)
    return groups


def observe_all(deployments: Iterable[Deployment], timeout_s: float = ACTIVE_TIMEOUT_S
                ) -> list[tuple[NodeSpec, list[str], Grants]]:
    """Build every distinct node of ``deployments``, a group at a time in a ROS domain of its own (each held to
    the end, so that no group meets what an earlier one left of a node of the same name; a group with a node whose
    granted endpoints the graph did not all list is built again in a new one, :data:`LAGGING_RETRIES`): each node,
    the deployments it runs in, and what it does (read from the graph)."""
    from fiper_ros.platform.dds import allocate_domain  # noqa: PLC0415

    observed = []
    with ExitStack() as domains:
        for group in batches(distinct_nodes(deployments)):
            specs = [spec for spec, _ in group]
            for attempt in range(LAGGING_RETRIES + 1):
                seen = observe(specs, domains.enter_context(allocate_domain()), timeout_s)
                lagging = [spec.fqn for spec in specs if (node_grants(spec) | seen[spec.fqn]) != seen[spec.fqn]]
                if not lagging or attempt == LAGGING_RETRIES:
                    break
                print(f"fiper security: {', '.join(lagging)} not wholly in the ROS graph {DISCOVERY_TIMEOUT_S:g} s "
                      "after ACTIVE: its group built again in a new domain", file=sys.stderr)
            observed += [(spec, origins, seen[spec.fqn]) for spec, origins in group]
    return observed


def mismatches(observed: Iterable[tuple[NodeSpec, list[str], Grants]]) -> list[str]:
    """Where an observed node does more or less than its grants, one line each."""
    return [f"{line} (in {origins[0]})" for spec, origins, seen in observed
            for line in differences({spec.fqn: node_grants(spec)}, {spec.fqn: seen},
                                    ("its grants", "what it does"))]


# the command --------------------------------------------------------------------------------------------------
def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``fiper security``."""
    parser.add_argument("configs", type=Path, nargs="*", metavar="LAUNCH",
                        help="launch files whose nodes the policy is for, read with their default arguments "
                             "(default: every suite the project starts with every shipped model, and the tools)")
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("-o", "--output", type=Path, help="write the policy here")
    mode.add_argument("--check", type=Path, metavar="POLICY", help="compare with this policy file; exit 1 if it "
                                                                   "allows more or less than the policy")
    mode.add_argument("--verify", action="store_true", help="build every node in this process (loopback, ROS "
                                                            "domains of its own) and check that each does exactly "
                                                            "what its grants say; exit 1 if not")


def run(args: argparse.Namespace) -> int:
    """``fiper security``."""
    try:
        deployments = ([Deployment(f"fiper launch {path}", load_launch(path)) for path in args.configs]
                       if args.configs else list(shipped_deployments()))
        if args.verify:
            observed = observe_all(deployments)
            found = mismatches(observed)
            for line in found:
                print(f"fiper security: {line}")
            print(f"fiper security: {len(observed)} distinct nodes built, {len(found)} differences from their grants")
            return 1 if found else 0
        policy = nodes_policy(deployments) if args.configs else shipped_policy()
    except TimeoutError as error:  # --verify: a node that never became active does nothing to compare
        print(f"fiper security: {error}", file=sys.stderr)
        return 1
    what = " ".join(map(_shown, args.configs)) or "every suite the project starts and its tools"
    if args.check is not None:
        try:
            text = args.check.read_text()
        except OSError as error:
            raise UsageError(f"--check {args.check}: cannot read the policy ({error.strerror or error})") from None
        found = differences(read_policy(text, f"--check {args.check}"), policy, (str(args.check), "the code"))
        for line in found:
            print(f"fiper security: {line}")
        print(f"fiper security: {args.check} {'differs from' if found else 'is'} the policy of {what}")
        return 1 if found else 0
    command = " ".join(["fiper security", *map(_shown, args.configs), "-o", _shown(args.output)])
    args.output.write_text(policy_xml(policy, command))
    print(f"fiper security: {len(policy)} enclaves written to {args.output} ({what})")
    return 0


def _shown(path: Path) -> str:
    """``path`` relative to the working directory where it lies below it (what the file's comment says)."""
    try:
        return str(path.resolve().relative_to(Path.cwd()))
    except ValueError:
        return str(path)
