"""Bags <-> core :class:`~fiper_ros.core.rollout.Rollout` records.

Writing lays rollouts out one after another on the bag's time line: a RolloutEvent START, then per
policy step an ObservationEmbedding and an ActionChunkBatch with the same ``(rollout_id, step)`` and
stamp (no batch for a rollout without action batches, observation-only data: its bag has no
``/fiper/action_chunks``), then END with the outcome; the messages are built by :mod:`fiper_ros.interface.conversions`, the
same code a policy node uses. A rollout with ``metadata["joint_positions"]`` (``[T, 7]``, the measured
arm joints of a joint-velocity policy) also gets a ``/joint_states`` message at each step's stamp, written
before the step's embedding and batch. A rollout with signals (``Rollout.signals``) gets a StepSignals message per
step after the step's embedding and batch, with the same ``(rollout_id, step)`` and stamp, as
:class:`~fiper_ros.publishing.FiperPublisher` publishes them. Reading matches embedding, batch and signals on
``(rollout_id, step)``,
takes task, scenario and outcome from the rollout's events, and restores ``joint_positions`` as the
ace_node sees them: per step, the arm joints of the ``/joint_states`` with the latest stamp not after
the batch's among all of the bag's (:mod:`fiper_ros.runtime.joint_history`; a live recording also holds
the states of the control steps that ran while the batch travelled, and may have logged a batch before
the states stamped up to it).

Observation-only data: a rollout without action batches (``actions`` ``None``) is written
without ActionChunkBatch messages, and a bag without the action topic is read as such rollouts (their
``exec_steps`` from ``custom_data``, else 1: it only spaces a written bag's steps).
"""
from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from fiper_msgs.msg import RolloutEvent
from fiper_ros.bagio.errors import BagError
from fiper_ros.bagio.reader import BagReader
from fiper_ros.bagio.schema import BagInfo, message_cdr, typestore
from fiper_ros.bagio.writer import BagWriter
from fiper_ros.core.rollout import ACTION_SPACES, Rollout, RolloutError
from fiper_ros.core.scores import JOINT_POSITIONS_KEY
from fiper_ros.interface.conversions import (action_batch_msg, embedding_msg, rollout_event_msg, signals_of,
                                             stamp_ns, step_signals_msg)
from fiper_ros.interface.messages import OUTCOME_OF, SUCCESS_OF
from fiper_ros.interface.topics import (ACTIONS_TOPIC, ARM_JOINT_NAMES, EMBEDDING_TOPIC, EVENTS_TOPIC,
                                        JOINT_STATES_TOPIC, STEP_SIGNALS_TOPIC, TOPICS)
from fiper_ros.runtime.joint_history import LatestNotAfter

LOG = logging.getLogger(__name__)

#: Default start of a converted bag's time line (2023-11-14T22:13:20Z): far from 0, which means
#: "no time yet" to a node under use_sim_time.
DEFAULT_START_NS = 1_700_000_000 * 1_000_000_000
#: The START event precedes step 0 by this much.
EVENT_LEAD_NS = 1_000_000
#: Pause between one rollout's END and the next START.
ROLLOUT_GAP_NS = 1_000_000_000


def shape_info(rollouts: Sequence[Rollout], base: BagInfo) -> BagInfo:
    """``base`` with the shapes and action space of ``rollouts`` (which must all agree; without action batches
    B, H, D are 0 and the action space "")."""
    def layout(r: Rollout) -> tuple[int, ...]:
        _, b, h, d = (0, 0, 0, 0) if r.actions is None else r.actions.shape
        return b, h, d, r.exec_steps, r.embeddings.shape[1]

    first = rollouts[0]
    for rollout in rollouts[1:]:
        if layout(rollout) != layout(first) or rollout.action_space != first.action_space:
            raise BagError(f"rollout {rollout.rollout_id!r} has B, H, D, h, E = {layout(rollout)} "
                           f"({rollout.action_space}), rollout {first.rollout_id!r} {layout(first)} "
                           f"({first.action_space}): one bag holds one layout")
    b, h, d, exec_steps, e = layout(first)
    return replace(base, batch_size=b, horizon=h, action_dim=d, exec_steps=exec_steps, embedding_dim=e,
                   action_space=first.action_space if first.has_actions else "")


def _env_steps(rollout: Rollout) -> np.ndarray:
    """Environment step of each policy step: ``metadata["env_steps"]`` or ``0, h, 2h, ...``."""
    steps = rollout.metadata.get("env_steps")
    if steps is None:
        return np.arange(rollout.length, dtype=np.int64) * rollout.exec_steps
    steps = np.asarray(steps, dtype=np.int64)
    return steps - steps[0]


def _joint_positions(rollout: Rollout, path: Path) -> np.ndarray | None:
    """``metadata["joint_positions"]`` as ``[T, 7]`` float64, or None if the rollout has none."""
    joints = rollout.metadata.get(JOINT_POSITIONS_KEY)
    if joints is None:
        return None
    joints = np.asarray(joints, dtype=np.float64)
    if joints.shape != (rollout.length, len(ARM_JOINT_NAMES)):
        raise BagError(f"{path}: rollout {rollout.rollout_id!r}: metadata['{JOINT_POSITIONS_KEY}'] has shape "
                       f"{joints.shape}, expected ({rollout.length}, {len(ARM_JOINT_NAMES)})")
    return joints


def _joint_state_cdr(stamp: int, positions: np.ndarray) -> bytes:
    """A ``/joint_states`` message of the arm joints (:data:`ARM_JOINT_NAMES`) at ``stamp``, as CDR.

    Built with ``rosbags``: rclpy's ``serialize_message`` appends bytes after a JointState that a CDR
    reader rejects (a JointState received over DDS has none).
    """
    store = typestore()
    types = store.types
    header = types["std_msgs/msg/Header"](types["builtin_interfaces/msg/Time"](*divmod(stamp, 1_000_000_000)), "")
    empty = np.zeros(0, dtype=np.float64)
    msg = types[TOPICS[JOINT_STATES_TOPIC].msgtype](header, list(ARM_JOINT_NAMES), np.asarray(positions, np.float64),
                                              empty, empty)
    return bytes(store.serialize_cdr(msg, TOPICS[JOINT_STATES_TOPIC].msgtype))


def write_rollouts(path: Path, rollouts: Sequence[Rollout], ids: Sequence[int], info: BagInfo, *,
                   start_ns: int = DEFAULT_START_NS, env_dt_ns: int = 100_000_000, overwrite: bool = False) -> int:
    """Write ``rollouts`` (with message rollout ids ``ids``) as one bag; returns the time after the last.

    Args:
        path: The bag directory to create.
        rollouts: Rollouts of one layout (B, H, D, h, E, action space); rollouts whose ``actions`` are None
            are written without action batches.
        ids: ``rollout_id`` of each rollout in the messages.
        info: ``custom_data``; the shapes are filled in from the rollouts.
        start_ns: Time of the first START.
        env_dt_ns: Duration of one environment (control) step; a policy step lasts ``h`` of them, and a
            rollout with ``metadata["control_steps"]`` ends that many control steps after step 0.
        overwrite: Replace an existing bag.
    """
    if not rollouts:
        raise BagError(f"{path}: no rollouts to write")
    with BagWriter(path, overwrite=overwrite) as writer:
        writer.info = shape_info(rollouts, info)
        now = start_ns
        for rollout, rollout_id in zip(rollouts, ids, strict=True):
            max_steps = int(rollout.metadata.get("max_steps", 0))
            writer.write(EVENTS_TOPIC, now, _cdr(rollout_event_msg(
                rollout_id, RolloutEvent.EVENT_START, now, task=rollout.task, scenario=rollout.scenario,
                max_steps=max_steps), EVENTS_TOPIC))
            joints = _joint_positions(rollout, path)
            for step, offset in enumerate(_env_steps(rollout)):
                stamp = now + EVENT_LEAD_NS + int(offset) * env_dt_ns
                if joints is not None:
                    writer.write(JOINT_STATES_TOPIC, stamp, _joint_state_cdr(stamp, joints[step]))
                writer.write(EMBEDDING_TOPIC, stamp,
                             _cdr(embedding_msg(rollout_id, step, stamp, rollout.embeddings[step]), EMBEDDING_TOPIC))
                if rollout.actions is not None:
                    writer.write(ACTIONS_TOPIC, stamp, _cdr(action_batch_msg(
                        rollout_id, step, stamp, rollout.actions[step], rollout.exec_steps, rollout.action_space),
                        ACTIONS_TOPIC))
                if rollout.signals:
                    values = {name: float(series[step]) for name, series in rollout.signals.items()}
                    writer.write(STEP_SIGNALS_TOPIC, stamp, _cdr(step_signals_msg(rollout_id, step, stamp, values),
                                                                 STEP_SIGNALS_TOPIC))
            control_steps = rollout.metadata.get("control_steps")
            end = (stamp + rollout.exec_steps * env_dt_ns if control_steps is None
                   else now + EVENT_LEAD_NS + int(control_steps) * env_dt_ns)
            writer.write(EVENTS_TOPIC, end, _cdr(rollout_event_msg(
                rollout_id, RolloutEvent.EVENT_END, end, outcome=OUTCOME_OF[rollout.success], task=rollout.task,
                scenario=rollout.scenario, max_steps=max_steps), EVENTS_TOPIC))
            now = end + ROLLOUT_GAP_NS
    return now


def _cdr(msg: Any, topic: str) -> bytes:
    return message_cdr(msg, TOPICS[topic].msgtype)


@dataclass
class _Collected:
    """What a bag says about one rollout."""

    rollout_id: int
    task: str = ""
    scenario: str = "unknown"
    outcome: int | None = None
    max_steps: int = 0
    embeddings: dict[int, np.ndarray] = field(default_factory=dict)
    batches: dict[int, np.ndarray] = field(default_factory=dict)
    exec_steps: int = 0
    action_space: str = ""
    joints: dict[int, np.ndarray] = field(default_factory=dict)
    signals: dict[int, dict[str, float]] = field(default_factory=dict)


def _arm_joints(msg: Any) -> np.ndarray:
    """The arm joint positions (:data:`ARM_JOINT_NAMES`, in that order) of a JointState message that has them."""
    positions = dict(zip(msg.name, np.asarray(msg.position, dtype=np.float64)))
    return np.array([positions[name] for name in ARM_JOINT_NAMES], dtype=np.float64)


def _collect(bag: BagReader) -> list[_Collected]:
    rollouts: dict[int, _Collected] = {}
    batch_stamps: list[tuple[_Collected, int, int]] = []  # (rollout, step, the batch's stamp)
    for message in bag.messages([EMBEDDING_TOPIC, ACTIONS_TOPIC, EVENTS_TOPIC, STEP_SIGNALS_TOPIC]):
        msg = bag.decode(message)
        record = rollouts.setdefault(int(msg.rollout_id), _Collected(int(msg.rollout_id), task=bag.info.task,
                                                                     exec_steps=bag.info.exec_steps))
        if message.topic == EVENTS_TOPIC:
            if msg.event == RolloutEvent.EVENT_START:
                record.task, record.scenario, record.max_steps = msg.task or record.task, msg.scenario, msg.max_steps
            elif msg.event == RolloutEvent.EVENT_END:
                record.outcome = int(msg.outcome)
        elif message.topic == EMBEDDING_TOPIC:
            record.embeddings[int(msg.step)] = np.asarray(msg.data, dtype=np.float32).ravel()
        elif message.topic == STEP_SIGNALS_TOPIC:
            try:
                record.signals[int(msg.step)] = signals_of(msg)
            except ValueError as error:
                raise BagError(f"{bag.path}: rollout {record.rollout_id} step {msg.step}: step signals: {error}") \
                    from error
        else:
            shape = (int(msg.batch_size), int(msg.horizon), int(msg.action_dim))
            data = np.asarray(msg.data, dtype=np.float32)
            if data.size != int(np.prod(shape)):
                raise BagError(f"{bag.path}: rollout {record.rollout_id} step {msg.step}: action batch holds "
                               f"{data.size} values, not B x H x D = {shape}")
            record.batches[int(msg.step)] = data.reshape(shape)
            record.exec_steps, record.action_space = int(msg.exec_steps), str(msg.action_space)
            batch_stamps.append((record, int(msg.step), stamp_ns(msg.header.stamp)))
    _resolve_joints(bag, batch_stamps)
    return list(rollouts.values())


def _resolve_joints(bag: BagReader, batch_stamps: list[tuple[_Collected, int, int]]) -> None:
    """Each batch's joint position: the ACE node's rule over every state of the bag, not only those logged
    before the batch (a recorder can take a batch before the states stamped up to it: other topics, another
    publisher; seen under load). A second pass over the states keeps one per batch at most, so a bag of many
    ``/joint_states`` costs no more memory than its batches."""
    if not batch_stamps or JOINT_STATES_TOPIC not in bag.topics:
        return
    lookup = LatestNotAfter(stamp for _, _, stamp in batch_stamps)
    for message in bag.messages([JOINT_STATES_TOPIC]):
        msg = bag.decode(message)
        if all(name in msg.name for name in ARM_JOINT_NAMES):
            lookup.offer(stamp_ns(msg.header.stamp), _arm_joints(msg))
    positions = lookup.positions()
    for record, step, stamp in batch_stamps:
        if stamp in positions:
            record.joints[step] = positions[stamp]


def _tables(record: _Collected, has_actions: bool) -> list[tuple[str, dict[int, Any]]]:
    """The per-step tables every step of ``record`` must have: embeddings, batches (in a bag with the action topic),
    signals (in a rollout with any)."""
    tables: list[tuple[str, dict[int, Any]]] = [("observation embedding", record.embeddings)]
    if has_actions:
        tables.append(("action batch", record.batches))
    if record.signals:
        tables.append(("step signals message", record.signals))
    return tables


def _signal_series(record: _Collected, steps: list[int], path: Path) -> dict[str, np.ndarray]:
    """The rollout's signals as ``{name: [T]}``; every step must name the same signals."""
    if not record.signals:
        return {}
    names = list(record.signals[steps[0]])
    for step in steps[1:]:
        if set(record.signals[step]) != set(names):
            raise BagError(f"{path}: rollout {record.rollout_id} step {step}: step signals name "
                           f"{', '.join(sorted(record.signals[step])) or 'none'}, step {steps[0]} "
                           f"{', '.join(sorted(names)) or 'none'}: every step of a rollout names the same signals")
    return {name: np.array([record.signals[s][name] for s in steps], dtype=np.float64) for name in names}


def _to_rollout(record: _Collected, path: Path, has_actions: bool) -> Rollout:
    steps = sorted(set(record.embeddings) | set(record.batches) | set(record.signals))
    for step in range(len(steps)):
        for name, table in _tables(record, has_actions):
            if step not in table:
                raise BagError(f"{path}: rollout {record.rollout_id} has no {name} for step {step} "
                               f"(steps {steps[0]}..{steps[-1]} present)")
    metadata: dict[str, Any] = {"bag": str(path), "max_steps": record.max_steps}
    if all(step in record.joints for step in steps):
        metadata[JOINT_POSITIONS_KEY] = np.stack([record.joints[s] for s in steps])
    elif record.action_space == "joint_velocity":
        LOG.warning("%s: rollout %d: no /joint_states with %s before step %d: ACE cannot score its joint "
                    "velocities", path, record.rollout_id, ", ".join(ARM_JOINT_NAMES),
                    min(set(steps) - set(record.joints)))
    signals = _signal_series(record, steps, path)
    try:
        return Rollout(
            rollout_id=str(record.rollout_id), task=record.task, scenario=record.scenario,
            embeddings=np.stack([record.embeddings[s] for s in steps]),
            actions=np.stack([record.batches[s] for s in steps]) if has_actions else None,
            exec_steps=record.exec_steps or 1, success=SUCCESS_OF.get(record.outcome),
            action_space=record.action_space or ACTION_SPACES[0], metadata=metadata,
            signals=signals,
        )
    except (RolloutError, ValueError) as error:
        raise BagError(f"{path}: rollout {record.rollout_id}: {error}") from error


def _drop_cut_step(record: _Collected, path: Path, has_actions: bool) -> None:
    """A rollout the bag cuts off (no END: the recording stopped, or ended unfinished) may end inside its last
    step, with some of its messages (embedding, batch, signals) but not all: that step is left out, with a
    warning."""
    tables = _tables(record, has_actions)
    steps = set().union(*(table for _, table in tables))
    if record.outcome is not None or not steps:
        return
    last = max(steps)
    held = [name for name, table in tables if last in table]
    if len(held) == len(tables):
        return
    LOG.warning("%s: rollout %d ends inside step %d (only its %s, no END): that step is left out", path,
                record.rollout_id, last, " and ".join(held))
    for table in (record.embeddings, record.batches, record.joints, record.signals):
        table.pop(last, None)


def read_rollouts(path: Path) -> list[Rollout]:
    """The rollouts of one bag, in the order they start; rollouts without any step are left out, a bag
    without embeddings and action batches is refused, and a bag without the action topic gives rollouts
    without action batches (observation-only data)."""
    with BagReader(path) as bag:
        bag.require_any((EMBEDDING_TOPIC, ACTIONS_TOPIC))
        has_actions = ACTIONS_TOPIC in bag.topics
        collected = _collect(bag)
    rollouts = []
    for record in collected:
        _drop_cut_step(record, path, has_actions)
        if not record.embeddings and not record.batches:
            LOG.warning("%s: rollout %d has no steps; left out", path, record.rollout_id)
            continue
        rollouts.append(_to_rollout(record, path, has_actions))
    return rollouts


def layout_of(bag: BagReader) -> BagInfo:
    """The bag's ``custom_data``, with the task, E, B, H, D, h and action space taken from its first
    messages where ``custom_data`` does not say (e.g. a bag of ``fiper record`` or of another tool); a bag
    without action batches has B, H, D 0 and no action space, whatever its ``custom_data`` says."""
    info = bag.info
    if ACTIONS_TOPIC not in bag.topics:
        info = replace(info, batch_size=0, horizon=0, action_dim=0, action_space="")
    if not info.task:
        tasks = (bag.decode(message).task for message in bag.messages([EVENTS_TOPIC]))
        info = replace(info, task=next((task for task in tasks if task), ""))
    if info.embedding_dim and info.action_dim and info.horizon and info.action_space:
        return info
    for topic in (EMBEDDING_TOPIC, ACTIONS_TOPIC):
        message = next(bag.messages([topic]), None)
        if message is None:
            continue
        msg = bag.decode(message)
        if topic == EMBEDDING_TOPIC:
            info = replace(info, embedding_dim=int(np.asarray(msg.data).size))
        else:
            info = replace(info, batch_size=int(msg.batch_size), horizon=int(msg.horizon), action_dim=int(msg.action_dim),
                           exec_steps=int(msg.exec_steps), action_space=str(msg.action_space))
    return info
