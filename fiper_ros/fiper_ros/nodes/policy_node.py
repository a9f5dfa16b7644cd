"""Policy node: a trained generative policy (``fiper_ros.policy``) driving a robot over ROS 2.

A thin shell: the observation parts (both cameras, proprioception) are checked and grouped by stamp
(:class:`~fiper_ros.runtime.observation_sync.ObservationSync`), rollouts and policy steps are
:class:`~fiper_ros.policy.session.PolicySession`'s business. Per step of the running rollout the node
publishes the ObservationEmbedding and the ActionChunkBatch FIPER monitors (same stamp and step as
the observation; :class:`~fiper_ros.publishing.FiperPublisher`, the policy authors' API) and then the
ActionCommand the robot executes (the first ``h`` actions of sample 0).
RolloutEvents are followed in a callback group of their own (the process spins two threads), so an END
that arrives while a step computes is seen at once: that step is not published (its rollout is over;
``steps_dropped_after_end`` on /diagnostics). A lock guards the session and the observation buffer.
Topics, QoS and parameters: docs/nodes.md, "The policy node".
"""
from __future__ import annotations

import sys
import threading
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from sensor_msgs.msg import Image, JointState

from fiper_msgs.msg import ActionCommand, RolloutEvent
from fiper_ros.data_paths import resolve_data_path
from fiper_ros.interface import qos
from fiper_ros.interface.conversions import action_command_msg, stamp_ns
from fiper_ros.interface.messages import outcome_name
from fiper_ros.interface.topics import (ACTIONS_TOPIC, CAMERA_THIRD_TOPIC, CAMERA_WRIST_TOPIC, EMBEDDING_TOPIC,
                                        EVENTS_TOPIC, SIM_ACTION_TOPIC, SIM_PROPRIO_TOPIC)
from fiper_ros.nodes.base import FiperNode, describe
from fiper_ros.nodes.settings import PolicySettings, policy_settings
from fiper_ros.platform.process import run_node, run_reported
from fiper_ros.policy.encoder import CAMERAS, RAW_IMAGE_SIZE
from fiper_ros.policy.policy import Policy
from fiper_ros.policy.session import PolicySession, PolicyStep
from fiper_ros.publishing import FiperPublisher
from fiper_ros.runtime import validation
from fiper_ros.runtime.observation_sync import ObservationSync
from fiper_ros.runtime.validation import INTERNAL, InputRejected

PROPRIO = "proprio"
#: Observation key -> parameter (and setting) naming its image topic.
IMAGE_TOPIC_PARAMS = {"wrist_rgb": "wrist_image_topic", "third_rgb": "third_image_topic"}


class PolicyNode(FiperNode):
    """Acts on every observation of the running rollout: embedding, sampled batch, command."""

    settings: PolicySettings

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("policy_node", **kwargs)
        declare = self.declare_parameter
        declare("model", "models/sorting", describe("policy folder (policy.yaml + policy.pt)", read_only=True))
        declare("batch", 0, describe("action chunks sampled per step; 0 = the model's B", read_only=True,
                                     low=0, high=65536, integer=True))
        declare("torch_threads", 1, describe("torch intra-op threads", read_only=True, low=1, high=256, integer=True))
        declare("start_wait_s", 1.0, describe("how long an observation may wait for its rollout's START",
                                              read_only=True, low=0.0, high=60.0))
        declare("events_topic", EVENTS_TOPIC, describe("RolloutEvent input", read_only=True))
        declare("wrist_image_topic", CAMERA_WRIST_TOPIC, describe("wrist camera, rgb8", read_only=True))
        declare("third_image_topic", CAMERA_THIRD_TOPIC, describe("third-person camera, rgb8",
                                                                         read_only=True))
        declare("proprio_topic", SIM_PROPRIO_TOPIC, describe("proprioception (sensor_msgs/JointState positions)",
                                                          read_only=True))
        declare("embedding_topic", EMBEDDING_TOPIC, describe("ObservationEmbedding output", read_only=True))
        declare("action_chunks_topic", ACTIONS_TOPIC, describe("ActionChunkBatch output", read_only=True))
        declare("action_topic", SIM_ACTION_TOPIC, describe("ActionCommand output (the robot's input)", read_only=True))
        self.settle(policy_settings)
        settings = self.settings
        self.policy: Policy | None = None
        self.session: PolicySession | None = None
        self.sync: ObservationSync[np.ndarray] = ObservationSync((*CAMERAS, PROPRIO))
        self.published = 0
        #: Steps computed for a rollout whose END arrived meanwhile (not published).
        self.dropped_after_end = 0
        self._lock = threading.Lock()
        self._events_group = MutuallyExclusiveCallbackGroup()
        #: A step taken when a waiting tick's START came; computed in the inputs' callback group.
        self._started_step: PolicyStep | None = None
        self._compute_started = self.create_guard_condition(self._on_started_step)
        self._events_sub: Any = None
        self._inputs: list[Any] = []

        # The policy side of the contract (the sim bridge publishes the rollout events): fiper_ros.publishing.
        self.fiper = FiperPublisher(self, embedding_topic=settings.embedding_topic,
                                    actions_topic=settings.action_chunks_topic, events_topic=None,
                                    event_callbacks=self.publisher_events)
        self._command_pub = self.create_publisher(ActionCommand, settings.action_topic, qos.INPUT,
                                                  event_callbacks=self.publisher_events(settings.action_topic))

    # lifecycle ----------------------------------------------------------------------------------------
    def configure(self) -> None:
        settings = self.settings
        model = resolve_data_path(settings.model)  # the rule of fiper_ros/data_paths.py
        torch.set_num_threads(settings.torch_threads)
        policy = Policy.load(model)  # a missing file is named in the error (the parameter is `model`)
        self.fiper.set_layout(policy.config.action_space, policy.config.exec_steps)
        self.session = PolicySession(policy, settings.batch or None, self.reject, settings.start_wait_ns)
        self.policy = policy
        c = policy.config
        self.get_logger().info(f"policy {model} loaded: {c.task} ({c.head}), B x H x D = {self.batch_size} x "
                               f"{c.horizon} x {c.action_dim}, E = {c.embed_dim}, T_h = {c.obs_horizon}, "
                               f"h = {c.exec_steps}, {c.action_space}")
        # Followed from here on in every state: a rollout started before activation is known.
        topic = settings.events_topic
        self._events_sub = self.create_subscription(RolloutEvent, topic, self._on_event, qos.EVENT,
                                                    callback_group=self._events_group,
                                                    event_callbacks=self.subscription_events(topic))

    def activate(self) -> None:
        for key, parameter in IMAGE_TOPIC_PARAMS.items():
            self._subscribe(Image, getattr(self.settings, parameter), lambda msg, key=key: self._on_image(key, msg))
        self._subscribe(JointState, self.settings.proprio_topic, self._on_proprio)

    def deactivate(self) -> None:
        for subscription in self._inputs:
            self.destroy_subscription(subscription)
        self._inputs.clear()
        with self._lock:
            self.sync.restart()

    def cleanup(self) -> None:
        if self._events_sub is not None:
            self.destroy_subscription(self._events_sub)
        self._events_sub = None
        with self._lock:
            self.session = None
            self.policy = None

    def _subscribe(self, msg_type: Any, topic: str, callback: Callable[[Any], None]) -> None:
        self._inputs.append(self.create_subscription(msg_type, topic, callback, qos.INPUT,
                                                     event_callbacks=self.subscription_events(topic)))

    @property
    def batch_size(self) -> int:
        """``B`` of the published batches (0 before configure)."""
        if self.policy is None:
            return 0
        return self.settings.batch or self.policy.config.sample_batch

    # callbacks ----------------------------------------------------------------------------------------
    def _on_event(self, msg: RolloutEvent) -> None:
        stamp = stamp_ns(msg.header.stamp)
        with self._lock:
            session = self.session
            if session is None:
                return
            if msg.event == RolloutEvent.EVENT_START:
                previous = session.running
                act_now = session.start(msg.rollout_id, stamp, msg.task, msg.scenario)
                if previous is not None and previous is not session.running:
                    self.get_logger().warning(f"{previous.summary()} (no END before rollout {msg.rollout_id} "
                                              "started)")
                self.sync.restart(stamp)
                if act_now:
                    self._started_step = session.begin()
                    self._compute_started.trigger()
            elif msg.event == RolloutEvent.EVENT_END:
                ended = session.end(msg.rollout_id, stamp, outcome_name(msg.outcome))
                if ended is not None:
                    self.get_logger().info(ended.summary())

    def _on_started_step(self) -> None:
        with self._lock:
            step, self._started_step = self._started_step, None
        if step is not None:
            self._act(step)

    def _on_image(self, key: str, msg: Image) -> None:
        self.tick(key, self.now_ns())
        try:
            image = validation.rgb8_image(msg.data, msg.height, msg.width, msg.encoding, msg.step,
                                          (RAW_IMAGE_SIZE, RAW_IMAGE_SIZE), key)
        except InputRejected as error:
            self.reject(error)
            return
        self._add(stamp_ns(msg.header.stamp), key, image)

    def _on_proprio(self, msg: JointState) -> None:
        self.tick(PROPRIO, self.now_ns())
        assert self.policy is not None
        try:
            proprio = validation.vector(msg.position, self.policy.config.proprio_dim, PROPRIO)
        except InputRejected as error:
            self.reject(error)
            return
        self._add(stamp_ns(msg.header.stamp), PROPRIO, proprio)

    def _add(self, stamp: int, key: str, part: np.ndarray) -> None:
        with self._lock:
            session = self.session
            if session is None:
                return
            observation = self.sync.add(stamp, key, part)
            if observation is None or not session.observe(stamp, observation, self.steady.now().nanoseconds):
                return
            step = session.begin()
        self._act(step)

    def _act(self, step: PolicyStep) -> None:
        """Compute ``step`` (without the lock: START / END are followed meanwhile) and publish it if its
        rollout still runs."""
        session, policy = self.session, self.policy
        assert session is not None and policy is not None
        started = self.timed()
        try:
            action = session.compute(step)
        except Exception as error:  # noqa: BLE001 - a policy error is reported, never fatal
            self.reject(InputRejected(INTERNAL, f"policy step failed: {error!r}"))
            return
        self.record_latency(started)
        with self._lock:
            if not session.is_running(action.rollout_id):
                self.dropped_after_end += 1
                self.get_logger().info(f"rollout {action.rollout_id} step {action.step} not published: the "
                                       "rollout ended while it was computed")
                return
            self.fiper.step(action.embedding, action.chunks, rollout_id=action.rollout_id, step=action.step,
                            stamp_ns=action.stamp)
            self._command_pub.publish(action_command_msg(action.rollout_id, action.step, action.stamp,
                                                         action.command, policy.config.action_space,
                                                         session.history_frames))
            self.published += 1

    # diagnostics --------------------------------------------------------------------------------------
    def diagnostic_values(self) -> dict[str, str]:
        with self._lock:
            return self._values()

    def _values(self) -> dict[str, str]:
        sync = self.sync
        values = {"model": self.settings.model, "published": str(self.published),
                  "steps_dropped_after_end": str(self.dropped_after_end),
                  "ticks.complete": str(sync.completed), "ticks.partial_dropped": str(sync.dropped_partial),
                  "ticks.stale": str(sync.stale), "ticks.duplicate": str(sync.duplicates)}
        session, policy = self.session, self.policy
        if session is None or policy is None:
            return values
        session.expire(self.steady.now().nanoseconds)
        c = policy.config
        running = session.running
        values |= {"task": c.task, "head": c.head, "batch_size": str(self.batch_size), "horizon": str(c.horizon),
                   "action_dim": str(c.action_dim), "embed_dim": str(c.embed_dim), "exec_steps": str(c.exec_steps),
                   "obs_horizon": str(c.obs_horizon), "history_frames": str(session.history_frames),
                   "action_space": c.action_space,
                   "rollouts_seen": str(session.rollouts_seen), "ticks.late": str(session.late),
                   "waiting_for_start": str(int(session.waiting)),
                   "rollout_id": "" if running is None else str(running.rollout_id),
                   "policy_step": "" if running is None else str(running.steps)}
        return values


#: The node class, for in-process launching.
NODE_CLASS = PolicyNode


def main(args: list[str] | None = None) -> int:
    """Entry point: ``python -m fiper_ros.nodes.policy_node --ros-args ...``."""
    return run_reported("policy_node", run_node, PolicyNode, args, threads=2)


if __name__ == "__main__":
    sys.exit(main())
