"""Test harness of the bridge node: the bridge as its own process, and a client node in the test's
domain that resets, halts, sends action commands and groups the observations by stamp.

``run_expert_rollout`` drives a whole rollout over DDS with the task's scripted expert. The expert
needs privileged state, which the bridge does not publish: the harness keeps a *shadow* environment
of the same ``(task, scenario, seed)`` in the test process, computes each chunk by stepping the
shadow with the expert's (float32-rounded) actions, and checks after every observation tick that the
bridge's proprioception equals the shadow's, bit for bit (MuJoCo is deterministic).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Image, JointState
from std_srvs.srv import Trigger

from fiper_msgs.msg import ActionCommand, RolloutEvent
from fiper_msgs.srv import ResetRollout
from fiper_ros.interface import qos
from fiper_ros.interface.conversions import float_array, stamp_ns, to_stamp
from helpers.dds import spawn_python, stop
from helpers.spin import spin_until
from sim_bridge.bridge_session import ACTION_SPACES
from sim_bridge.env import make_env
from sim_bridge.experts import make_expert

IMAGE_TOPICS = {"wrist_rgb": "/camera/wrist/image_raw", "third_rgb": "/camera/third/image_raw"}


def image_array(msg: Image) -> np.ndarray:
    """An rgb8 Image as a (height, width, 3) uint8 array."""
    return np.frombuffer(msg.data, dtype=np.uint8).reshape(msg.height, msg.width, 3)


@dataclass
class Tick:
    """The observation messages published with one stamp."""

    stamp: int
    msgs: dict[str, Any] = field(default_factory=dict)

    def complete(self, images: bool) -> bool:
        """Whether the proprioception (and both images) arrived."""
        return "proprio" in self.msgs and (not images or all(k in self.msgs for k in IMAGE_TOPICS))

    def observation(self) -> dict[str, np.ndarray]:
        """The tick as an environment observation (``proprio`` float32, images uint8)."""
        obs = {key: image_array(self.msgs[key]) for key in IMAGE_TOPICS if key in self.msgs}
        obs["proprio"] = np.asarray(self.msgs["proprio"].position, dtype=np.float32)
        return obs


class BridgeClient(Node):
    """The policy's side of the bridge's topics and services, plus /clock and /diagnostics."""

    def __init__(self, context: Context) -> None:
        super().__init__("bridge_test_client", context=context)
        self.ticks: dict[int, Tick] = {}
        self.joint_states: list[JointState] = []
        self.events: list[RolloutEvent] = []
        self.clock: list[int] = []
        self.diagnostics: dict[str, str] = {}
        self.actions = self.create_publisher(ActionCommand, "/sim/action", qos.INPUT)
        self.reset_client = self.create_client(ResetRollout, "/sim/reset")
        self.halt_client = self.create_client(Trigger, "/sim/halt")
        self.observation_subs = [
            self.create_subscription(JointState, "/sim/proprio", lambda m: self._add("proprio", m), qos.INPUT),
            self.create_subscription(JointState, "/joint_states", self._on_joint_state, qos.INPUT),
            *(self.create_subscription(Image, topic, lambda m, k=key: self._add(k, m), qos.INPUT)
              for key, topic in IMAGE_TOPICS.items()),
        ]
        self.create_subscription(RolloutEvent, "/fiper/rollout_events", self.events.append, qos.EVENT)
        self.create_subscription(Clock, "/clock", lambda m: self.clock.append(stamp_ns(m.clock)),
                                 QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
        self.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, qos.DIAGNOSTICS)

    def _add(self, key: str, msg: Any) -> None:
        stamp = stamp_ns(msg.header.stamp)
        self.ticks.setdefault(stamp, Tick(stamp)).msgs[key] = msg

    def _on_joint_state(self, msg: JointState) -> None:
        self.joint_states.append(msg)
        self._add("joint_states", msg)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith("fiper: ") and status.name.endswith("bridge_node"):
                level = status.level[0] if isinstance(status.level, bytes) else int(status.level)
                self.diagnostics = {"level": str(level), "message": status.message} | {
                    kv.key: kv.value for kv in status.values}

    def events_of(self, rollout_id: int) -> list[RolloutEvent]:
        """START / END events of one rollout, in arrival order."""
        return [e for e in self.events if e.rollout_id == rollout_id]

    def command(self, rollout_id: int, step: int, actions: np.ndarray, action_space: str,
                stamp: int = 0, observation_history: int = 0) -> ActionCommand:
        """An ActionCommand of an ``(n, D)`` array (data as given, also when inconsistent)."""
        actions = np.atleast_2d(actions)
        msg = ActionCommand(rollout_id=rollout_id, step=step, num_actions=actions.shape[0],
                            action_dim=actions.shape[1], data=float_array(actions.ravel()), action_space=action_space,
                            observation_history=observation_history)
        msg.header.stamp = to_stamp(stamp)
        return msg


class BridgeHarness:
    """A bridge process with the given parameters and a client on a private executor, both in ``domain``."""

    def __init__(self, domain: int, **params: Any) -> None:
        self.images = bool(params.get("images", True))
        args = ["-m", "sim_bridge.bridge_node", "--ros-args"]
        for key, value in params.items():
            args += ["-p", f"{key}:={str(value).lower() if isinstance(value, bool) else value}"]
        self.proc = spawn_python(args, domain)
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.client = BridgeClient(self.context)
        self.executor.add_node(self.client)
        self.output = ""

    def spin_until(self, condition: Callable[[], bool], timeout: float = 10.0) -> bool:
        """Spin the client until ``condition`` holds or ``timeout`` seconds passed."""
        return spin_until(self.executor, condition, timeout)

    def wait_ready(self, timeout: float = 60.0) -> None:
        """Wait until the bridge is active and every topic is matched both ways."""
        client = self.client
        subs = client.observation_subs if self.images else client.observation_subs[:2]
        ready = self.spin_until(lambda: client.reset_client.service_is_ready() and client.halt_client.service_is_ready()
                                and client.actions.get_subscription_count() >= 1
                                and all(s.get_publisher_count() >= 1 for s in subs)
                                and client.diagnostics.get("lifecycle_state") == "active", timeout)
        assert ready, f"bridge not ready: {client.diagnostics}\n{self.close()}"

    def call(self, cli: Any, request: Any, timeout: float = 20.0) -> Any:
        """Call a service and wait for the response."""
        future = cli.call_async(request)
        assert self.spin_until(future.done, timeout), f"no response from {cli.srv_name}"
        return future.result()

    def reset(self, task: str, scenario: str, seed: int) -> ResetRollout.Response:
        """Call /sim/reset."""
        return self.call(self.client.reset_client, ResetRollout.Request(task=task, scenario=scenario, seed=seed))

    def halt(self) -> Trigger.Response:
        """Call /sim/halt."""
        return self.call(self.client.halt_client, Trigger.Request())

    def next_tick(self, after: int, timeout: float = 10.0) -> Tick:
        """The first complete observation tick stamped later than ``after``."""
        def found() -> Tick | None:
            later = [t for s, t in self.client.ticks.items() if s > after and t.complete(self.images)]
            return min(later, key=lambda t: t.stamp) if later else None
        assert self.spin_until(lambda: found() is not None, timeout), f"no observation after {after}"
        tick = found()
        assert tick is not None
        return tick

    def event_of(self, rollout_id: int, kind: int, timeout: float = 10.0) -> RolloutEvent:
        """The START or END (``kind``) event of ``rollout_id``."""
        def event() -> RolloutEvent | None:
            return next((e for e in self.client.events_of(rollout_id) if e.event == kind), None)
        assert self.spin_until(lambda: event() is not None, timeout), f"no event {kind} of rollout {rollout_id}"
        found = event()
        assert found is not None
        return found

    def end_of(self, rollout_id: int, timeout: float = 10.0) -> RolloutEvent:
        """The END event of ``rollout_id``."""
        return self.event_of(rollout_id, RolloutEvent.EVENT_END, timeout)

    def first_tick(self, rollout_id: int, timeout: float = 10.0) -> Tick:
        """The first observation of ``rollout_id``: the tick stamped like its START event."""
        stamp = stamp_ns(self.event_of(rollout_id, RolloutEvent.EVENT_START, timeout).header.stamp)
        assert self.spin_until(lambda: stamp in self.client.ticks and self.client.ticks[stamp].complete(self.images),
                               timeout), f"no first observation of rollout {rollout_id}"
        return self.client.ticks[stamp]

    def close(self) -> str:
        """Stop the bridge and the client; returns the bridge's output."""
        if self.context.ok():
            self.executor.remove_node(self.client)
            self.client.destroy_node()
            self.executor.shutdown()
            rclpy.try_shutdown(context=self.context)
        self.output += stop(self.proc)
        return self.output


@dataclass
class ExpertRun:
    """What a rollout driven by the scripted expert produced."""

    rollout_id: int
    ticks: list[Tick]
    end: RolloutEvent
    shadow_info: dict[str, Any]


def run_expert_rollout(harness: BridgeHarness, task: str, scenario: str, seed: int) -> ExpertRun:
    """Reset the bridge and drive one rollout with the task's expert until END."""
    response = harness.reset(task, scenario, seed)
    assert response.success, response.message
    shadow = make_env(task, scenario, seed, images=False)
    shadow.reset()
    expert = make_expert(shadow)
    tick = harness.first_tick(response.rollout_id)
    ticks = [tick]
    step = 0
    while True:
        np.testing.assert_array_equal(tick.observation()["proprio"], shadow.observation()["proprio"])
        chunk = []
        for _ in range(shadow.exec_steps):
            action = np.asarray(expert.act(shadow.state()), dtype=np.float32)
            shadow.step(action.astype(np.float64))
            chunk.append(action)
            if shadow.done:
                break
        harness.client.actions.publish(harness.client.command(response.rollout_id, step, np.array(chunk),
                                                              ACTION_SPACES[task], tick.stamp))
        step += 1
        if shadow.done:
            break
        tick = harness.next_tick(tick.stamp)
        ticks.append(tick)
    return ExpertRun(response.rollout_id, ticks, harness.end_of(response.rollout_id), shadow.info())
