"""Test harness of the policy node: the node in process, a probe that records what it publishes (and
its /diagnostics), and a fake driver that publishes rollout events and observation ticks by hand."""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import Executor
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import Image, JointState

from fiper_msgs.msg import ActionChunkBatch, ActionCommand, ObservationEmbedding, RolloutEvent
from fiper_ros.interface import qos
from fiper_ros.interface.conversions import rollout_event_msg, to_stamp
from fiper_ros.interface.topics import ACTIONS_TOPIC, EMBEDDING_TOPIC, EVENTS_TOPIC
from fiper_ros.nodes.policy_node import PolicyNode
from helpers.spin import spin_until
from sim_ros.bridge_client import IMAGE_TOPICS

#: One step's outputs: the embedding, the batch and the command.
Outputs = tuple[ObservationEmbedding, ActionChunkBatch, ActionCommand]


class PolicyProbe(Node):
    """Records the policy node's embeddings, batches and commands, and its diagnostics."""

    def __init__(self, context: Context) -> None:
        super().__init__("policy_probe", context=context)
        self.embeddings: list[ObservationEmbedding] = []
        self.batches: list[ActionChunkBatch] = []
        self.commands: list[ActionCommand] = []
        self.diagnostics: dict[str, str] = {}
        outputs = ((ObservationEmbedding, EMBEDDING_TOPIC, self.embeddings), (ActionChunkBatch, ACTIONS_TOPIC,
                                                                              self.batches),
                   (ActionCommand, "/sim/action", self.commands))
        self.output_subs = [self.create_subscription(msg_type, topic, store.append, qos.INPUT)
                            for msg_type, topic, store in outputs]
        self.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, qos.DIAGNOSTICS)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.endswith("/policy_node"):
                self.diagnostics = {"level": str(int.from_bytes(status.level, "little")), "message": status.message}
                self.diagnostics |= {kv.key: kv.value for kv in status.values}

    def rejected(self, reason: str) -> int:
        """The node's ``rejected.<reason>`` count on /diagnostics."""
        return int(self.diagnostics.get(f"rejected.{reason}", 0))

    def outputs(self, rollout_id: int, step: int) -> Outputs | None:
        """The embedding, batch and command of one step, once all three arrived."""
        found = [next((m for m in msgs if m.rollout_id == rollout_id and m.step == step), None)
                 for msgs in (self.embeddings, self.batches, self.commands)]
        return None if None in found else (found[0], found[1], found[2])


class PolicyHarness:
    """The policy node (namespace /fiper) and a probe on ``executor``; ``params`` override the node's."""

    def __init__(self, context: Context, executor: Executor, **params: Any) -> None:
        overrides = {"diagnostics_period_s": 0.1, "configure_retry_s": 0.2} | params
        self.executor = executor
        self.node = PolicyNode(context=context, namespace="/fiper",
                               parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()])
        self.probe = PolicyProbe(context)
        for node in (self.node, self.probe):
            executor.add_node(node)

    def spin_until(self, condition: Callable[[], bool], timeout: float = 10.0) -> bool:
        """Spin until ``condition`` holds or ``timeout`` seconds passed."""
        return spin_until(self.executor, condition, timeout)

    def wait_ready(self, timeout: float = 30.0) -> None:
        """Wait until the node is active, its observation inputs have a publisher and the probe hears it."""
        node, probe = self.node, self.probe
        ready = self.spin_until(lambda: node.lifecycle_state() == "active"
                                and all(s.get_publisher_count() >= 1 for s in node._inputs)
                                and all(s.get_publisher_count() >= 1 for s in probe.output_subs)
                                and probe.diagnostics.get("lifecycle_state") == "active", timeout)
        assert ready, (node.lifecycle_state(), node.config_error, probe.diagnostics)

    def wait_outputs(self, rollout_id: int, step: int, timeout: float = 20.0) -> Outputs:
        """The outputs of one step (asserts they arrive)."""
        assert self.spin_until(lambda: self.probe.outputs(rollout_id, step) is not None, timeout), \
            f"no outputs for rollout {rollout_id} step {step}: {self.probe.diagnostics}"
        outputs = self.probe.outputs(rollout_id, step)
        assert outputs is not None
        return outputs

    def wait_rejected(self, reason: str, count: int, timeout: float = 5.0) -> None:
        """Wait until the node reports ``count`` rejections for ``reason``."""
        assert self.spin_until(lambda: self.probe.rejected(reason) >= count, timeout), (reason, self.probe.diagnostics)

    def close(self) -> None:
        """Remove and destroy both nodes (the context stays)."""
        for node in (self.node, self.probe):
            self.executor.remove_node(node)
            node.destroy_node()


class FakeDriver(Node):
    """Publishes what the sim bridge would, by hand: rollout events and observation ticks."""

    def __init__(self, context: Context, proprio_dim: int) -> None:
        super().__init__("fake_driver", context=context)
        self.proprio_dim = proprio_dim
        self.rng = np.random.default_rng(0)
        self.events = self.create_publisher(RolloutEvent, EVENTS_TOPIC, qos.EVENT)
        self.images = {key: self.create_publisher(Image, topic, qos.INPUT) for key, topic in IMAGE_TOPICS.items()}
        self.proprio = self.create_publisher(JointState, "/sim/proprio", qos.INPUT)

    def event(self, rollout_id: int, kind: int, stamp: int) -> None:
        """A START or END (``kind``) of ``rollout_id``."""
        self.events.publish(rollout_event_msg(rollout_id, kind, stamp, task="sorting", scenario="id"))

    def tick(self, stamp: int, wrist_size: int = 96, third_encoding: str = "rgb8",
             proprio: list[float] | None = None) -> None:
        """Both camera images (random pixels) and the proprio (random unless given), all stamped ``stamp``."""
        for key, pub in self.images.items():
            side = wrist_size if key == "wrist_rgb" else 96
            encoding = third_encoding if key == "third_rgb" else "rgb8"
            msg = Image(height=side, width=side, encoding=encoding, step=3 * side,
                        data=self.rng.integers(0, 255, (side, side, 3), dtype=np.uint8).tobytes())
            msg.header.stamp = to_stamp(stamp)
            pub.publish(msg)
        values = self.rng.normal(size=self.proprio_dim).tolist() if proprio is None else proprio
        msg = JointState(name=[f"p{i}" for i in range(len(values))], position=values)
        msg.header.stamp = to_stamp(stamp)
        self.proprio.publish(msg)
