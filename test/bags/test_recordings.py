"""Recordings survive a crash (docs/bags.md, "What survives which stop"; docs/reliability.md, "Recordings"):
``fiper record`` and ``fiper snapshot`` run as their own processes over DDS (loopback) while the test publishes
a known stream (fixed CDR bytes, 50 messages a second), and are stopped by SIGKILL or SIGTERM. A killed
recorder leaves an unfinished bag; ``fiper replay --offline`` reads it with a warning (``--strict`` refuses
it), ``fiper bag recover`` finishes it, and the finished bag holds every message received more than one
chunk period before the kill, bit for bit and in order, readable by rosbags' ``AnyReader`` and by the
``mcap`` package's reader. Killing the power is approximated on the files: test_recover.py."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from collections.abc import Sequence
from pathlib import Path

import pytest
from helpers.dds import spawn_python, stop
from helpers.stream import Policy, Sent, alarm_cdr, start_cdr, step_cdr
from helpers.synthetic import make_rollout
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader

from fiper_msgs.msg import FailureAlarm
from fiper_ros.bagio.recover import unfinished
from fiper_ros.bagio.storage import Salvage
from fiper_ros.cli import main
from fiper_ros.interface.topics import ACTIONS_TOPIC, ALARM_TOPIC, EMBEDDING_TOPIC, EVENTS_TOPIC

#: ``--chunk-s`` of the recorders under test.
CHUNK_S = 0.5
#: How much later than its publication a message may reach a chunk the recorder hands to the disk (DDS delivery
#: and the recorder's loop, on a shared 2-core machine): generous.
SLACK_S = 1.5
#: One policy step (an embedding and an action batch) every 40 ms.
PERIOD_S = 0.04
#: The rollout the assertions are about; the warm-up rollout before it proves that every topic is matched.
ROLLOUT, WARM_UP = 5, 4


def _bag_messages(bag: Path) -> list[tuple[str, bytes]]:
    """``(topic, raw)`` of a finished bag in log-time order, read by rosbags' AnyReader; the mcap package's
    reader must read the same."""
    with AnyReader([bag]) as reader:
        ours = [(c.topic, bytes(raw)) for c, _, raw in reader.messages()]
    (file,) = bag.glob("*.mcap")
    with file.open("rb") as stream:
        theirs = [(channel.topic, message.data) for _, channel, message in make_reader(stream).iter_messages()]
    assert ours == theirs
    return ours


def _holds(bag_messages: list[tuple[str, bytes]], sent: Sequence[Sent], first_ns: int, last_ns: int) -> int:
    """Assert that, per topic, the bag holds a contiguous run of the ``sent`` messages, bit for bit and in order,
    covering every one published in ``[first_ns, last_ns]``; returns how many of ``sent`` it holds."""
    held = 0
    for topic in {s.topic for s in sent}:
        mine = [s for s in sent if s.topic == topic]
        index = {s.raw: i for i, s in enumerate(mine)}
        got = [index[raw] for t, raw in bag_messages if t == topic and raw in index]
        wanted = [i for i, s in enumerate(mine) if first_ns <= s.time_ns <= last_ns]
        if wanted:
            assert got and got[0] <= wanted[0] and got[-1] >= wanted[-1], (
                f"{topic}: holds sent messages {got[:1]}..{got[-1:]}, must hold {wanted[0]}..{wanted[-1]}")
        if got:
            assert got == list(range(got[0], got[-1] + 1)), f"{topic}: not a contiguous run of what was sent"
        held += len(got)
    return held


def _on_disk(bag: Path, topic: str) -> bool:
    """Whether the recorder has handed a chunk with a message on ``topic`` to the disk (its file, read as it
    is written: the positive event that the recorder is matched before the measured stream starts)."""
    files = list(bag.glob("*.mcap")) if bag.is_dir() else []
    if not files:
        return False
    records = list(Salvage(files[0]).records())
    channels = {r.id for r in records if getattr(r, "topic", None) == topic}
    return any(getattr(r, "channel_id", None) in channels for r in records)


def _kill(proc: subprocess.Popen[str], sig: int) -> None:
    os.killpg(proc.pid, sig)
    proc.wait(timeout=30)


def _steps(policy: Policy, rollout_id: int, steps: range, alarm_from: int | None = None) -> list[Sent]:
    """Publish the steps of a synthetic rollout, one every :data:`PERIOD_S` (with an alarm each if
    ``alarm_from`` is given: ALARM from that step on)."""
    rollout = make_rollout(400 + rollout_id, length=max(steps) + 1)
    sent = []
    for step in steps:
        sent.extend(policy.publish(topic, raw) for topic, raw in step_cdr(rollout_id, step, rollout))
        if alarm_from is not None:
            state = FailureAlarm.STATE_ALARM if step >= alarm_from else FailureAlarm.STATE_OK
            sent.append(policy.publish(ALARM_TOPIC, alarm_cdr(rollout_id, step, state)))
        policy.spin_until(lambda: False, PERIOD_S)
    return sent


def _warm_up_recorder(policy: Policy, bag: Path) -> None:
    """Publish warm-up steps until the recorder wrote one of each topic to disk."""
    rollout = make_rollout(400, length=1000)
    for step in range(1000):
        for topic, raw in step_cdr(WARM_UP, step, rollout):
            policy.publish(topic, raw)
        policy.spin_until(lambda: False, 0.1)
        if step % 5 == 4 and _on_disk(bag, EMBEDDING_TOPIC) and _on_disk(bag, ACTIONS_TOPIC):
            return
    raise AssertionError(f"{bag}: the recorder wrote no warm-up step in 100 s")


def _record_and_stop(policy: Policy, tmp_path: Path, ros_domain: int, steps: int,
                     sig: int) -> tuple[Path, list[Sent], int]:
    """``fiper record`` in a process of its own; once it wrote the warm-up, a rollout of ``steps`` steps, then
    ``sig``. The bag, what was sent after the warm-up, and when the signal went out."""
    bag = tmp_path / "recording"
    proc = spawn_python(["-m", "fiper_ros.cli", "record", "-o", str(bag), "--chunk-s", str(CHUNK_S)], ros_domain)
    try:
        assert policy.subscribed((EMBEDDING_TOPIC, ACTIONS_TOPIC, EVENTS_TOPIC))
        _warm_up_recorder(policy, bag)
        sent = [policy.publish(EVENTS_TOPIC, start_cdr(ROLLOUT)), *_steps(policy, ROLLOUT, range(steps))]
        stopped_ns = time.time_ns()
        _kill(proc, sig)
    finally:
        output = stop(proc)
    assert proc.returncode == (-sig if sig == signal.SIGKILL else 0), output
    return bag, sent, stopped_ns


def test_a_killed_recorder_loses_at_most_its_open_chunk(tmp_path: Path, ros_domain: int, policy: Policy,
                                                        small_calibration: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    bag, sent, killed_ns = _record_and_stop(policy, tmp_path, ros_domain, 150, signal.SIGKILL)
    assert bag.is_dir() and not (bag / "metadata.yaml").exists() and unfinished(bag)

    # Unfinished: replay --offline reads what it holds, with one warning line; --strict refuses it.
    report, recovered_report = tmp_path / "unfinished.json", tmp_path / "recovered.json"
    replay = ["replay", "--offline", "--calibration", str(small_calibration), "--report"]
    assert main([*replay, str(report), str(bag)]) == 0
    err = capsys.readouterr().err
    assert err.startswith(f"fiper replay: warning: {bag}: MCAP data but no metadata.yaml") and err.count("\n") == 1
    assert "complete chunk(s)" in err and f"('fiper bag recover {bag}' finishes the bag)" in err
    assert main([*replay, str(report), str(bag), "--strict"]) == 2
    assert capsys.readouterr().err.startswith(f"fiper replay: {bag}: MCAP data but no metadata.yaml")

    assert main(["bag", "recover", str(bag)]) == 0
    out = capsys.readouterr().out
    assert "messages: /fiper/action_chunks " in out and f"{bag}: finished" in out, out
    messages = _bag_messages(bag)
    held = _holds(messages, sent, sent[0].time_ns, killed_ns - int((CHUNK_S + SLACK_S) * 1e9))
    assert f"/fiper/observation_embedding {sum(t == EMBEDDING_TOPIC for t, _ in messages)}" in out

    # The replay of the unfinished bag said what the finished bag says: the alarms of the messages it holds.
    assert main([*replay, str(recovered_report), str(bag)]) == 0
    rollouts = json.loads(report.read_text())["rollouts"]
    assert rollouts == json.loads(recovered_report.read_text())["rollouts"]
    assert {r["rollout_id"] for r in rollouts} == {WARM_UP, ROLLOUT}
    print(f"SIGKILL: kept {held} of {len(sent)} messages")


def test_a_terminated_recorder_finishes_its_bag(tmp_path: Path, ros_domain: int, policy: Policy,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    bag, sent, stopped_ns = _record_and_stop(policy, tmp_path, ros_domain, 100, signal.SIGTERM)
    assert unfinished(bag) is None
    _holds(_bag_messages(bag), sent, sent[0].time_ns, stopped_ns - int(SLACK_S * 1e9))
    assert main(["bag", "recover", str(bag)]) == 0
    assert capsys.readouterr().out == f"{bag}: a finished bag, nothing to recover\n"


def test_a_snapshot_survives_its_black_box(tmp_path: Path, ros_domain: int, policy: Policy) -> None:
    """One black box, two rises: the first snapshot finishes (its after-window passes), then the black box is
    killed during the second one's after-window. The first bag is whole; the second, recovered, holds its
    before-window and the after-window up to one chunk before the kill."""
    before_s, after_s, out = 3.0, 6.0, tmp_path / "snapshots"
    proc = spawn_python(["-m", "fiper_ros.cli", "snapshot", "-o", str(out), "--before", str(before_s), "--after",
                         str(after_s), "--chunk-s", str(CHUNK_S)], ros_domain)
    try:
        assert policy.subscribed((EMBEDDING_TOPIC, ACTIONS_TOPIC, EVENTS_TOPIC, ALARM_TOPIC)), stop(proc)
        # The warm-up rollout rises at step 10 and goes on until its snapshot is finished.
        first = _steps(policy, WARM_UP, range(20), alarm_from=10)
        assert policy.spin_until(lambda: any((b / "metadata.yaml").is_file() for b in out.glob("*")), timeout=30)
        rollout = [policy.publish(EVENTS_TOPIC, start_cdr(ROLLOUT)), *_steps(policy, ROLLOUT, range(100),
                                                                             alarm_from=1000)]
        rise = _steps(policy, ROLLOUT, range(100, 101), alarm_from=100)
        after = _steps(policy, ROLLOUT, range(101, 101 + int(4.5 / PERIOD_S)), alarm_from=100)
        killed_ns = time.time_ns()
        _kill(proc, signal.SIGKILL)
    finally:
        output = stop(proc)
    assert proc.returncode == -signal.SIGKILL, output
    finished, cut = sorted(out.iterdir(), key=lambda b: b.name)
    assert finished.name.endswith(f"_rollout{WARM_UP}_step10") and unfinished(finished) is None
    assert cut.name.endswith(f"_rollout{ROLLOUT}_step100") and unfinished(cut)
    whole = _bag_messages(finished)
    assert (ALARM_TOPIC, [s for s in first if s.topic == ALARM_TOPIC][10].raw) in whole  # the rise
    assert main(["bag", "recover", str(cut)]) == 0
    sent = rollout + rise + after
    rise_ns = rise[-1].time_ns
    _holds(_bag_messages(cut), sent, rise_ns - int((before_s - SLACK_S) * 1e9),
           killed_ns - int((CHUNK_S + SLACK_S) * 1e9))
    early = {s.raw for s in sent if s.time_ns < rise_ns - int((before_s + SLACK_S) * 1e9)}
    assert not early & {raw for _, raw in _bag_messages(cut)}, "the bag holds more than --before"
