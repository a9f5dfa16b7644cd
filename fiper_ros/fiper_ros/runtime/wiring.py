"""Whether a suite's nodes are wired: every DDS match between their topics exists.

Each node reports on ``/diagnostics``, per topic of its own, how many subscriptions its publisher has
matched (``matched_subscribers.<topic>``) and how many publishers its subscription has matched
(``matched_publishers.<topic>``). The policy's outputs are VOLATILE, so a detector whose subscription
the policy has not matched yet loses the first steps of a rollout; whoever starts rollouts waits for
:func:`missing_matches` to be empty first. A policy outside the suite (:mod:`fiper_ros.publishing`) sees
its own publishers' matches, not its readers': :func:`unmatched_readers` tells it which readers report
a subscription of its topic and which of them have not matched every publisher of it yet.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

MATCHED_SUBSCRIBERS = "matched_subscribers."
MATCHED_PUBLISHERS = "matched_publishers."


def _counts(values: Mapping[str, str], prefix: str) -> dict[str, int]:
    return {key[len(prefix):]: int(value) for key, value in values.items() if key.startswith(prefix)}


def missing_matches(diagnostics: Mapping[str, Mapping[str, str]], nodes: Sequence[str],
                    own_subscriptions: Mapping[str, int]) -> list[str]:
    """What is not matched yet among ``nodes`` (fully qualified names) on each topic one of them publishes.

    Every subscriber among ``nodes`` must have matched a publisher, and every publisher among ``nodes``
    must have matched all those subscriptions plus the caller's own (``own_subscriptions``: count per
    topic). Topics no node of ``nodes`` publishes are not checked; a node without diagnostics yet counts
    as neither publisher nor subscriber (wait for its lifecycle state first).

    Args:
        diagnostics: The latest /diagnostics key/values per node.
        nodes: The nodes that must be wired.
        own_subscriptions: The caller's own subscriptions per topic.

    Returns:
        One line per missing match; empty when the suite is wired.
    """
    published = {n: _counts(diagnostics.get(n, {}), MATCHED_SUBSCRIBERS) for n in nodes}
    subscribed = {n: _counts(diagnostics.get(n, {}), MATCHED_PUBLISHERS) for n in nodes}
    missing = []
    for topic in sorted({t for counts in published.values() for t in counts}):
        readers = [n for n in nodes if topic in subscribed[n]]
        missing += [f"{n} to match a publisher of {topic}" for n in readers if subscribed[n][topic] < 1]
        needed = len(readers) + own_subscriptions.get(topic, 0)
        missing += [f"{n} to match {needed} subscriptions of {topic} (has {counts[topic]})"
                    for n, counts in published.items() if counts.get(topic, needed) < needed]
    return missing


def unmatched_readers(diagnostics: Mapping[str, Mapping[str, str]], topic: str,
                      publishers: int) -> tuple[list[str], list[str]]:
    """The nodes whose /diagnostics report a subscription of ``topic``, and what they have not matched yet.

    DDS matching is not symmetric: a publisher can have matched a subscription whose reader has not matched
    it yet, and a VOLATILE reader drops what it receives before. A reader that reports having matched at least
    ``publishers`` publishers of ``topic`` (the ROS graph's count, the caller's own among them) has matched the
    caller's too.

    Args:
        diagnostics: The latest /diagnostics key/values per node (fully qualified names).
        topic: The topic (fully qualified).
        publishers: How many publishers of ``topic`` the ROS graph shows.

    Returns:
        The reporting readers (sorted), and one line per reader that has matched fewer than ``publishers``.
    """
    key = f"{MATCHED_PUBLISHERS}{topic}"
    readers = sorted(node for node, values in diagnostics.items() if key in values)
    missing = [f"{node} to match {publishers} publishers of {topic} (has {diagnostics[node][key]})"
               for node in readers if int(diagnostics[node][key]) < publishers]
    return readers, missing
