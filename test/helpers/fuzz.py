"""Property-based fuzzing of the node shells, in process: settings, strategies, a publication recorder.

The fuzz tests (``test/nodes/test_fuzz.py``, ``test/sim_ros/test_fuzz.py``) build the real node classes in a
private rclpy context (``autostart`` off, then configure and activate by hand), call their subscription
callbacks directly with generated messages, one at a time, and check properties after every call. Direct
calls rather than DDS: every message reaches the callback it was generated for, in the generated order, and
an example runs in milliseconds. What a node publishes is recorded by wrapping its publisher's ``publish``
(the real publish still runs).

Hypothesis runs deterministically (``derandomize``: the examples follow from the test's code alone), keeps no
example database, and has no per-example deadline (a loaded machine must not fail a test). Nodes are built
afresh for every example, so that an example's outcome depends on that example alone (and shrinks); loading a
calibration (and a policy) is what takes the time there, so a fuzz test loads each once
(:func:`load_once`): the nodes get the very objects ``load_calibration``, ``PinocchioFK`` or ``Policy.load``
returned for the same files.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import pytest
import rclpy
from builtin_interfaces.msg import Time
from hypothesis import HealthCheck, Phase, settings
from hypothesis import strategies as st
from rclpy.context import Context
from rclpy.lifecycle import TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message

from fiper_ros.interface.cdr import codec

UINT8_MAX = 2**8 - 1
UINT32_MAX = 2**32 - 1
UINT64_MAX = 2**64 - 1
INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1
#: The largest finite float32.
FLOAT32_MAX = float(np.finfo(np.float32).max)

#: Settings of every fuzz test (:func:`fuzz`). No shrink phase: with nodes in the loop an example costs 0.1-1 s
#: and shrinking a failing one took over five minutes (hypothesis then gives up anyway); a failure is reported
#: as generated, with its compact message log (``note``).
FUZZ = settings(derandomize=True, database=None, deadline=None, print_blob=False,
                phases=[Phase.explicit, Phase.generate],
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.function_scoped_fixture])


def fuzz(max_examples: int) -> settings:
    """The fuzz tests' settings with ``max_examples`` examples (each test's own, for its cost per example)."""
    return settings(FUZZ, max_examples=max_examples)


def _uint(bits: int) -> st.SearchStrategy[int]:
    top = 2**bits - 1
    return st.one_of(st.sampled_from([0, 1, top - 1, top, 2 ** (bits - 1)]), st.integers(0, top))


# Strategies are built once here: hypothesis validates every new strategy object, which costs more than the
# draws when a strategy is made per message.
#: Unsigned integers, biased to their extremes.
UINT8, UINT32, UINT64 = _uint(8), _uint(32), _uint(64)
#: Any float32 value: NaN, infinities, subnormals, the largest finite ones.
FLOAT32 = st.one_of(st.sampled_from([math.nan, math.inf, -math.inf, FLOAT32_MAX, -FLOAT32_MAX, 0.0, -0.0]),
                    st.floats(-FLOAT32_MAX, FLOAT32_MAX, width=32))
#: Short arbitrary strings (any code point a ROS string can carry).
TEXT = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=12)
#: Any ``builtin_interfaces/Time``: ``sec`` int32, ``nanosec`` uint32 (also beyond 1e9).
STAMP = st.builds(Time, sec=st.one_of(st.sampled_from([0, 1, INT32_MIN, INT32_MAX]), st.integers(INT32_MIN, INT32_MAX)),
                  nanosec=UINT32)
_NEAR = st.sampled_from([0, 0, 0, -1, 1, 2, 101, 102])
_FAR = st.one_of(st.integers(0, 30), UINT32)
_PAYLOADS = st.sampled_from(["valid", "valid", "at_bound", "nan", "inf", "huge", "short", "long", "empty", "oversize",
                             "any"])
_SIGN = st.sampled_from([1.0, -1.0])
#: True 3 times in 4: for "mostly the valid (or expected) value, else anything".
MOSTLY = st.sampled_from([True, True, True, False])


def draw_step(draw: st.DrawFn, expected: int) -> int:
    """A uint32 policy step, mostly near the ``expected`` next one (in order, repeated, a small gap, behind,
    just within and just beyond the default ``max_step_gap`` of 100), else small or any uint32."""
    if draw(MOSTLY):
        step = expected + draw(_NEAR)
        if 0 <= step <= UINT32_MAX:
            return step
    return draw(_FAR)


def draw_payload(draw: st.DrawFn, valid: np.ndarray, max_elements: int, max_abs: float) -> tuple[np.ndarray, bool]:
    """A float32 array standing in for the valid ``valid`` one, and whether its content is still valid.

    Valid: ``valid`` itself, or with values at exactly ``+-max_abs``. Not: NaN, infinities or magnitudes
    beyond ``max_abs`` at some positions, too few or too many values, none, more than ``max_elements``,
    or any list of float32 values (valid only if it happens to have the right size and values).
    """
    n = valid.size
    flat = valid.astype(np.float32).ravel().copy()
    kind = draw(_PAYLOADS)
    if kind == "valid":
        return flat, True
    if kind in ("at_bound", "nan", "inf", "huge"):
        above = float(np.nextafter(np.float32(max_abs), np.float32(np.inf)))
        for _ in range(draw(st.integers(1, 3))):
            magnitude = {"at_bound": max_abs, "nan": math.nan, "inf": math.inf}.get(kind)
            if magnitude is None:
                magnitude = draw(st.floats(above, FLOAT32_MAX, width=32))
            flat[draw(st.integers(0, n - 1))] = draw(_SIGN) * magnitude
        return flat, kind == "at_bound"
    if kind == "short":
        return flat[: draw(st.integers(1, n - 1))], False
    if kind == "long":
        return np.concatenate([flat, flat[: draw(st.integers(1, n))]]), False
    if kind == "empty":
        return np.zeros(0, np.float32), False
    if kind == "oversize":
        return np.resize(flat, max_elements + 1), False
    values = np.asarray(draw(st.lists(FLOAT32, max_size=min(2 * n, 40))), dtype=np.float32)
    ok = values.size == n and bool(np.isfinite(values).all()) and bool((np.abs(values) <= max_abs).all())
    return values, ok


def load_once(monkeypatch: pytest.MonkeyPatch, module: Any, name: str) -> None:
    """Make ``module.name`` (a loader such as ``load_calibration``) load once per arguments and hand out that
    result."""
    load = getattr(module, name)
    loaded: dict[tuple[str, ...], Any] = {}

    def load_or_reuse(*args: Any) -> Any:
        key = tuple(str(a) for a in args)
        if key not in loaded:
            loaded[key] = load(*args)
        return loaded[key]

    monkeypatch.setattr(module, name, load_or_reuse)


#: Keyword arguments of a fuzzed node: no parameter services (rclpy's, not the node's; they cost most of the
#: time of building a node).
NODE_KWARGS: dict[str, Any] = {"start_parameter_services": False}


def node_params(**params: Any) -> list[Parameter]:
    """Parameter overrides of a fuzzed node: no autostart (the test configures and activates it), and ``params``."""
    return [Parameter("autostart", value=False), *(Parameter(k, value=v) for k, v in params.items())]


def bring_up(node: Any) -> Any:
    """Configure and activate a :class:`~fiper_ros.nodes.base.FiperNode` by hand; returns it."""
    assert node.trigger_configure() == TransitionCallbackReturn.SUCCESS, node.config_error
    assert node.trigger_activate() == TransitionCallbackReturn.SUCCESS
    assert node.lifecycle_state() == "active"
    return node


@contextmanager
def private_context(domain: int) -> Iterator[Context]:
    """An rclpy context of its own in ``domain`` (the nodes' DDS entities exist; nothing is spun)."""
    context = Context()
    rclpy.init(context=context, domain_id=domain)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


def callbacks(node: Any) -> dict[str, Callable[[Any], None]]:
    """The node's subscription callbacks by topic: what rclpy would call for a message on that topic. A raw
    subscription's (the wire codec's, issue #24) takes a message or a codec view and gets its bytes: rclpy's own
    serialization of a message, the codec's of a view."""
    def raw(subscription: Any) -> Callable[[Any], None]:
        def call(msg: Any) -> None:
            if isinstance(msg, subscription.msg_type):
                msg = serialize_message(msg)
            elif not isinstance(msg, bytes):
                msg = codec(subscription.msg_type).encode(msg)
            subscription.callback(msg)
        return call

    return {s.topic_name: raw(s) if s.raw else s.callback for s in node.subscriptions}


def record(publisher: Any, *then: Callable[[Any], None]) -> list[Any]:
    """Every message ``publisher`` publishes from now on, in order (what it publishes as bytes, as the wire
    codec's view of them); each is also passed to ``then`` (another node's callback, a checker) after the real
    publish ran."""
    sent: list[Any] = []
    publish: Callable[[Any], None] = publisher.publish

    def publish_and_pass_on(msg: Any) -> None:
        publish(msg)
        if isinstance(msg, bytes):
            msg = codec(publisher.msg_type).decode(msg)
        sent.append(msg)
        for call in then:
            call(msg)

    publisher.publish = publish_and_pass_on
    return sent
