"""Every fiper_msgs type crosses a process boundary over real DDS (loopback) unchanged."""
from __future__ import annotations

import array
import copy

from helpers.dds import spawn_python, stop
from helpers.samples import BATCH_SHAPE, as_plain, sample_messages


def test_every_type_arrives_field_by_field_equal_in_another_process(ros_domain: int) -> None:
    publisher = spawn_python(["-m", "helpers.publish_samples"], ros_domain)
    try:
        receiver = spawn_python(["-m", "helpers.receive_samples", "40"], ros_domain)
        out, _ = receiver.communicate(timeout=90)
    finally:
        pub_out = stop(publisher)
    assert receiver.returncode == 0, f"receiver:\n{out}\npublisher:\n{pub_out}"
    assert out.count("OK ") == len(sample_messages())


def test_batch_sample_is_the_largest_shape() -> None:
    msg = sample_messages()["fiper_msgs/msg/ActionChunkBatch"]
    assert (msg.batch_size, msg.horizon, msg.action_dim) == BATCH_SHAPE
    assert len(msg.data) == 256 * 16 * 3


def test_comparison_sees_a_single_flipped_bit() -> None:
    sample = sample_messages()["fiper_msgs/msg/ActionChunkBatch"]
    changed = copy.deepcopy(sample)
    raw = bytearray(changed.data.tobytes())
    raw[-1] ^= 0x01
    changed.data = array.array("f", bytes(raw))
    assert as_plain(changed) != as_plain(sample)
    assert as_plain(copy.deepcopy(sample)) == as_plain(sample)
