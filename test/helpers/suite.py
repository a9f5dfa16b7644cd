"""In-process harness for node tests: a private rclpy context in the test's domain, the FIPER nodes,
and a driver node that publishes rollouts and collects alarms, scores and diagnostics."""
from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from fiper_msgs.msg import ActionChunkBatch, FailureAlarm, ObservationEmbedding, RolloutEvent, Score
from fiper_ros.core.monitor import RolloutPrediction
from fiper_ros.core.rollout import Rollout
from fiper_ros.interface import qos
from fiper_ros.interface.conversions import action_batch_msg, embedding_msg, rollout_event_msg
from helpers.spin import spin_until

STEP_NS = 100_000_000  # 10 Hz policy
STATE = {FailureAlarm.STATE_OK: "ok", FailureAlarm.STATE_ALARM: "alarm", FailureAlarm.STATE_UNKNOWN: "unknown"}


def assert_as_the_oracle(alarms: dict[int, FailureAlarm], prediction: RolloutPrediction) -> None:
    """The per-step verdicts are the offline oracle's: state (latched), flags, windowed scores and thresholds."""
    latched = np.logical_or.accumulate(prediction.alarms)
    assert sorted(alarms) == list(range(len(latched)))
    for t, msg in alarms.items():
        assert STATE[msg.state] == ("alarm" if latched[t] else "ok"), (t, msg)
        traces = prediction.detectors
        assert list(msg.detectors) == list(traces), t
        assert list(msg.exceeded) == [bool(trace.exceeded[t]) for trace in traces.values()], t
        assert list(msg.eta) == [np.float32(trace.windowed[t]) for trace in traces.values()], t
        assert list(msg.gamma) == [np.float32(trace.thresholds[t]) for trace in traces.values()], t
        for name, exceeded, eta, gamma in (("rnd_oe", "obs_exceeded", "eta_obs", "gamma_obs"),
                                           ("ace", "act_exceeded", "eta_act", "gamma_act")):
            if name in traces:  # FIPER's pair also fills the pair's fields
                trace = traces[name]
                assert (getattr(msg, exceeded), getattr(msg, eta), getattr(msg, gamma)) == (
                    bool(trace.exceeded[t]), np.float32(trace.windowed[t]), np.float32(trace.thresholds[t])), t


class PolicySideNode(Node):
    """Publishes the policy side of the suite's topics and records everything the suite says."""

    def __init__(self, context: Context) -> None:
        super().__init__("test_driver", namespace="/fiper", context=context)
        self.embeddings = self.create_publisher(ObservationEmbedding, "observation_embedding", qos.INPUT)
        self.batches = self.create_publisher(ActionChunkBatch, "action_chunks", qos.INPUT)
        self.events = self.create_publisher(RolloutEvent, "rollout_events", qos.EVENT)
        self.alarms: list[FailureAlarm] = []
        self.scores: list[Score] = []
        self.diagnostics: dict[str, dict[str, str]] = {}
        self.create_subscription(FailureAlarm, "alarm", self.alarms.append, qos.ALARM_EVERY)
        for detector in ("rnd_oe", "ace"):
            self.create_subscription(Score, f"scores/{detector}", self.scores.append, qos.SCORE_SUB)
        self.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, qos.DIAGNOSTICS)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            self.diagnostics[status.name] = {"level": str(int.from_bytes(status.level, "little"))
                                             if isinstance(status.level, bytes) else str(status.level),
                                             "message": status.message} | {kv.key: kv.value for kv in status.values}

    def start(self, rollout_id: int) -> None:
        self.events.publish(rollout_event_msg(rollout_id, RolloutEvent.EVENT_START, 0, task="synthetic"))

    def end(self, rollout_id: int, success: bool) -> None:
        outcome = RolloutEvent.OUTCOME_SUCCESS if success else RolloutEvent.OUTCOME_FAILURE
        self.events.publish(rollout_event_msg(rollout_id, RolloutEvent.EVENT_END, 0, outcome=outcome))

    def step(self, rollout_id: int, step: int, embedding: np.ndarray, actions: np.ndarray, exec_steps: int) -> None:
        """One policy step, stamped as a policy does: the clock's now (the fusion node and the supervisor take
        the policy period from the stamps, so a paced test slowed by load must not stamp ahead of itself)."""
        stamp = self.get_clock().now().nanoseconds
        self.embeddings.publish(embedding_msg(rollout_id, step, stamp, embedding))
        self.batches.publish(action_batch_msg(rollout_id, step, stamp, actions, exec_steps, "ee_position"))

    def alarms_of(self, rollout_id: int) -> dict[int, FailureAlarm]:
        """The per-step decisions of a rollout (heartbeats left out), the first message per step."""
        out: dict[int, FailureAlarm] = {}
        for msg in self.alarms:
            if msg.rollout_id == rollout_id and not msg.heartbeat:
                out.setdefault(msg.step, msg)
        return out


class PolicySideSession:
    """A :class:`PolicySideNode` on its own executor, in a private context of ``domain``: the test side of a suite that
    runs in other processes (``fiper launch``)."""

    def __init__(self, domain: int) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.driver = PolicySideNode(self.context)
        self.executor.add_node(self.driver)

    def spin_until(self, condition: Callable[[], bool], timeout: float = 30.0) -> bool:
        return spin_until(self.executor, condition, timeout, step=0.02)

    def wired(self) -> bool:
        """Whether the driver's inputs are matched by the scoring nodes and its events by all three nodes."""
        return (self.driver.embeddings.get_subscription_count() >= 1
                and self.driver.batches.get_subscription_count() >= 1
                and self.driver.events.get_subscription_count() >= 3)

    def run(self, rollout: Rollout, rollout_id: int, why: Callable[[], object] = lambda: "") -> dict[int, FailureAlarm]:
        """Start ``rollout_id`` and publish ``rollout`` step by step, each step's alarm awaited (10 s; ``why()`` says
        what to show when one does not come); the alarms by step."""
        self.driver.start(rollout_id)
        for step in range(rollout.length):
            self.driver.step(rollout_id, step, rollout.embeddings[step], rollout.actions[step], rollout.exec_steps)
            assert self.spin_until(lambda s=step: s in self.driver.alarms_of(rollout_id), timeout=10), (step, why())
        return self.driver.alarms_of(rollout_id)

    def close(self) -> None:
        self.executor.shutdown()
        self.driver.destroy_node()
        rclpy.try_shutdown(context=self.context)


class Suite:
    """The three FIPER nodes plus the driver on one executor, in their own context and domain."""

    def __init__(self, domain: int, calibration_dir: str, extra: Iterable[Parameter] = (),
                 fusion: Iterable[Parameter] = ()) -> None:
        from fiper_ros.nodes.ace_node import AceNode
        from fiper_ros.nodes.fusion_node import FusionNode
        from fiper_ros.nodes.rnd_oe_node import RndOeNode

        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.executor = SingleThreadedExecutor(context=self.context)
        params = [Parameter("calibration_dir", value=calibration_dir), *extra]
        self.rnd_oe = RndOeNode(context=self.context, namespace="/fiper", parameter_overrides=params)
        self.ace = AceNode(context=self.context, namespace="/fiper", parameter_overrides=params)
        self.fusion = FusionNode(context=self.context, namespace="/fiper", parameter_overrides=list(fusion))
        self.driver = PolicySideNode(self.context)
        self.nodes = [self.rnd_oe, self.ace, self.fusion, self.driver]
        for node in self.nodes:
            self.executor.add_node(node)

    def spin_until(self, condition: Callable[[], bool], timeout: float = 10.0) -> bool:
        return spin_until(self.executor, condition, timeout, step=0.02)

    def wait_active(self) -> None:
        assert self.spin_until(lambda: all(n.lifecycle_state() == "active" for n in self.nodes[:3])), \
            [n.lifecycle_state() for n in self.nodes[:3]]
        # discovery between the driver and the nodes
        assert self.spin_until(lambda: self.driver.embeddings.get_subscription_count() >= 1
                               and self.driver.batches.get_subscription_count() >= 1
                               and self.driver.events.get_subscription_count() >= 3)

    def run(self, rollout: Rollout, rollout_id: int, *, end: bool = True) -> dict[int, FailureAlarm]:
        """Publish a whole rollout step by step, waiting for each step's alarm; return them by step."""
        self.driver.start(rollout_id)
        self.spin_until(lambda: self.fusion.fuser is not None and self.fusion.fuser.rollout_id == rollout_id)
        for step in range(rollout.length):
            self.driver.step(rollout_id, step, rollout.embeddings[step], rollout.actions[step], rollout.exec_steps)
            assert self.spin_until(lambda s=step: s in self.driver.alarms_of(rollout_id)), f"no alarm for step {step}"
        if end:
            self.driver.end(rollout_id, bool(rollout.success))
            self.spin_until(lambda: self.fusion.fuser.active_rollout is None, timeout=2.0)
        return self.driver.alarms_of(rollout_id)

    def close(self) -> None:
        for node in self.nodes:
            self.executor.remove_node(node)
            node.destroy_node()
        self.executor.shutdown()
        rclpy.try_shutdown(context=self.context)
