"""The policy side of the contract, for policy authors: what a policy publishes for FIPER, on a node of its own.

Add these lines to a policy (a runnable whole: ``python -m fiper_ros.examples.minimal_policy``)::

    from fiper_ros.publishing import FiperPublisher

    fiper = FiperPublisher(node, action_space="ee_position", exec_steps=h)   # the three publishers, the QoS
    fiper.wait_for_suite(timeout_s=60.0)       # until the suite's scoring nodes have matched them
    fiper.start(task="my_task", scenario="id") # RolloutEvent START (a new rollout id)
    for each policy step:
        fiper.step(embedding, chunks)          # embedding (E values), chunks [B, H, D]: same stamp and step
        # or fiper.step(embedding, chunks, signals={"chunk_mse": 0.12})  # named scalars the policy logs, if any
    fiper.end(success=True)                    # RolloutEvent END with the outcome (None: not known)

:class:`FiperPublisher` creates, on the caller's node (it has no node of its own), the publishers of
``/fiper/observation_embedding``, ``/fiper/action_chunks`` and ``/fiper/step_signals`` (:data:`~fiper_ros.interface.
qos.INPUT`: RELIABLE, VOLATILE) and ``/fiper/rollout_events`` (:data:`~fiper_ros.interface.qos.EVENT`: RELIABLE,
TRANSIENT_LOCAL). A step's signals (named scalars the policy logs, e.g. features of the executed chunk) are optional:
a StepSignals message goes out only for a step given some, with the step's rollout id, step and stamp. The
inputs are VOLATILE: a step published before a scoring node's reader has matched the publisher is lost to it, so
:meth:`~FiperPublisher.wait_for_suite` waits until every reader that reports its matches on ``/diagnostics`` (the
suite's nodes, and ``fiper record``) has matched the publishers, among them an ACTIVE node of the suite per input
topic, the fusion node (the publisher of ``/fiper/alarm``) is ACTIVE, and every reader of the alarm that reports
(``fiper launch --summary``, ``fiper record``) has matched it; on timeout :class:`SuiteNotReady`
names what is missing. A step's embedding and batch carry the same rollout id, step and stamp (the node clock's
now, unless given). Messages are built by :mod:`fiper_ros.interface.conversions`, the code the suite's own policy
node and bag tools use; a step's are published as their CDR bytes (``embedding_cdr``, ``action_batch_cdr``: the
same messages, without the generated classes' per-field Python work).
"""
from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.duration import Duration
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from fiper_msgs.msg import ActionChunkBatch, ObservationEmbedding, RolloutEvent, StepSignals
from fiper_ros.core.rollout import ACTION_SPACES, RolloutError, check_signal_name
from fiper_ros.errors import FiperError
from fiper_ros.interface import qos
from fiper_ros.interface.conversions import action_batch_cdr, embedding_cdr, rollout_event_msg, step_signals_cdr
from fiper_ros.interface.messages import NO_ROLLOUT, OUTCOME_OF
from fiper_ros.interface.topics import (ACTIONS_TOPIC, ALARM_TOPIC, DIAGNOSTICS_TOPIC, EMBEDDING_TOPIC, EVENTS_TOPIC,
                                        STEP_SIGNALS_TOPIC)
from fiper_ros.runtime.trusted_publishers import fully_qualified
from fiper_ros.runtime.wiring import unmatched_readers

__all__ = ["FiperPublisher", "SuiteNotReady"]

#: How often :meth:`FiperPublisher.wait_for_suite` looks at the graph and the reports it received.
POLL_S = 0.05
#: The /diagnostics key of a managed node's lifecycle state (the suite's nodes report it).
LIFECYCLE_STATE = "lifecycle_state"
#: Largest rollout id a message carries (``uint64``).
MAX_ROLLOUT_ID = 2**64 - 1


class SuiteNotReady(FiperError, RuntimeError):
    """The suite did not match the policy's publishers in time; the message says what is missing (a
    ``RuntimeError`` too, which a policy author's code may catch)."""


class FiperPublisher:
    """The publishers of a policy's FIPER topics on ``node``, and START / step / END.

    Args:
        node: The policy's rclpy node (the publishers live on it).
        action_space: How the chunks' actions read: ``ee_position``, ``joint_position`` or ``joint_velocity``.
        exec_steps: Actions of a chunk executed before the next policy step (``h`` <= ``H``).
        embedding_topic: Where the observation embeddings go.
        actions_topic: Where the action-chunk batches go; ``None``: none are published (observation-only: a
            suite of RND-OE alone, ``observation_only:=true``).
        events_topic: Where the rollout events go; ``None``: another node (e.g. the robot's bridge) publishes
            them, and :meth:`start` / :meth:`end` are not used.
        signals_topic: Where a step's signals go (:meth:`step`'s ``signals``); ``None``: none are published.
        event_callbacks: Makes the QoS event callbacks of the publisher of a topic (e.g. to count incompatible
            QoS); none by default.
    """

    def __init__(self, node: Node, *, action_space: str = ACTION_SPACES[0], exec_steps: int = 1,
                 embedding_topic: str = EMBEDDING_TOPIC, actions_topic: str | None = ACTIONS_TOPIC,
                 events_topic: str | None = EVENTS_TOPIC, signals_topic: str | None = STEP_SIGNALS_TOPIC,
                 event_callbacks: Callable[[str], PublisherEventCallbacks] | None = None) -> None:
        self.node = node
        self.set_layout(action_space, exec_steps)

        def publisher(kind: Any, topic: str, profile: Any) -> Any:
            callbacks = event_callbacks(topic) if event_callbacks is not None else None
            return node.create_publisher(kind, topic, profile, event_callbacks=callbacks)

        self.embeddings = publisher(ObservationEmbedding, embedding_topic, qos.INPUT)
        self.batches = None if actions_topic is None else publisher(ActionChunkBatch, actions_topic, qos.INPUT)
        self.events = None if events_topic is None else publisher(RolloutEvent, events_topic, qos.EVENT)
        self.signals = None if signals_topic is None else publisher(StepSignals, signals_topic, qos.INPUT)
        self.rollout_id: int | None = None
        """The rollout :meth:`start` began and :meth:`end` has not ended."""
        self.next_step = 0
        """The step :meth:`step` publishes next for :attr:`rollout_id`."""
        self._last_id = NO_ROLLOUT
        self._reports: dict[str, dict[str, str]] = {}

    def set_layout(self, action_space: str, exec_steps: int) -> None:
        """What the published batches say of their chunks: the action space and ``h`` (e.g. once the policy is
        loaded)."""
        if action_space not in ACTION_SPACES:
            raise ValueError(f"action_space must be one of {', '.join(ACTION_SPACES)}, got {action_space!r}")
        if exec_steps < 1:
            raise ValueError(f"exec_steps must be >= 1, got {exec_steps}")
        self.action_space, self.exec_steps = action_space, exec_steps

    # waiting for the suite ---------------------------------------------------------------------------
    def _inputs(self) -> list[Any]:
        return [p for p in (self.embeddings, self.batches) if p is not None]

    def missing(self, also: Sequence[str] = (), suite: bool = True) -> list[str]:
        """What has not matched the publishers yet (empty: publishing loses nothing), from the ROS graph and the
        ``/diagnostics`` reports received so far: every reader of the inputs (step signals included) or of
        ``/fiper/alarm`` that reports its matches (for the alarm, KEEP_LAST(1) at the fusion node: so that the first
        verdicts are not lost to it),
        ``also`` (nodes, fully qualified, e.g. ``/fiper_record``, that must have reported: a reader this process has not
        discovered yet cannot be waited for otherwise) and, with ``suite``, an ACTIVE reader of the suite per input
        topic and an ACTIVE fusion node."""
        node = self.node
        lines = [f"{name} to report its matches on /diagnostics" for name in also if name not in self._reports]
        for publisher in self._inputs():
            topic = publisher.topic_name
            readers, unmatched = unmatched_readers(self._reports, topic, node.count_publishers(topic))
            if suite and not any(self._active(reader) for reader in readers):
                lines.append(f"an active node of the suite subscribing to {topic} (none reports one on /diagnostics)")
            lines += unmatched
            lines += self._writer_side(publisher)
        if self.signals is not None:  # no node of the suite reads them: only who reports a reader (fiper record)
            topic = self.signals.topic_name
            lines += unmatched_readers(self._reports, topic, node.count_publishers(topic))[1]
            lines += self._writer_side(self.signals)
        if self.events is not None:
            lines += self._writer_side(self.events)
        # who watches the suite's verdicts (fiper launch --summary, fiper record) must hear the first ones too
        lines += unmatched_readers(self._reports, ALARM_TOPIC, node.count_publishers(ALARM_TOPIC))[1]
        fusion = [fully_qualified(p.node_namespace,
                                  p.node_name) for p in node.get_publishers_info_by_topic(ALARM_TOPIC)]
        if suite and not any(self._active(name) for name in fusion):
            state = f"{', '.join(fusion)} not active" if fusion else f"no publisher of {ALARM_TOPIC}"
            lines.append(f"the fusion node ({state})")
        return lines

    def _active(self, name: str) -> bool:
        """Whether the node ``name`` last reported its lifecycle state ACTIVE (a node of the suite, at work)."""
        return self._reports.get(name, {}).get(LIFECYCLE_STATE) == "active"

    def _writer_side(self, publisher: Any) -> list[str]:
        """Our publisher must have matched every subscription of its topic in the graph."""
        topic = publisher.topic_name
        readers, matched = self.node.count_subscribers(topic), publisher.get_subscription_count()
        return [] if matched >= readers else [f"this publisher of {topic} to match {readers} subscriptions "
                                               f"(has {matched})"]

    def wait_for_suite(self, timeout_s: float = 60.0, also: Sequence[str] = (), suite: bool = True) -> None:
        """Return once :meth:`missing` is empty; :class:`SuiteNotReady` naming what is missing after ``timeout_s``.
        ``suite`` False: only the nodes of ``also`` (e.g. ``fiper record`` of calibration rollouts, before there
        is a calibration to launch the suite with).

        The node is spun here if it belongs to no executor; one that does is spun by its executor (which must be
        spinning meanwhile, e.g. in another thread).
        """
        node = self.node
        subscription = node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self._on_diagnostics,
                                                qos.DIAGNOSTICS)
        owner, executor = node.executor, None
        if owner is None or node not in owner.get_nodes():  # nobody spins the node (rclpy.spin_once leaves owner set)
            executor = SingleThreadedExecutor(context=node.context)
            executor.add_node(node)
        deadline = time.monotonic() + timeout_s
        try:
            while missing := self.missing(also, suite):
                if time.monotonic() >= deadline:
                    what = "the FIPER suite is" if suite else f"{', '.join(also)} {'is' if len(also) == 1 else 'are'}"
                    hint = ("the suite (fiper launch fiper_ros/launch/fiper.launch.yaml calibration_dir:=DIR)"
                            if suite else "it")
                    raise SuiteNotReady(f"{what} not ready after {timeout_s:g} s in ROS domain "
                                        f"{node.context.get_domain_id()}; waiting for: {'; '.join(missing)}. "
                                        f"Is {hint} running in this domain?")
                if executor is not None:
                    executor.spin_once(timeout_sec=POLL_S)
                else:
                    time.sleep(POLL_S)
        finally:
            if executor is not None:
                executor.remove_node(node)
                node.executor = None
                executor.shutdown()
            node.destroy_subscription(subscription)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            self._reports[status.hardware_id] = {v.key: v.value for v in status.values}

    # publishing ---------------------------------------------------------------------------------------
    def now_ns(self) -> int:
        """The node clock (sim time under ``use_sim_time``), the stamp of what is published without one."""
        return self.node.get_clock().now().nanoseconds

    def new_rollout_id(self) -> int:
        """A rollout id never used before, also across runs: the wall clock in ms, at least one above the last."""
        return max(self._last_id + 1, time.time_ns() // 1_000_000)

    def start(self, rollout_id: int | None = None, *, task: str = "", scenario: str = "",
              max_steps: int = 0) -> int:
        """Publish the START of a rollout (``rollout_id``, default :meth:`new_rollout_id`; > 0) of ``task`` in
        ``scenario``; its steps count from 0. Returns the rollout id."""
        if self.events is None:
            raise RuntimeError("this FiperPublisher publishes no rollout events (events_topic None)")
        rollout_id = self.new_rollout_id() if rollout_id is None else int(rollout_id)
        if not NO_ROLLOUT < rollout_id <= MAX_ROLLOUT_ID:
            raise ValueError(f"rollout_id must be in 1..2^64-1 ({NO_ROLLOUT} means no rollout), got {rollout_id}")
        self.events.publish(rollout_event_msg(rollout_id, RolloutEvent.EVENT_START, self.now_ns(), task=task,
                                              scenario=scenario, max_steps=max_steps))
        self.rollout_id, self.next_step, self._last_id = rollout_id, 0, rollout_id
        return rollout_id

    def step(self, embedding: np.ndarray, chunks: np.ndarray | None = None, *, rollout_id: int | None = None,
             step: int | None = None, stamp_ns: int | None = None, signals: Mapping[str, float] | None = None) -> int:
        """Publish one policy step: the observation embedding and the ``[B, H, D]`` sampled chunks (all B of
        them: ACE needs the batch), and the step's signals if given, with the same rollout id, step and stamp.

        Args:
            embedding: The encoder's output for the step's observation (any shape, E values).
            chunks: The B sampled action chunks; ``None`` only without an action-batch publisher.
            rollout_id: Default: the rollout :meth:`start` began.
            step: Default: the next step of that rollout (0, 1, ...).
            stamp_ns: Default: the node clock's now.
            signals: Named finite scalars of the step (names of :data:`~fiper_ros.core.detectors.SIGNAL_NAME`; give
                the same names at every step of a rollout); ``None`` or empty: no StepSignals message.

        Returns:
            The step published.
        """
        rollout_id = self.rollout_id if rollout_id is None else int(rollout_id)
        if rollout_id is None:
            raise RuntimeError("no rollout is running: call start() first, or give rollout_id and step")
        if step is None:
            if rollout_id != self.rollout_id:
                raise ValueError(f"give the step of rollout {rollout_id}: it is not the one start() began")
            step = self.next_step
        values = np.asarray(embedding, dtype=np.float32)
        if values.size == 0:
            raise ValueError("the embedding is empty")
        if (chunks is None) != (self.batches is None):
            raise ValueError("chunks are required with an action-batch publisher, and not taken without one"
                             if chunks is None else "this FiperPublisher publishes no action batches "
                                                    "(actions_topic None): give no chunks")
        stamp = self.now_ns() if stamp_ns is None else int(stamp_ns)
        if chunks is not None:
            batch = np.asarray(chunks, dtype=np.float32)
            if batch.ndim != 3 or 0 in batch.shape:
                raise ValueError(f"chunks must be [B, H, D] with B, H, D >= 1, got shape {batch.shape}")
        scalars = self._checked_signals(signals or {})
        self.embeddings.publish(embedding_cdr(rollout_id, step, stamp, values))
        if chunks is not None:
            self.batches.publish(action_batch_cdr(rollout_id, step, stamp, batch, self.exec_steps, self.action_space))
        if scalars:
            self.signals.publish(step_signals_cdr(rollout_id, step, stamp, scalars))
        if rollout_id == self.rollout_id:
            self.next_step = step + 1
        return step

    def _checked_signals(self, signals: Mapping[str, float]) -> dict[str, float]:
        """A step's signals as ``{name: float}``, refused (:class:`ValueError`) unless every name is a signal name
        and every value a finite number, and without a signals publisher."""
        if signals and self.signals is None:
            raise ValueError("this FiperPublisher publishes no signals (signals_topic None): give no signals")
        checked: dict[str, float] = {}
        for name, value in signals.items():
            try:
                check_signal_name(name, "signals")
            except RolloutError as error:
                raise ValueError(str(error)) from error
            try:
                checked[name] = float(value)
            except (TypeError, ValueError) as error:
                raise ValueError(f"signal {name!r} is not a number: {value!r}") from error
            if not np.isfinite(checked[name]):
                raise ValueError(f"signal {name!r} is {checked[name]}: signals must be finite")
        return checked

    def end(self, success: bool | None, *, rollout_id: int | None = None) -> None:
        """Publish the END of the rollout (default: the one :meth:`start` began) with its outcome: ``True``
        success, ``False`` failure, ``None`` not known."""
        if self.events is None:
            raise RuntimeError("this FiperPublisher publishes no rollout events (events_topic None)")
        rollout_id = self.rollout_id if rollout_id is None else int(rollout_id)
        if rollout_id is None:
            raise RuntimeError("no rollout is running: call start() first, or give rollout_id")
        self.events.publish(rollout_event_msg(rollout_id, RolloutEvent.EVENT_END, self.now_ns(),
                                              outcome=OUTCOME_OF[success]))
        if rollout_id == self.rollout_id:
            self.rollout_id = None

    def flush(self, timeout_s: float = 10.0) -> bool:
        """Wait until every subscription matched has acknowledged everything published (before the process
        exits: what is still in flight would be lost); whether it did within ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        done = True
        for publisher in (*self._inputs(), *(p for p in (self.events, self.signals) if p is not None)):
            left = max(0.0, deadline - time.monotonic())
            done = publisher.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))) and done
        return done
