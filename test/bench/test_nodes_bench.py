"""``make bench-nodes`` says where the steps of a rate it could not sustain went, from the nodes' /diagnostics, and
asks a node's lifecycle state again when a request goes unanswered."""
from __future__ import annotations

import time

import pytest

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


def test_a_get_state_request_left_unanswered_is_asked_again(ros_domain: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """A benchmark run once waited 120 s for a reply that never came, every node ACTIVE (docs/benchmarks.md); the
    driver now asks again after GET_STATE_TIMEOUT_S. Here the server sits on its first request past the start-up
    timeout and answers the next at once: without the second request the driver would time out."""
    import threading

    import rclpy
    from lifecycle_msgs.msg import State
    from lifecycle_msgs.srv import GetState
    from rclpy.callback_groups import ReentrantCallbackGroup
    from rclpy.context import Context
    from rclpy.executors import MultiThreadedExecutor

    from fiper_ros.bench import nodes_bench

    monkeypatch.setattr(nodes_bench, "STARTUP_TIMEOUT_S", 8.0)
    context = Context()
    rclpy.init(context=context, domain_id=ros_domain)
    server = rclpy.create_node("slow_node", namespace="/fiper", context=context)
    requests: list[float] = []
    release = threading.Event()

    def get_state(_: GetState.Request, response: GetState.Response) -> GetState.Response:
        requests.append(time.monotonic())
        if len(requests) == 1:
            release.wait(30)  # the first request stays unanswered until the test ends
        response.current_state.id = State.PRIMARY_STATE_ACTIVE
        return response

    server.create_service(GetState, "slow_node/get_state", get_state, callback_group=ReentrantCallbackGroup())
    executor = MultiThreadedExecutor(num_threads=2, context=context)
    executor.add_node(server)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    driver = nodes_bench.PolicyStepDriver(nodes_bench.SHAPES[0], ros_domain)
    try:
        began = time.monotonic()
        driver.wait_active(["/fiper/slow_node"])
        assert len(requests) >= 2
        # asked again only after the timeout (sent at least GET_STATE_TIMEOUT_S after the first, which was sent after
        # `began`; the arrivals' own gap may be shorter, when the first request was delivered late)
        assert requests[1] - began >= nodes_bench.GET_STATE_TIMEOUT_S
        assert time.monotonic() - began < nodes_bench.STARTUP_TIMEOUT_S
    finally:
        release.set()
        driver.close()
        executor.shutdown()
        server.destroy_node()
        rclpy.try_shutdown(context=context)
