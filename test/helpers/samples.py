"""One deterministic, fully populated sample of every fiper_msgs message type.

Publisher and receiver processes build the same samples independently, so a receiver can compare
what arrived over DDS field by field with what was sent.
"""
from __future__ import annotations

import array
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from std_msgs.msg import Header

from fiper_msgs.msg import (ActionChunkBatch, ActionCommand, FailureAlarm, ObservationEmbedding, RolloutEvent, Score,
                            StepSignals)

#: The largest batch the suite publishes (PushT / PushChair shape).
BATCH_SHAPE = (256, 16, 3)


def _header(sec: int) -> Header:
    return Header(stamp=Time(sec=sec, nanosec=123_456_789), frame_id="policy")


def _floats(n: int, seed: int) -> array.array:
    values = np.random.default_rng(seed).standard_normal(n).astype(np.float32)
    values[:4] = [np.float32(1e-38), np.float32(-0.0), np.float32(3.4e38), np.float32(np.pi)]
    return array.array("f", values.tobytes())


def sample_messages() -> dict[str, Any]:
    """Map each ROS type name ``fiper_msgs/msg/X`` to one populated instance."""
    b, h, d = BATCH_SHAPE
    return {
        "fiper_msgs/msg/ObservationEmbedding": ObservationEmbedding(
            header=_header(11), rollout_id=2**63 + 5, step=41, data=_floats(512, 1), shape=[512]
        ),
        "fiper_msgs/msg/ActionChunkBatch": ActionChunkBatch(
            header=_header(12), rollout_id=7, step=4_000_000_000, batch_size=b, horizon=h, action_dim=d,
            exec_steps=8, data=_floats(b * h * d, 2), action_space=ActionChunkBatch.ACTION_SPACE_EE_POSITION,
        ),
        "fiper_msgs/msg/RolloutEvent": RolloutEvent(
            header=_header(13), rollout_id=7, event=RolloutEvent.EVENT_END, outcome=RolloutEvent.OUTCOME_FAILURE,
            task="sorting", scenario="ood_box_position", max_steps=75,
        ),
        "fiper_msgs/msg/Score": Score(
            header=_header(14), rollout_id=7, step=3, detector=Score.DETECTOR_ACE, score=1.5, windowed_score=4.25,
            threshold=float("nan"), exceeded=True, window=12, latency_ms=0.375, complete=False,
        ),
        "fiper_msgs/msg/FailureAlarm": FailureAlarm(
            header=_header(15), rollout_id=7, step=3, state=FailureAlarm.STATE_ALARM, latched=True,
            obs_exceeded=True, act_exceeded=False, eta_obs=10.5, gamma_obs=9.25, eta_act=float("inf"),
            gamma_act=-1.0, combine=FailureAlarm.COMBINE_OR, reason="rnd_oe exceeded (or) — ünïcode", heartbeat=True,
            detectors=["rnd_oe", "ace", "signal_ünï"], eta=[10.5, float("inf"), 0.25],
            gamma=[9.25, -1.0, 0.5], exceeded=[True, False, False], votes=1,
        ),
        "fiper_msgs/msg/ActionCommand": ActionCommand(
            header=_header(16), rollout_id=7, step=3, num_actions=4, action_dim=8, data=_floats(32, 3),
            action_space=ActionCommand.ACTION_SPACE_JOINT_VELOCITY,
        ),
        "fiper_msgs/msg/StepSignals": StepSignals(
            header=_header(17), rollout_id=2**64 - 1, step=3, names=["chunk_mse", "eef_z", "gripper_oscillation"],
            values=array.array("d", [1e-300, -0.0, 1.7976931348623157e308]),
        ),
    }


def topic_of(type_name: str) -> str:
    """The test topic a sample of ``type_name`` travels on."""
    return "/fiper_test/" + type_name.rsplit("/", 1)[-1]


def as_plain(value: Any) -> Any:
    """Turn a message into nested plain data for exact comparison (floats by their bit pattern)."""
    if hasattr(value, "get_fields_and_field_types"):
        return {name: as_plain(getattr(value, name)) for name in value.get_fields_and_field_types()}
    if isinstance(value, array.array):
        return (value.typecode, value.tobytes())
    if isinstance(value, np.ndarray):
        return (value.dtype.str, value.tobytes())
    if isinstance(value, float):
        return ("f", np.float64(value).tobytes())
    if isinstance(value, (list, tuple)):
        return [as_plain(v) for v in value]
    return value
