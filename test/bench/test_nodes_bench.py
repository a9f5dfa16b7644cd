"""``make bench-nodes`` says where the steps of a rate it could not sustain went, from the nodes' /diagnostics."""
from __future__ import annotations

from fiper_ros.bench.nodes_bench import loss_counters, where_lost


def diagnostics(rnd_oe: int, ace: int, matched: int, evicted: int, unmatched: int) -> dict[str, dict[str, str]]:
    """The /diagnostics values of the three suite nodes (as their status names and keys are), and a foreign one."""
    return {
        "fiper: /fiper/rnd_oe_node": {"published": str(rnd_oe), "latency_p50_ms": "0.2"},
        "fiper: /fiper/ace_node": {"published": str(ace), "waiting_for_start": "0"},
        "fiper: /fiper/fusion_node": {"matched": str(matched), "evicted": str(evicted), "unmatched": str(unmatched),
                                      "published.ok": "9"},
        "fiper: /fiper/policy_node": {"published": "5"},
    }


def test_the_counters_of_the_suite_nodes_only() -> None:
    assert loss_counters(diagnostics(10, 11, 9, 1, 2)) == {
        "rnd_oe_node.published": 10, "ace_node.published": 11, "fusion_node.matched": 9,
        "fusion_node.evicted": 1, "fusion_node.unmatched": 2}
    assert loss_counters({}) == {}


def test_a_run_is_told_by_the_differences() -> None:
    before = loss_counters(diagnostics(100, 100, 100, 0, 0))
    after = loss_counters(diagnostics(2100, 2100, 1817, 183, 0))
    assert where_lost(before, after, 2000) == (
        "scores published: rnd_oe 2000, ace 2000 of 2000; the fusion node fused 1717, evicted 183 (from its full "
        "buffer of unmatched steps; a step counts once per score evicted) and dropped 0 (the other score never came)")
