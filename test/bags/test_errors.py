"""Robustness of the commands that read bags and calibrations (docs/reliability.md, "Bags and calibration
files" and "Recordings"): every failure class of helpers.bag_damage and helpers.calibration_damage, on real
files made by the project's writer and calibrate and then damaged, run through the ``fiper`` entry point of
every command that reads it, gives exit status 2 and one line on stderr that starts with ``fiper COMMAND:``
and names the file and what is wrong (no traceback), and leaves no output behind. An unfinished bag (cut
after a complete chunk, or without metadata.yaml) is read up to its last complete chunk with a one-line
warning instead, exactly as a bag of those messages; with --strict it is refused like the others."""
from __future__ import annotations

import json
import pickle
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.bag_damage import BAG_DAMAGES, CHUNK, UNFINISHED, chunk_messages, mcap_of, records, write_recorded_bag
from helpers.calibration_damage import CALIBRATION_DAMAGES, FIT_DAMAGES, fit_damages
from helpers.synthetic import make_rollout
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from fiper_ros.bagio.reader import BagReader
from fiper_ros.bagio.rollout_bags import read_rollouts, write_rollouts
from fiper_ros.bagio.schema import BagInfo
from fiper_ros.bagio.writer import BagWriter
from fiper_ros.cli import main
from fiper_ros.core.calibration import load_calibration
from fiper_ros.core.rollout import RolloutSet

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "bags"
SORTING_CALIBRATION = ROOT / "models" / "sorting" / "calibration"
GADGET = "acme_msgs/msg/Gadget"

#: command name -> argv for (input bag, calibration, empty output directory).
BAG_COMMANDS: dict[str, Callable[[Path, Path, Path], list[str]]] = {
    "replay --offline": lambda bag, cal, out: ["replay", str(bag), "--offline", "--calibration", str(cal),
                                               "--report", str(out / "report.json")],
    "replay": lambda bag, cal, out: ["replay", str(bag), "--fast", "--calibration", str(cal),
                                     "--report", str(out / "report.json")],
    "calibrate": lambda bag, cal, out: ["calibrate", str(bag), "-o", str(out / "calibration"), "--delta", "0.2"],
    "evaluate": lambda bag, cal, out: ["evaluate", "--data", f"synthetic={bag}", "--tiny", "--no-cache", "--quiet",
                                       "--out", str(out / "results")],
}
#: command name -> argv for (input bag, calibration, empty output directory); replay and demo start the
#: suite's node processes and refuse the calibration while they boot.
CALIBRATION_COMMANDS: dict[str, Callable[[Path, Path, Path], list[str]]] = {
    "replay --offline": BAG_COMMANDS["replay --offline"],
    "replay": BAG_COMMANDS["replay"],
    "collect": lambda bag, cal, out: ["collect", "--task", "sorting", "--episodes", "1", "--ros", "--calibration",
                                      str(cal), "--out", str(out / "collected")],
    "demo": lambda bag, cal, out: ["demo", "--calibration", str(cal), "--no-view", "--out", str(out / "demo")],
}


@pytest.fixture(scope="module")
def recorded_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """20 synthetic successes over several MCAP chunks, written by the project's writer."""
    return write_recorded_bag(tmp_path_factory.mktemp("recorded") / "rollouts")


def refused(argv: list[str], out: Path, capsys: pytest.CaptureFixture[str]) -> str:
    """Run ``fiper ARGV``: exit status 2, one line on stderr, no traceback, nothing in ``out``; the line."""
    status = main(argv)
    err = capsys.readouterr().err
    assert status == 2, err
    assert err.count("\n") == 1 and err.endswith("\n") and "Traceback" not in err, err
    assert sorted(p.name for p in out.iterdir()) == [], "output left behind"
    return err


def _prefix(command: str) -> str:
    return f"fiper {command.split()[0]}: "


def _damaged(recorded_bag: Path, damage: str, tmp_path: Path) -> tuple[Path, str, Path]:
    """A damaged copy of the recorded bag, the text of its refusal, and an empty output directory."""
    bag = tmp_path / "bags" / "rollouts"
    shutil.copytree(recorded_bag, bag)
    expected = BAG_DAMAGES[damage](bag)
    out = tmp_path / "out"
    out.mkdir()
    return bag, expected, out


@pytest.mark.parametrize("command", BAG_COMMANDS)
@pytest.mark.parametrize("damage", [d for d in BAG_DAMAGES if d not in UNFINISHED])
def test_a_damaged_bag_is_refused_by_every_command_that_reads_it(
        damage: str, command: str, recorded_bag: Path, small_calibration: Path, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    bag, expected, out = _damaged(recorded_bag, damage, tmp_path)
    err = refused(BAG_COMMANDS[command](bag, small_calibration, out), out, capsys)
    assert err.startswith(_prefix(command) + expected), err


@pytest.mark.parametrize("command", BAG_COMMANDS)
@pytest.mark.parametrize("damage", UNFINISHED)
def test_an_unfinished_bag_is_refused_with_strict(
        damage: str, command: str, recorded_bag: Path, small_calibration: Path, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    bag, expected, out = _damaged(recorded_bag, damage, tmp_path)
    err = refused([*BAG_COMMANDS[command](bag, small_calibration, out), "--strict"], out, capsys)
    assert err.startswith(_prefix(command) + expected), err
    assert err.endswith(f"; 'fiper bag recover {bag}' finishes it\n"), err


def _bag_of_the_first(source: Path, count: int, path: Path) -> Path:
    """A finished bag of the first ``count`` messages of ``source`` (in log-time order, which is the file
    order of the recorded bag), with its custom_data."""
    with BagReader(source) as reader, BagWriter(path) as writer:
        writer.info = reader.info
        for _, message in zip(range(count), reader.messages()):
            writer.write(message.topic, message.log_time_ns, message.raw)
    return path


#: command -> argv for (bag, calibration, output directory) when the bag is read to the end.
READING_COMMANDS: dict[str, Callable[[Path, Path, Path], list[str]]] = {
    "replay --offline": BAG_COMMANDS["replay --offline"],
    "calibrate": lambda bag, cal, out: [*BAG_COMMANDS["calibrate"](bag, cal, out), "--max-epochs", "2",
                                        "--min-rollouts", "2"],
}


@pytest.mark.parametrize("command", READING_COMMANDS)
@pytest.mark.parametrize("damage", UNFINISHED)
def test_an_unfinished_bag_is_read_up_to_its_last_complete_chunk(
        damage: str, command: str, recorded_bag: Path, small_calibration: Path, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """The report or calibration equals that of a finished bag of the messages of the complete chunks (counted
    by the test's own walk), and the command says in one line what it read."""
    bag, expected, out = _damaged(recorded_bag, damage, tmp_path)
    counts = chunk_messages(mcap_of(bag).read_bytes())
    whole = chunk_messages(mcap_of(recorded_bag).read_bytes())
    assert counts == whole[:len(counts)] and (len(counts) < len(whole) or damage != "cut_inside_a_chunk")
    assert main(READING_COMMANDS[command](bag, small_calibration, out)) == 0
    err = capsys.readouterr().err
    warning = [line for line in err.splitlines() if " warning: " in line]
    assert len(warning) == 1, err
    assert warning[0].startswith(f"{_prefix(command)}warning: ") and expected.split(": the recording")[0] in warning[0]
    assert warning[0].endswith(f"reading its {len(counts)} complete chunk(s), {sum(counts)} messages ('fiper bag "
                               f"recover {bag}' finishes the bag)"), warning[0]
    reference = _bag_of_the_first(recorded_bag, sum(counts), tmp_path / "reference" / "rollouts")
    (tmp_path / "reference_out").mkdir()
    assert main(READING_COMMANDS[command](reference, small_calibration, tmp_path / "reference_out")) == 0
    if command == "calibrate":
        assert (load_calibration(out / "calibration").content_hash
                == load_calibration(tmp_path / "reference_out" / "calibration").content_hash)
    else:
        report, reference_report = (json.loads((o / "report.json").read_text())
                                    for o in (out, tmp_path / "reference_out"))
        assert report["rollouts"] == reference_report["rollouts"] and report["rollouts"]


@pytest.mark.parametrize("damage", ["cut_inside_a_chunk", "no_metadata"])
def test_evaluate_reads_an_unfinished_bag(damage: str, recorded_bag: Path, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    """Beside a finished bag of the test split, so that the tiny sweep runs to its end."""
    bag, _, out = _damaged(recorded_bag, damage, tmp_path)
    test = tmp_path / "test_rollouts"
    write_rollouts(test, [make_rollout(50, length=60), make_rollout(51, length=60, fail=True)], [101, 102],
                   BagInfo(task="synthetic", synthetic=True, source="test", split="test"))
    # --split same: the bag cut inside its second chunk keeps 7 successes, too few to split (that refusal is
    # tested in test/evaluation); what is tested here is reading the cut bag
    argv = ["evaluate", "--data", f"synthetic={bag},{test}", "--tiny", "--no-cache", "--quiet", "--no-plots",
            "--split", "same"]
    assert main([*argv, "--out", str(out / "results")]) == 0
    err = capsys.readouterr().err
    assert "fiper evaluate: warning: " in err and f"('fiper bag recover {bag}' finishes the bag)" in err, err
    assert (out / "results" / "results.md").is_file()


def test_the_undamaged_bag_spans_several_chunks_and_is_read(
        recorded_bag: Path, small_calibration: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The table's starting point: the same commands accept the bag before it is damaged."""
    assert sum(op == CHUNK for _, op, _ in records(mcap_of(recorded_bag).read_bytes())) >= 3
    assert main(["replay", str(recorded_bag), "--offline", "--calibration", str(small_calibration)]) == 0
    assert capsys.readouterr().out.count("rollout ") == 20
    assert main(["calibrate", str(recorded_bag), "-o", str(tmp_path / "cal"), "--max-epochs", "2", "--delta", "0.2"]) == 0
    assert (tmp_path / "cal" / "calibration.yaml").is_file()


@pytest.mark.parametrize("command", CALIBRATION_COMMANDS)
@pytest.mark.parametrize("damage", (*CALIBRATION_DAMAGES, *FIT_DAMAGES))
def test_a_damaged_or_unfitting_calibration_is_refused_by_every_command_that_reads_it(
        command: str, damage: str, recorded_bag: Path, small_calibration: Path, tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    # replay plays the synthetic bag (its calibration: small_calibration); collect and demo run the
    # shipped Sorting policy (its calibration: models/sorting/calibration).
    base, foreign = ((small_calibration, SORTING_CALIBRATION) if command.startswith("replay")
                     else (SORTING_CALIBRATION, small_calibration))
    calibration = tmp_path / "calibration"
    shutil.copytree(base, calibration)
    expected = (CALIBRATION_DAMAGES | fit_damages(base, foreign))[damage](calibration)
    out = tmp_path / "out"
    out.mkdir()
    err = refused(CALIBRATION_COMMANDS[command](recorded_bag, calibration, out), out, capsys)
    if damage in FIT_DAMAGES:
        assert err.startswith(f"{_prefix(command)}calibration {calibration} does not fit ") and expected in err, err
    else:
        assert err.startswith(_prefix(command) + expected), err


# -- fiper convert --------------------------------------------------------------------------------------

def _fiper_layout(root: Path, test_dims: tuple[int, ...] = (2, 2)) -> Path:
    """<root>/task/rollouts/{calibration,test}/*.pkl of the FIPER authors' layout (E = 6, B = 4, H = 3)."""
    rng = np.random.default_rng(0)
    for split, dims in (("calibration", (2, 2)), ("test", test_dims)):
        directory = root / "task" / "rollouts" / split
        directory.mkdir(parents=True)
        for index, d in enumerate(dims):
            steps = [{"obs_embedding": rng.normal(size=6), "action_pred": rng.normal(size=(4, 3, d))} for _ in range(5)]
            with (directory / f"rollout_{index}_success.pkl").open("wb") as stream:
                pickle.dump({"metadata": {}, "rollout": steps}, stream)
    return root / "task"


#: A damage of one source pickle -> the text of its refusal.
PICKLE_DAMAGES: dict[str, tuple[Callable[[bytes], bytes], str]] = {
    "zero_bytes": (lambda data: b"", "not a readable pickle (EOFError"),
    "truncated": (lambda data: data[: len(data) // 2], "not a readable pickle ("),
    "random_bytes": (lambda data: np.random.default_rng(0).bytes(1000), "not a readable pickle ("),
    "another_structure": (lambda data: pickle.dumps([1, 2, 3]), "not a FIPER rollout pickle"),
}


@pytest.mark.parametrize("damage", PICKLE_DAMAGES)
def test_a_damaged_source_file_is_refused_by_convert(damage: str, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    source = _fiper_layout(tmp_path / "src")
    victim = source / "rollouts" / "test" / "rollout_1_success.pkl"
    change, text = PICKLE_DAMAGES[damage]
    victim.write_bytes(change(victim.read_bytes()))
    out = tmp_path / "out"
    out.mkdir()
    err = refused(["convert", "fiper", str(source), "--exec-steps", "2", "-o", str(out / "bags")], out, capsys)
    assert err.startswith(f"fiper convert: {victim}: {text}"), err


def test_convert_failing_after_its_first_bag_leaves_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The calibration bag is written, then the test split (rollouts of two action sizes) fails: the
    staging directory holding the finished bag goes too."""
    source = _fiper_layout(tmp_path / "src", test_dims=(2, 3))
    out = tmp_path / "out"
    out.mkdir()
    convert = ["convert", "fiper", "--exec-steps", "2", "-o", str(out / "bags")]
    err = refused([*convert, str(source)], out, capsys)
    assert "one bag holds one layout" in err
    assert main([*convert, str(_fiper_layout(tmp_path / "good"))]) == 0
    assert sorted(p.name for p in (out / "bags").iterdir()) == ["calibration_rollouts", "test_rollouts"]


@pytest.mark.parametrize("damage", ["truncated", "random_bytes"])
def test_a_damaged_rollout_set_is_refused_by_evaluate(damage: str, tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "rollouts.npz"
    RolloutSet([make_rollout(seed) for seed in range(4)], [make_rollout(9, fail=True)]).save_npz(path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2] if damage == "truncated" else np.random.default_rng(0).bytes(len(data)))
    out = tmp_path / "out"
    out.mkdir()
    err = refused(["evaluate", "--data", f"synthetic={path}", "--tiny", "--out", str(out / "results")], out, capsys)
    assert err.startswith(f"fiper evaluate: {path}: not a readable rollout set, damaged or not written by "
                          "save_npz ("), err


# -- outputs of a failed run ----------------------------------------------------------------------------

def test_a_failed_evaluate_leaves_an_existing_output_folder_as_it_was(
        recorded_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "results"
    out.mkdir()
    (out / "results.md").write_text("the previous run\n")
    bag = tmp_path / "bag"
    shutil.copytree(recorded_bag, bag)
    BAG_DAMAGES["changed_byte_in_a_chunk"](bag)
    assert main(["evaluate", "--data", f"synthetic={bag}", "--tiny", "--no-cache", "--quiet", "--out", str(out)]) == 2
    assert "corrupt MCAP data" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag", "results"]  # no staging left beside it
    assert [p.name for p in out.iterdir()] == ["results.md"]
    assert (out / "results.md").read_text() == "the previous run\n"


def test_a_report_path_that_is_a_folder_is_refused_before_replaying(
        recorded_bag: Path, small_calibration: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "report").mkdir()
    (tmp_path / "report" / "keep.txt").write_text("x")
    assert main(["replay", str(recorded_bag), "--offline", "--calibration", str(small_calibration),
                 "--report", str(tmp_path / "report")]) == 2
    assert capsys.readouterr().err == f"fiper replay: --report {tmp_path / 'report'} is a directory: give a file name\n"
    assert (tmp_path / "report" / "keep.txt").read_text() == "x"


# -- what is not an error -------------------------------------------------------------------------------

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
    status = main(["replay", str(bag), "--offline", "--calibration", str(small_calibration)])
    assert status == 0 and capsys.readouterr().out.count("rollout ") == 4


def test_every_shipped_bag_passes_the_checks() -> None:
    """The sample bags (written before chunks had checksums) open: their schema is the installed one."""
    from fiper_ros.bagio.reader import find_bags

    bags = find_bags([SAMPLES])
    assert len(bags) >= 5
    for bag in bags:
        with BagReader(bag) as reader:
            assert reader.topics


def test_calibration_of_another_shape_is_refused(small_bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    calibration = SAMPLES / "pretzel_synthetic" / "calibration"
    assert main(["replay", str(small_bag), "--offline", "--calibration", str(calibration)]) == 2
    assert capsys.readouterr().err == (
        f"fiper replay: calibration {calibration} does not fit bag {small_bag}: calibration mismatch "
        "for embedding_dim: expected 512, got 16\n")


def test_missing_calibration_is_refused(small_bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["replay", str(small_bag), "--fast"]) == 2
    assert "no calibration: give --calibration DIR" in capsys.readouterr().err


def test_a_replayed_suite_gets_the_robot_model_on_its_ace_node_only(tmp_path: Path) -> None:
    from fiper_ros.client.suite_process import ACE_MODULE, installed_launch, replay_config
    from fiper_ros.core.detectors import DETECTORS, OBSERVATION_ONLY
    from fiper_ros.core.kinematics import RobotModel
    from fiper_ros.launcher.config import load_launch

    urdf = tmp_path / "robot.urdf"
    urdf.write_text("<robot name='r'/>")
    plain = load_launch(replay_config(installed_launch(), tmp_path, DETECTORS, tmp_path / "plain.yaml"))
    config = load_launch(replay_config(installed_launch(), tmp_path, DETECTORS, tmp_path / "suite.yaml",
                                       RobotModel(str(urdf), "tool0", 0.1)))
    for spec, before in zip(config.nodes, plain.nodes, strict=True):
        assert before.parameters["use_sim_time"] is True and before.parameters["calibration_dir"] == str(tmp_path)
        if spec.module == ACE_MODULE:
            assert spec.parameters == before.parameters | {"urdf_path": str(urdf.resolve()), "ee_frame": "tool0"}
        else:
            assert spec.parameters == before.parameters
    assert [s.module for s in config.nodes].count(ACE_MODULE) == 1
    alone = load_launch(replay_config(installed_launch(), tmp_path, OBSERVATION_ONLY, tmp_path / "alone.yaml"))
    assert [spec.name for spec in alone.nodes] == ["rnd_oe_node", "fusion_node"]


@pytest.mark.parametrize("command", ["demo", "collect"])
def test_a_calibration_that_declares_no_detector_is_refused_before_any_node_starts(
        command: str, recorded_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # The suite runs the scoring nodes of the declared detectors (an observation-only calibration runs RND-OE
    # alone: test/demo/test_demo_observation_only.py); a calibration that declares none has no suite to run.
    calibration = tmp_path / "no_detector"
    shutil.copytree(SORTING_CALIBRATION, calibration)
    content = yaml.safe_load((calibration / "calibration.yaml").read_text())
    content["settings"]["detectors"] = []
    (calibration / "calibration.yaml").write_text(yaml.safe_dump(content))
    out = tmp_path / "out"
    out.mkdir()
    err = refused(CALIBRATION_COMMANDS[command](recorded_bag, calibration, out), out, capsys)
    assert err == (f"fiper {command}: {calibration / 'calibration.yaml'}: malformed entry (declare each detector once, "
                   "at least one, got (none))\n")
