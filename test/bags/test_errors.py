"""Robustness: truncated, corrupt or foreign bags, bags with unknown types and calibrations of another
shape give one clear line naming the file (exit 2, no traceback)."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from fiper_ros.bags.reader import BagReader
from fiper_ros.bags.rollouts import read_rollouts
from fiper_ros.cli import main

SAMPLES = Path(__file__).resolve().parents[2] / "bags"
GADGET = "acme_msgs/msg/Gadget"


def _copy(small_bag: Path, tmp_path: Path, name: str) -> Path:
    bag = tmp_path / name
    shutil.copytree(small_bag, bag)
    return bag


def _replay_offline(bag: Path, calibration: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    status = main(["replay", str(bag), "--offline", "--calibration", str(calibration)])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


@pytest.mark.parametrize("damage", ["truncated", "corrupt", "empty"])
def test_damaged_bag_is_named(damage: str, tmp_path: Path, small_bag: Path, small_calibration: Path,
                              capsys: pytest.CaptureFixture[str]) -> None:
    bag = _copy(small_bag, tmp_path, damage)
    mcap = bag / "small.mcap"
    data = mcap.read_bytes()
    mcap.write_bytes({"truncated": data[: len(data) * 2 // 3],
                      "corrupt": data[:3000] + bytes(range(256)) * 8 + data[5048:],
                      "empty": b""}[damage])
    status, _, err = _replay_offline(bag, small_calibration, capsys)
    assert status == 2, err
    assert err.count("\n") == 1 and err.startswith(f"fiper replay: {bag}:"), err
    assert "Traceback" not in err
    assert main(["calibrate", str(bag), "-o", str(tmp_path / "cal")]) == 2
    assert capsys.readouterr().err.startswith(f"fiper calibrate: {bag}:")
    assert not (tmp_path / "cal").exists()


def test_not_a_bag(tmp_path: Path, small_calibration: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "metadata.yaml").write_text("just: text\n")
    status, _, err = _replay_offline(tmp_path / "notes", small_calibration, capsys)
    assert status == 2 and f"{tmp_path / 'notes'}: metadata.yaml is not rosbag2 metadata" in err


def test_unknown_types_are_decoded_from_the_bag(tmp_path: Path, small_bag: Path, small_calibration: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    definition = "string name\nfloat64[] values\n"
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(definition, GADGET))
    bag = tmp_path / "foreign"
    gadget = store.types[GADGET](name="widget", values=np.array([1.5, 2.5]))
    with BagReader(small_bag) as source, Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {}
        for message in source.messages():
            if message.topic not in connections:
                connections[message.topic] = writer.add_connection(message.topic, message.msgtype, typestore=source.reader.typestore)
            writer.write(connections[message.topic], message.log_time_ns, message.raw)
        extra = writer.add_connection("/acme/gadget", GADGET, typestore=store)
        writer.write(extra, source.start_ns, store.serialize_cdr(gadget, GADGET))
    with BagReader(bag) as reader:  # our typestore knows nothing of acme_msgs: definitions come from the bag
        (message,) = list(reader.messages(["/acme/gadget"]))
        decoded = reader.decode(message)
    assert decoded.name == "widget" and list(decoded.values) == [1.5, 2.5]
    assert len(read_rollouts(bag)) == 4
    status, out, _ = _replay_offline(bag, small_calibration, capsys)
    assert status == 0 and out.count("rollout ") == 4


def test_calibration_of_another_shape_is_refused(small_bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    calibration = SAMPLES / "pretzel_synthetic" / "calibration"
    status, _, err = _replay_offline(small_bag, calibration, capsys)
    assert status == 2
    assert err == (f"fiper replay: calibration {calibration} does not fit bag {small_bag}: calibration mismatch "
                   "for embedding_dim: expected 512, got 16\n")


def test_missing_calibration_is_refused(small_bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(small_bag), "--fast"]) == 2
    assert "no calibration: give --calibration DIR" in capsys.readouterr().err


def test_a_replayed_suite_gets_the_robot_model_on_its_ace_node_only(tmp_path: Path) -> None:
    from fiper_ros.bags.suite_process import ACE_MODULE, installed_config, replay_config
    from fiper_ros.core.kinematics import RobotModel
    from fiper_ros.launch import load_config

    urdf = tmp_path / "robot.urdf"
    urdf.write_text("<robot name='r'/>")
    plain = load_config(replay_config(installed_config(), tmp_path, tmp_path / "plain.yaml"))
    config = load_config(replay_config(installed_config(), tmp_path, tmp_path / "suite.yaml",
                                       RobotModel(str(urdf), "tool0", 0.1)))
    assert config.use_sim_time
    for spec, before in zip(config.nodes, plain.nodes):
        if spec.module == ACE_MODULE:
            assert spec.parameters == before.parameters | {"urdf_path": str(urdf.resolve()), "ee_frame": "tool0"}
        else:
            assert spec.parameters == before.parameters
    assert [s.module for s in config.nodes].count(ACE_MODULE) == 1
