"""missing_matches: when the suite's nodes have matched each other's topics; unmatched_readers: which readers of a
policy's topic have not matched all its publishers (no DDS)."""
from __future__ import annotations

from fiper_ros.runtime.wiring import missing_matches, unmatched_readers

EMB = "/fiper/observation_embedding"
POLICY, RND_OE, FUSION = "/fiper/policy_node", "/fiper/rnd_oe_node", "/fiper/fusion_node"


def test_a_publisher_must_match_every_managed_reader_and_the_callers_own() -> None:
    diagnostics = {POLICY: {"lifecycle_state": "active", f"matched_subscribers.{EMB}": "1"},
                   RND_OE: {f"matched_publishers.{EMB}": "1"}}
    nodes = (POLICY, RND_OE)
    # matched 1 = the detector; the caller records the topic too: one short
    assert missing_matches(diagnostics, nodes, {EMB: 1}) == [f"{POLICY} to match 2 subscriptions of {EMB} (has 1)"]
    assert missing_matches(diagnostics, nodes, {}) == []
    diagnostics[POLICY][f"matched_subscribers.{EMB}"] = "2"
    assert missing_matches(diagnostics, nodes, {EMB: 1}) == []


def test_a_reader_must_match_a_publisher() -> None:
    diagnostics = {POLICY: {f"matched_subscribers.{EMB}": "1"}, RND_OE: {f"matched_publishers.{EMB}": "0"}}
    assert missing_matches(diagnostics, (POLICY, RND_OE), {}) == [f"{RND_OE} to match a publisher of {EMB}"]


def test_topics_without_a_managed_publisher_and_unlisted_nodes_are_not_checked() -> None:
    diagnostics = {RND_OE: {"matched_publishers./camera/wrist/image_raw": "0"},  # nobody of ours publishes it
                   POLICY: {f"matched_subscribers.{EMB}": "0"}, FUSION: {f"matched_publishers.{EMB}": "0"}}
    assert missing_matches(diagnostics, (RND_OE,), {}) == []
    # the policy published to nobody, but FUSION is not one of the nodes to wire
    assert missing_matches(diagnostics, (POLICY,), {}) == []
    assert missing_matches(diagnostics, (POLICY, FUSION), {}) == [
        f"{FUSION} to match a publisher of {EMB}", f"{POLICY} to match 1 subscriptions of {EMB} (has 0)"]


def test_readers_are_the_nodes_reporting_a_subscription_of_the_topic_and_must_match_every_publisher() -> None:
    record = "/fiper_record"
    diagnostics = {RND_OE: {f"matched_publishers.{EMB}": "1", "matched_publishers./fiper/rollout_events": "0"},
                   record: {f"matched_publishers.{EMB}": "2"},
                   FUSION: {"matched_publishers./fiper/rollout_events": "1"},
                   POLICY: {f"matched_subscribers.{EMB}": "2"}}
    readers = [RND_OE, record]  # sorted: "/fiper/..." before "/fiper_..."
    assert unmatched_readers(diagnostics, EMB, 1) == (readers, [])
    assert unmatched_readers(diagnostics, EMB, 2) == (readers, [f"{RND_OE} to match 2 publishers of {EMB} (has 1)"])
    assert unmatched_readers(diagnostics, EMB, 3) == (readers, [f"{RND_OE} to match 3 publishers of {EMB} (has 1)",
                                                                f"{record} to match 3 publishers of {EMB} (has 2)"])
    assert unmatched_readers(diagnostics, "/fiper/action_chunks", 1) == ([], [])  # nobody reports a reader of it
    assert unmatched_readers({}, EMB, 0) == ([], [])


def test_a_node_without_diagnostics_yet_is_neither_reader_nor_publisher_and_every_topic_is_reported() -> None:
    act = "/fiper/action_chunks"
    diagnostics = {POLICY: {f"matched_subscribers.{EMB}": "1", f"matched_subscribers.{act}": "1"},
                   RND_OE: {f"matched_publishers.{EMB}": "0"}, FUSION: {f"matched_publishers.{act}": "0"}}
    nodes = (POLICY, RND_OE, FUSION, "/fiper/ace_node")  # the ACE node has not reported yet
    assert missing_matches(diagnostics, nodes, {}) == [f"{FUSION} to match a publisher of {act}",
                                                       f"{RND_OE} to match a publisher of {EMB}"]
