"""The bag schema: MCAP rosbag2 v9 with zstd chunks, offered QoS per connection, custom_data, and the
rollout reader (bag -> core Rollouts)."""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from rclpy.serialization import serialize_message

from fiper_msgs.msg import FailureAlarm
from fiper_ros import __version__
from fiper_ros.bagio.errors import BagError
from fiper_ros.bagio.reader import BagReader, find_bags
from fiper_ros.bagio.rollout_bags import read_rollouts, write_rollouts
from fiper_ros.bagio.schema import BagInfo, normalize_cdr
from fiper_ros.bagio.writer import BagWriter
from fiper_ros.core.rollout import Rollout
from fiper_ros.interface.topics import ACTIONS_TOPIC, ALARM_TOPIC, EMBEDDING_TOPIC, EVENTS_TOPIC, TOPICS


def _metadata(bag: Path) -> dict:
    return yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]


def test_bag_format_custom_data_and_offered_qos(small_bag: Path) -> None:
    meta = _metadata(small_bag)
    assert meta["version"] == 9 and meta["storage_identifier"] == "mcap"
    assert meta["relative_file_paths"] == ["small.mcap"]  # not the temporary name it was written under
    custom = meta["custom_data"]
    assert custom["fiper_schema"] == "1" and custom["code_version"] == __version__
    assert (custom["task"], custom["synthetic"], custom["source"]) == ("synthetic", "true", "test")
    assert [custom[k] for k in ("embedding_dim", "batch_size", "horizon", "action_dim", "exec_steps")] == \
        ["16", "32", "8", "2", "4"]
    assert custom["action_space"] == "ee_position"
    durability = {t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"][0]["durability"]
                  for t in meta["topics_with_message_count"]}
    assert durability == {EVENTS_TOPIC: "transient_local", "/fiper/observation_embedding": "volatile",
                          "/fiper/action_chunks": "volatile"}
    with (small_bag / "small.mcap").open("rb") as stream:
        compressions = {c.compression for c in make_reader(stream).get_summary().chunk_indexes}
    assert compressions == {"zstd"}


def test_custom_data_round_trip() -> None:
    info = BagInfo(task="pretzel", batch_size=30, horizon=16, action_dim=5, exec_steps=8, embedding_dim=512,
                   action_space="ee_position", calibration_hash="ab" * 32, synthetic=True, source="x", split="test",
                   rollout_sources={"1": "a.pkl"})
    assert BagInfo.from_custom_data(info.to_custom_data()) == info
    assert BagInfo.from_custom_data({"other_tool": "x"}) == BagInfo()
    with pytest.raises(BagError, match="malformed custom_data"):
        BagInfo.from_custom_data({"horizon": "sixteen"})


def test_rollout_reader_round_trip(small_bag: Path, rollouts: list[Rollout], rollout_ids: list[int]) -> None:
    back = read_rollouts(small_bag)
    assert [r.rollout_id for r in back] == [str(i) for i in rollout_ids]
    for original, read in zip(rollouts, back):
        assert np.array_equal(original.embeddings, read.embeddings)
        assert np.array_equal(original.actions, read.actions)
        assert (read.task, read.scenario, read.success) == (original.task, original.scenario, original.success)
        assert (read.exec_steps, read.action_space) == (original.exec_steps, original.action_space)


def test_writing_is_deterministic_and_atomic(tmp_path: Path, rollouts: list[Rollout]) -> None:
    digests = []
    for name in ("a", "b"):
        bag = tmp_path / name / "bag"
        write_rollouts(bag, rollouts, [1, 2, 3, 4], BagInfo(task="synthetic"))
        digests.append(hashlib.sha256((bag / "bag.mcap").read_bytes()).hexdigest())
    assert digests[0] == digests[1]
    with pytest.raises(BagError, match="exists already"):
        write_rollouts(tmp_path / "a" / "bag", rollouts, [1, 2, 3, 4], BagInfo())
    with pytest.raises(RuntimeError), BagWriter(tmp_path / "aborted") as writer:
        writer.write(EVENTS_TOPIC, 1, b"\x00\x01\x00\x00")
        raise RuntimeError("interrupted")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "b"]  # nothing of the aborted bag left


def test_alarm_topic_is_recorded_transient_local(tmp_path: Path) -> None:
    msg = FailureAlarm(rollout_id=3, step=4, state=FailureAlarm.STATE_ALARM, combine="and", reason="x")
    raw = normalize_cdr(serialize_message(msg), TOPICS[ALARM_TOPIC].msgtype)
    with BagWriter(tmp_path / "alarm") as writer:
        writer.write(ALARM_TOPIC, 5, raw)
    with BagReader(tmp_path / "alarm") as bag:
        assert bag.offered_qos(ALARM_TOPIC)[0].durability.name == "TRANSIENT_LOCAL"
        assert bag.offered_qos(ALARM_TOPIC)[0].depth == 1
        (message,) = list(bag.messages())
        decoded = bag.decode(message)
    assert (decoded.rollout_id, decoded.step, decoded.state, message.raw) == (3, 4, 1, raw)


def test_reader_names_a_missing_step(tmp_path: Path, small_bag: Path) -> None:
    bag = tmp_path / "gap"
    with BagReader(small_bag) as source, BagWriter(bag) as writer:
        for message in source.messages():
            msg = source.decode(message)
            if message.topic == EMBEDDING_TOPIC and msg.rollout_id == 8 and msg.step == 5:
                continue
            writer.write(message.topic, message.log_time_ns, message.raw)
    with pytest.raises(BagError, match=r"rollout 8 has no observation embedding for step 5"):
        read_rollouts(bag)


def _without(small_bag: Path, bag: Path, drop: set[tuple[str, int, int]], events: bool = True) -> Path:
    """``small_bag`` without the ``(topic, rollout, step)`` messages in ``drop`` (and without the END of rollout
    10, the last, unless ``events``)."""
    with BagReader(small_bag) as source, BagWriter(bag) as writer:
        writer.info = source.info
        for message in source.messages():
            msg = source.decode(message)
            if message.topic == EVENTS_TOPIC and not events and msg.rollout_id == 10 and msg.event == 1:
                continue
            if (message.topic, msg.rollout_id, getattr(msg, "step", -1)) not in drop:
                writer.write(message.topic, message.log_time_ns, message.raw)
    return bag


def test_a_step_cut_off_by_the_end_of_a_recording_is_left_out(tmp_path: Path, small_bag: Path,
                                                               caplog: pytest.LogCaptureFixture) -> None:
    """A recording that ends between the last step's embedding and its action batch: the rollout has no END,
    and that half step is left out, with a line; with the END (a finished rollout) it is an error."""
    last = (ACTIONS_TOPIC, 10, len(read_rollouts(small_bag)[-1].embeddings) - 1)
    cut = read_rollouts(_without(small_bag, tmp_path / "cut", {last}, events=False))
    assert (cut[-1].length, cut[-1].success) == (last[2], None)
    assert f"rollout 10 ends inside step {last[2]} (only its observation embedding, no END)" in caplog.text
    with pytest.raises(BagError, match=f"rollout 10 has no action batch for step {last[2]}"):
        read_rollouts(_without(small_bag, tmp_path / "ended", {last}))


def test_find_bags(tmp_path: Path, small_bag: Path) -> None:
    assert find_bags([small_bag]) == [small_bag]
    assert find_bags([small_bag.parent]) == [small_bag]
    with pytest.raises(BagError, match="no bag"):
        find_bags([tmp_path])
    with pytest.raises(BagError, match="give the bag directory"):
        find_bags([small_bag / "small.mcap"])
