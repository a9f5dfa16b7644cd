"""Who may speak on the suite's topics: the rule that judges the ROS graph's publishers of a topic.

rclpy tells a subscriber nothing about which publisher sent a message (its message info holds
timestamps and sequence numbers, no publisher id), so data on a topic that has an unexpected or a
second publisher cannot be attributed to the suite: it is doubt. What a node can see is the graph: per
topic, each publisher's node name, namespace and endpoint id. :func:`judge` turns what the graph says
about one topic, and what the suite expects there (:class:`Expected`), into findings; the node shells
query the graph and act on them (docs/reliability.md, "Who may speak").

A publisher counts as a second one unless it is known to be dead, where the topic's liveliness tells
(``speaking``: the publishers a subscription has matched, less those whose liveliness lapsed): a process
killed with SIGKILL leaves its endpoints in the graph until its DDS participant lease ends (20 s with Fast
DDS's default), and its liveliness lapses long before, so a respawned node and the endpoint of its killed
predecessor are not taken for two suites, while a new publisher counts from the moment it is matched,
before it says anything. A node the graph does not
name yet cannot be attributed either: an endpoint is often discovered before its node's name (0-100 ms
here), so it is a finding only when it stays unnamed for longer than a grace period; meanwhile it is
counted as a publisher.
"""
from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field

#: Kinds of findings.
FOREIGN = "foreign"
SEVERAL = "several"
UNIDENTIFIED = "unidentified"
#: What the ROS graph says for the node and namespace of an endpoint whose node it does not know yet.
UNKNOWN_NODE_NAME = "_NODE_NAME_UNKNOWN_"
UNKNOWN_NODE_NAMESPACE = "_NODE_NAMESPACE_UNKNOWN_"
#: How long an endpoint may stay unnamed before that is a finding (its node's name is on its way).
UNNAMED_GRACE_NS = 1_000_000_000


def fully_qualified(namespace: str, name: str) -> str:
    """``/ns/name`` of a node (``/name`` in the root namespace); ``""`` when the graph does not know it."""
    if not name or name == UNKNOWN_NODE_NAME or namespace == UNKNOWN_NODE_NAMESPACE:
        return ""
    return f"{namespace.rstrip('/')}/{name}"


def resolve_node(name: str, namespace: str) -> str:
    """A node name as a parameter gives it: absolute as is, relative in ``namespace``."""
    return name if name.startswith("/") else fully_qualified(namespace, name)


@dataclass(frozen=True)
class Publisher:
    """One publisher of a topic, as the ROS graph shows it."""

    node: str
    """Fully qualified node name; ``""`` while the graph does not name the node."""
    gid: str
    """The endpoint's id (hex), to tell two publishers of the same node name apart."""


@dataclass(frozen=True)
class Expected:
    """What the suite expects of the publishers of one topic."""

    topic: str
    """Fully qualified topic name."""
    nodes: frozenset[str] = field(default_factory=frozenset)
    """The nodes that may publish it (fully qualified); empty: any node."""
    limited: bool = True
    """At most one publisher per node of ``nodes`` that publishes it (two of one name are two suites), one in
    all when ``nodes`` is empty; False: no limit (a node's own output, whose second publisher its consumer
    reports: only a consumer sees the topic's liveliness)."""

    def most(self, publishers: Sequence[Publisher]) -> int | None:
        """How many of ``publishers`` may speak at once (``None``: any number): one per allowed node present, and
        at least one (so one, without an allow list)."""
        if not self.limited:
            return None
        return max(1, len({p.node for p in publishers if p.node in self.nodes}))


@dataclass(frozen=True)
class Finding:
    """Something about a topic's publishers that the suite did not expect."""

    topic: str
    kind: str
    nodes: tuple[str, ...]
    """The publishers' node names (``""``: not named yet); for :data:`SEVERAL`, all of the topic's."""
    count: int = 0
    """For :data:`SEVERAL`: how many publishers (those that may speak, when liveliness tells)."""
    most: int = 1
    """For :data:`SEVERAL`: how many the suite has there."""

    def __str__(self) -> str:
        names = ", ".join(node or "(a node not named yet)" for node in self.nodes)
        if self.kind == FOREIGN:
            return f"{self.topic}: publisher(s) the suite does not expect: {names}"
        if self.kind == UNIDENTIFIED:
            return f"{self.topic}: {len(self.nodes)} publisher(s) of a node the graph does not name yet"
        return f"{self.topic}: {self.count} publishers where the suite has {'one' if self.most == 1 else self.most}: " \
               f"{names}"


def judge(expected: Expected, publishers: Sequence[Publisher], speaking: int | None = None,
          young: Collection[str] = ()) -> tuple[Finding, ...]:
    """The findings about ``publishers`` of ``expected.topic``.

    Args:
        expected: What the suite expects there.
        publishers: The graph's publishers of the topic.
        speaking: How many publishers may speak: those a subscription of the topic has matched, less those
            whose liveliness lapsed; ``None`` when its liveliness is not known: then every one in the graph.
        young: Endpoint ids of unnamed publishers still within their grace period.

    Returns:
        :data:`UNIDENTIFIED` if a publisher's node is not named (and not ``young``), :data:`FOREIGN` for
        nodes outside ``expected.nodes`` (when given), :data:`SEVERAL` for more publishers than
        :meth:`Expected.most`; empty when the topic's publishers are as expected (none at all is staleness's
        business, not this rule's).
    """
    found = []
    unnamed = tuple(p.node for p in publishers if not p.node and p.gid not in young)
    if unnamed:
        found.append(Finding(expected.topic, UNIDENTIFIED, unnamed))
    foreign = tuple(sorted(p.node for p in publishers if p.node and expected.nodes and p.node not in expected.nodes))
    if foreign:
        found.append(Finding(expected.topic, FOREIGN, foreign))
    count = len(publishers) if speaking is None else speaking
    most = expected.most(publishers)
    if most is not None and count > most:
        found.append(Finding(expected.topic, SEVERAL, tuple(sorted(p.node for p in publishers)), count, most))
    return tuple(found)


class PublisherWatch:
    """The findings of the latest look at the graph, and what changed since the one before."""

    def __init__(self, unnamed_grace_ns: int = UNNAMED_GRACE_NS) -> None:
        self.unnamed_grace_ns = unnamed_grace_ns
        self.findings: tuple[Finding, ...] = ()
        self.seen = 0
        """Findings that appeared so far (a topic's finding of one kind counted once per appearance)."""
        self._unnamed_since: dict[str, int] = {}

    def update(self, expectations: Sequence[Expected], graph: Mapping[str, Sequence[Publisher]],
               speaking: Mapping[str, int], now_ns: int) -> tuple[list[Finding], list[Finding]]:
        """Judge every expected topic (``graph``: its publishers; ``speaking``: where liveliness tells, how
        many may speak) at ``now_ns``; return the findings that appeared and those that went."""
        unnamed = {p.gid for publishers in graph.values() for p in publishers if not p.node}
        self._unnamed_since = {gid: self._unnamed_since.get(gid, now_ns) for gid in unnamed}
        young = {gid for gid, since in self._unnamed_since.items() if now_ns - since <= self.unnamed_grace_ns}
        now = tuple(f for e in expectations for f in judge(e, graph.get(e.topic, ()), speaking.get(e.topic), young))
        before, after = {(f.topic, f.kind) for f in self.findings}, {(f.topic, f.kind) for f in now}
        appeared = [f for f in now if (f.topic, f.kind) not in before]  # a name learnt or a count changed: the same
        gone = [f for f in self.findings if (f.topic, f.kind) not in after]
        self.findings = now
        self.seen += len(appeared)
        return appeared, gone

    def doubt(self, topics: Sequence[str]) -> str:
        """Why data on ``topics`` cannot be attributed to the suite now; ``""`` when it can."""
        return "; ".join(str(f) for f in self.findings if f.topic in topics)
