"""Common shell of the suite's managed nodes: parameters, autostart, diagnostics, rejections.

Every node is a lifecycle node: ``configure`` loads what it needs (calibration, models), ``activate``
creates its subscriptions. Its parameters are read once, when it is built, into frozen settings
(:mod:`fiper_ros.nodes.settings`): the shell's own in :attr:`FiperNode.shell`, the node's in ``settings`` (a value
the node's builder refuses leaves ``settings`` ``None`` and fails every ``configure`` with the refusal). With the ``autostart`` parameter (default true) the node walks itself to
ACTIVE and retries ``configure`` every ``configure_retry_s`` while it fails (e.g. the calibration is
missing), so it keeps running and says why on ``/diagnostics`` instead of dying.
"""
from __future__ import annotations

import time
import traceback
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.exceptions import ParameterUninitializedException
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from rclpy.serialization import deserialize_message
from rclpy.subscription import Subscription

from fiper_ros.errors import FiperError, one_line
from fiper_ros.interface import qos
from fiper_ros.interface.cdr import CdrError, EncapsulationError, codec
from fiper_ros.interface.conversions import header_view
from fiper_ros.interface.topics import DIAGNOSTICS_TOPIC
from fiper_ros.nodes.graph_watch import PublisherCheck
from fiper_ros.nodes.settings import ShellSettings, shell_settings
from fiper_ros.platform.process import process_age_s
from fiper_ros.runtime.stats import LatencyStats, RateLimitedLog, RateMeter
from fiper_ros.runtime.trusted_publishers import Expected, resolve_node
from fiper_ros.runtime.validation import MALFORMED, InputRejected
from fiper_ros.runtime.wiring import MATCHED_PUBLISHERS, MATCHED_SUBSCRIBERS

#: Topics of ROS itself, left out of the matched-endpoint diagnostics.
INFRASTRUCTURE_TOPICS = ("/rosout", "/parameter_events", DIAGNOSTICS_TOPIC)
#: The log line of a node that reached ACTIVE: :data:`ACTIVE_LOG`, the seconds since its process started, then
#: :data:`ACTIVE_LOG_END` (``make bench-nodes`` reads the seconds).
ACTIVE_LOG, ACTIVE_LOG_END = "ACTIVE", "s after the process started"
#: How often a node that watches its topics' publishers looks at the graph (a second suite: noticed within 1 s).
PUBLISHER_CHECK_PERIOD_S = 0.25


def own_topic(topic: str) -> bool:
    """Whether ``topic`` (fully qualified) is one of the suite's, not ROS's infrastructure or lifecycle events."""
    return not topic.startswith(INFRASTRUCTURE_TOPICS) and not topic.endswith("/transition_event")


def describe(description: str, *, read_only: bool = True, low: float | None = None, high: float | None = None,
             integer: bool = False) -> ParameterDescriptor:
    """A parameter descriptor with an optional range. Read-only unless asked otherwise: the nodes read their
    parameters once into their settings (:func:`parameter_values`) and apply none live (no set-parameters
    callback), so a ``ros2 param set`` is refused with a reason rather than accepted and ignored."""
    descriptor = ParameterDescriptor(description=description, read_only=read_only)
    if low is not None and high is not None:
        if integer:
            descriptor.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=1)]
        else:
            descriptor.floating_point_range = [FloatingPointRange(from_value=float(low), to_value=float(high))]
    return descriptor


def parameter_values(node: Node) -> dict[str, Any]:
    """Every parameter ``node`` has declared, by name, read once (what a settings builder of
    :mod:`fiper_ros.nodes.settings` takes); one declared with a type and no value is ``None``."""
    values: dict[str, Any] = {}
    for name in node.list_parameters([], 0).names:
        try:
            values[name] = node.get_parameter(name).value
        except ParameterUninitializedException:
            values[name] = None
    return values


_DIAGNOSTICS = codec(DiagnosticArray)
_STATUS_VIEW = codec(DiagnosticStatus).view
_KEY_VALUE_VIEW = codec(KeyValue).view


def diagnostic_array(node: Node, level: bytes, message: str, values: dict[str, str]) -> bytes:
    """The one-status /diagnostics message of ``node`` (``name`` = ``fiper: <fully qualified name>``), serialized by
    the wire codec (a publisher takes the bytes), as the suite's other messages are."""
    name = node.get_fully_qualified_name()
    status = _STATUS_VIEW(level=level, name=f"fiper: {name}", message=message, hardware_id=name,
                          values=[_KEY_VALUE_VIEW(key, value) for key, value in values.items()])
    return _DIAGNOSTICS.encode(_DIAGNOSTICS.view(header=header_view(node.get_clock().now().nanoseconds),
                                                 status=[status]))


class FiperNode(LifecycleNode):
    """Lifecycle node with autostart, ``/diagnostics``, QoS-event and rejection accounting."""

    def __init__(self, name: str, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self.declare_parameter("autostart", True, describe("walk to ACTIVE on start-up", read_only=True))
        self.declare_parameter("configure_retry_s", 2.0,
                               describe("retry period of a failed configure (autostart)", low=0.1, high=3600.0))
        self.declare_parameter("diagnostics_period_s", 1.0,
                               describe("period of /diagnostics messages", read_only=True, low=0.05, high=60.0))
        self.declare_parameter("log_period_s", 10.0,
                               describe("at most one log line per rejection reason in this period", low=0.0, high=3600.0))
        #: The shell's settings (autostart, retry, diagnostics and log periods).
        self.shell: ShellSettings = shell_settings(parameter_values(self))
        self.settings: Any = None
        """The node's settings (:meth:`settle`; ``None`` until built, or when a value was refused)."""
        self.settings_refusal: FiperError | None = None
        """Why the node's builder refused its parameters (every configure fails with it)."""
        self.configure_failures = 0
        """Configure attempts that failed (on /diagnostics: ``configure_failures``)."""
        self.rejected: Counter[str] = Counter()
        self.qos_incompatible: Counter[str] = Counter()
        self.latency = LatencyStats()
        self.rates: dict[str, RateMeter] = {}
        self.config_error = ""
        self._log_limit = RateLimitedLog(self.shell.log_period_s)
        #: Wall-clock (steady) time for what must not stall with a paused /clock: heartbeats, retries.
        self.steady = Clock(clock_type=ClockType.STEADY_TIME)
        #: The node clock's handle (:meth:`now_ns`); the clock object is the node's for its life, sim time included.
        self._clock_handle = self.get_clock().handle
        self._diagnostics = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, qos.DIAGNOSTICS)
        self.create_timer(self.shell.diagnostics_period_s, self.publish_diagnostics, clock=self.steady)
        self.publisher_check: PublisherCheck | None = None
        self._autostart_timer = None
        if self.shell.autostart:
            self._autostart_timer = self.create_timer(0.0, self._autostart, clock=self.steady)

    # lifecycle ----------------------------------------------------------------------------------------
    def _autostart(self) -> None:
        self._autostart_timer.cancel()
        state = self.lifecycle_state()
        if state == "unconfigured":
            if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                self._autostart_timer = self.create_timer(self.shell.configure_retry_s,
                                                          self._autostart, clock=self.steady)
                return
            state = "inactive"
        if state == "inactive":
            self.trigger_activate()

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Load what the node needs. A failure keeps the node alive, UNCONFIGURED, counted
        (:attr:`configure_failures`) and said on /diagnostics as ``configure failed: REASON``: a user error (a
        :class:`~fiper_ros.errors.FiperError`: a refused parameter value, a calibration that is missing, damaged or
        does not fit the node's parameters) in its one line; any other exception (a defect) with its type, and its
        traceback logged."""
        try:
            if self.settings_refusal is not None:
                raise self.settings_refusal
            self.configure()
        except FiperError as error:
            return self._configure_failed(one_line(error))
        except Exception as error:  # noqa: BLE001 - a defect while loading: reported with its traceback, never fatal
            self.get_logger().error(f"configure raised:\n{traceback.format_exc()}")
            return self._configure_failed(one_line(f"{type(error).__name__}: {error}"))
        self.config_error = ""
        return TransitionCallbackReturn.SUCCESS

    def _configure_failed(self, reason: str) -> TransitionCallbackReturn:
        self.configure_failures += 1
        message = f"configure failed: {reason}"
        if message != self.config_error:
            self.get_logger().error(message)
        self.config_error = message
        return TransitionCallbackReturn.FAILURE

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Create subscriptions (inputs start flowing); say so, with the seconds since the process started."""
        self.activate()
        result = super().on_activate(state)
        self.get_logger().info(f"{ACTIVE_LOG} {process_age_s():.2f} {ACTIVE_LOG_END}")
        return result

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Destroy subscriptions (inputs stop)."""
        self.deactivate()
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Forget what configure loaded."""
        self.cleanup()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Nothing to release beyond what rclpy releases."""
        return TransitionCallbackReturn.SUCCESS

    def configure(self) -> None:
        """Load calibration / models; raise to fail the transition."""

    def activate(self) -> None:
        """Create subscriptions."""

    def deactivate(self) -> None:
        """Destroy subscriptions."""

    def cleanup(self) -> None:
        """Drop loaded state."""

    # helpers for subclasses ---------------------------------------------------------------------------
    def settle(self, build: Callable[[Mapping[str, Any]], Any]) -> bool:
        """Read the declared parameters once into :attr:`settings` with the node's builder ``build``, after the
        node declared them all; whether it built them. A value it refuses (a :class:`~fiper_ros.nodes.errors.NodeError`,
        or any other :class:`~fiper_ros.errors.FiperError` of what it calls) leaves :attr:`settings` ``None``: the node
        then builds nothing that needs them, and every configure fails with the refusal, reported on /diagnostics."""
        try:
            self.settings = build(parameter_values(self))
        except FiperError as error:
            self.settings_refusal = error
            return False
        return True

    def lifecycle_state(self) -> str:
        """Label of the current lifecycle state ("unconfigured", "inactive", "active", ...)."""
        return self._state_machine.current_state[1]  # rclpy offers no public getter

    def now_ns(self) -> int:
        """The node clock (sim time under ``use_sim_time``) in nanoseconds: what ``get_clock().now()`` reads, without
        the ``Time`` object it builds (a quarter of the cost; every message reads the clock)."""
        handle = self._clock_handle
        with handle:
            return handle.get_now().nanoseconds

    def tick(self, stream: str, now_ns: int) -> None:
        """Count one message of ``stream``, arrived at ``now_ns`` (the node clock), for the rate diagnostics."""
        meter = self.rates.get(stream)
        if meter is None:
            meter = self.rates[stream] = RateMeter()
        meter.tick(now_ns)

    def reject(self, error: InputRejected) -> None:
        """Count a rejected message and log it, at most once per reason and log period."""
        self.rejected[error.reason] += 1
        if self._log_limit.should_log(error.reason, self.now_ns()):
            suppressed = self._log_limit.suppressed.pop(error.reason, 0)
            more = f" ({suppressed} more since the last report)" if suppressed else ""
            self.get_logger().warning(f"rejected message: {error}{more}")

    def create_wire_subscription(self, msg_type: Any, topic: str, handler: Callable[[Any], None],
                                 qos_profile: QoSProfile, **kwargs: Any) -> Subscription:
        """A subscription to ``topic`` that takes the CDR bytes (``raw=True``) and hands ``handler`` their view
        (:mod:`fiper_ros.interface.cdr`), read like the message: rclpy's message objects cost a node more than
        its own work per message at high rates. Bytes of another encapsulation than plain
        little-endian CDR are read by rclpy; bytes that are no message of the type are rejected as
        ``malformed``."""
        wire = codec(msg_type)

        def on_bytes(data: bytes) -> None:
            try:
                msg = wire.decode(data)
            except EncapsulationError:
                msg = deserialize_message(data, msg_type)
            except CdrError as error:
                self.reject(InputRejected(MALFORMED, f"{topic}: {error}"))
                return
            handler(msg)

        return self.create_subscription(msg_type, topic, on_bytes, qos_profile, raw=True, **kwargs)

    def subscription_events(self, topic: str, extra: Callable[[Any], None] | None = None) -> SubscriptionEventCallbacks:
        """Event callbacks that count QoS incompatibilities on ``topic`` (and optional liveliness)."""
        return SubscriptionEventCallbacks(incompatible_qos=lambda info: self._incompatible(topic, info),
                                          liveliness=extra)

    def publisher_events(self, topic: str) -> PublisherEventCallbacks:
        """Event callbacks that count QoS incompatibilities on ``topic``."""
        return PublisherEventCallbacks(incompatible_qos=lambda info: self._incompatible(topic, info))

    def _incompatible(self, topic: str, info: Any) -> None:
        self.qos_incompatible[topic] += 1
        self.get_logger().error(
            f"QoS incompatible with a peer on {topic} (policy id {info.last_policy_kind}); messages are not delivered"
        )

    def watch_publishers(self, on_change: Callable[[], None] | None = None) -> PublisherCheck:
        """Check the graph's publishers of this node's topics (:meth:`expected_publishers`) every
        ``PUBLISHER_CHECK_PERIOD_S``; an unexpected one is an ERROR on /diagnostics (docs/reliability.md,
        "Who may speak")."""
        # No default value: an empty list would be typed as bytes; unset, it reads as the empty list (any node).
        self.declare_parameter("allowed_publishers", Parameter.Type.STRING_ARRAY, describe(
            "nodes that may publish this node's inputs, one publisher each (relative names: in its namespace); "
            "unset or empty: any node, but one publisher per input topic", read_only=True))
        self.publisher_check = PublisherCheck(self, self.expected_publishers, PUBLISHER_CHECK_PERIOD_S, on_change)
        return self.publisher_check

    def allowed(self, names: Iterable[str]) -> frozenset[str]:
        """The fully qualified names of the nodes ``names`` lists (relative: in this node's namespace)."""
        return frozenset(resolve_node(name, self.get_namespace()) for name in names)

    def expected_publishers(self) -> list[Expected]:
        """What the node expects of its topics' publishers: for each input (a subscription now open) one
        publisher, or one per node of ``allowed_publishers`` if that is set (and no other node); for each output
        only this node (a second publisher of the same name is for the topic's consumer to tell: only it sees
        the liveliness)."""
        allowed = self.allowed(self.settings.allowed_publishers if self.settings is not None else ())
        me = frozenset({self.get_fully_qualified_name()})
        inputs = {s.topic_name: Expected(s.topic_name, allowed) for s in self.subscriptions if own_topic(s.topic_name)}
        outputs = {p.topic_name: Expected(p.topic_name, me, limited=False) for p in self.publishers
                   if own_topic(p.topic_name)}
        return list((inputs | outputs).values())

    def timed(self) -> float:
        """Start a latency measurement; pass the result to :meth:`record_latency`."""
        return time.perf_counter()

    def record_latency(self, started: float) -> float:
        """Record and return the milliseconds since ``started``."""
        latency_ms = (time.perf_counter() - started) * 1e3
        self.latency.add(latency_ms)
        return latency_ms

    # diagnostics --------------------------------------------------------------------------------------
    def diagnostic_values(self) -> dict[str, str]:
        """Node-specific key/values for /diagnostics."""
        return {}

    def matched_endpoints(self) -> dict[str, str]:
        """DDS-level matches of the node's own topics (not ROS's infrastructure): per publisher the
        subscriptions it has matched, per subscription the publishers (read by
        :func:`fiper_ros.runtime.wiring.missing_matches`)."""
        values = {f"{MATCHED_SUBSCRIBERS}{p.topic_name}": str(p.get_subscription_count())
                  for p in self.publishers if own_topic(p.topic_name)}
        values |= {f"{MATCHED_PUBLISHERS}{s.topic_name}": str(s.get_publisher_count())
                   for s in self.subscriptions if own_topic(s.topic_name)}
        return dict(sorted(values.items()))

    def diagnostic_level(self) -> tuple[int, str]:
        """Worst condition of the node and its message."""
        if self.qos_incompatible:
            return DiagnosticStatus.ERROR, "QoS incompatible: " + ", ".join(sorted(self.qos_incompatible))
        if self.config_error:
            return DiagnosticStatus.ERROR, self.config_error
        if self.publisher_check is not None and self.publisher_check.watch.findings:
            return DiagnosticStatus.ERROR, self.publisher_check.error()
        state = self.lifecycle_state()
        if state != "active":
            return DiagnosticStatus.WARN, f"lifecycle state {state}"
        if self.rejected:
            return DiagnosticStatus.WARN, "rejected input: " + ", ".join(f"{k}={v}" for k, v in sorted(self.rejected.items()))
        return DiagnosticStatus.OK, "running"

    def publish_diagnostics(self) -> None:
        """Publish this node's DiagnosticStatus on /diagnostics."""
        now = self.now_ns()
        level, message = self.diagnostic_level()
        values = {
            "lifecycle_state": self.lifecycle_state(),
            "configure_failures": str(self.configure_failures),
            "latency_p50_ms": f"{self.latency.percentile(50):.3f}",
            "latency_p99_ms": f"{self.latency.percentile(99):.3f}",
        }
        values |= {f"rate_hz.{name}": f"{meter.rate(now):.2f}" for name, meter in sorted(self.rates.items())}
        values |= {f"rejected.{reason}": str(n) for reason, n in sorted(self.rejected.items())}
        values |= {f"qos_incompatible.{topic}": str(n) for topic, n in sorted(self.qos_incompatible.items())}
        values |= self.matched_endpoints()
        if self.publisher_check is not None:
            values |= self.publisher_check.diagnostic_values()
        values |= self.diagnostic_values()
        self._diagnostics.publish(diagnostic_array(self, level, message, values))
