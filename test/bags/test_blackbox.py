"""The black box (``fiper snapshot``) by hand, on its own parts with made-up receive times: the window of a
snapshot, which alarm messages are rises (exactly one bag per rise of a real rollout), and its bounds (the
ring buffer in time and bytes, the rollouts it remembers, the bags open at once). Over DDS: test_capture.py
and test_recordings.py."""
from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from helpers.stream import alarm_cdr, step_cdr
from helpers.synthetic import make_rollout

from fiper_msgs.msg import FailureAlarm
from fiper_ros.bagio.chunks import LiveChunks
from fiper_ros.bagio.reader import BagReader
from fiper_ros.bagio.storage import Salvage
from fiper_ros.client.capture import InfoTracker, TopicTap
from fiper_ros.client.ros_session import RosSession
from fiper_ros.client.snapshot import MAX_OPEN_SNAPSHOTS, TRACKED_ROLLOUTS, BlackBox, Recorder, Rise
from fiper_ros.interface.topics import ALARM_TOPIC, EMBEDDING_TOPIC, TOPICS

ALARM_TYPE, EMBEDDING_TYPE = TOPICS[ALARM_TOPIC].msgtype, TOPICS[EMBEDDING_TOPIC].msgtype
OK, ALARMED, UNKNOWN = FailureAlarm.STATE_OK, FailureAlarm.STATE_ALARM, FailureAlarm.STATE_UNKNOWN
S = 1_000_000_000
#: Receive times start here (2023-11-14), so that the snapshot names carry a real date.
T0 = 1_700_000_000 * S


@pytest.fixture
def session(ros_domain: int) -> Iterator[RosSession]:
    with RosSession("test_blackbox", ros_domain) as s:
        yield s


def _recorder(out: Path, session: RosSession, before_s: float, after_s: float, max_bytes: int = 1 << 20) -> Recorder:
    tap = TopicTap(session, [], lambda *_: None)  # never polled: the test hands the messages over itself
    return Recorder(out, before_s, after_s, max_bytes, LiveChunks(), tap, InfoTracker(session, "fiper snapshot"))


def _embedding(step: int) -> bytes:
    (_, raw), _ = step_cdr(6, step, make_rollout(300, length=20))
    return raw


def test_a_snapshot_holds_rise_minus_before_to_rise_plus_after(tmp_path: Path, session: RosSession) -> None:
    """Alarms every second (the rise at 5 s), embeddings half a second after each; before 2 s, after 1 s."""
    recorder = _recorder(tmp_path, session, before_s=2.0, after_s=1.0)
    recorder.add(ALARM_TOPIC, ALARM_TYPE, T0, alarm_cdr(6, 0, OK))  # the first alarm only sets the state
    for t in range(1, 10):
        recorder.add(ALARM_TOPIC, ALARM_TYPE, T0 + t * S, alarm_cdr(6, t, ALARMED if t >= 5 else OK))
        if t == 5:  # the rise: its bag is open, and [3 s, 5 s] is on disk already (MCAP data, no metadata.yaml)
            (snapshot,) = recorder.open
            bag = snapshot.writer.path
            assert bag.name == "alarm_20231114T221325.000000_rollout6_step5"
            assert not (bag / "metadata.yaml").exists()
            salvage = Salvage(bag / f"{bag.name}.mcap")
            on_disk = [r.log_time for r in salvage.records() if hasattr(r, "log_time")]
            assert [(t - T0) / S for t in on_disk] == [3.0, 3.5, 4.0, 4.5, 5.0]
        recorder.tick(T0 + t * S)
        recorder.add(EMBEDDING_TOPIC, EMBEDDING_TYPE, T0 + t * S + S // 2, _embedding(t))
        recorder.tick(T0 + t * S + S // 2)
        if t == 5:
            assert recorder.open, "closed before rise + after"
    assert not recorder.open and recorder.written == 1
    with BagReader(bag) as reader:  # finished at 6 s: the bounds included, nothing after
        assert [(m.log_time_ns - T0) / S for m in reader.messages()] == [3.0, 3.5, 4.0, 4.5, 5.0, 5.5, 6.0]
        assert reader.info.source == "fiper snapshot: alarm rise of rollout 6 at step 5"


def _rises(box: BlackBox, alarms: list[tuple[int, int, int, bool, str]]) -> list[tuple[int, int]]:
    rises = []
    for index, (rollout_id, step, state, heartbeat, reason) in enumerate(alarms):
        rise = box.add(ALARM_TOPIC, ALARM_TYPE, T0 + index * S // 10, alarm_cdr(rollout_id, step, state,
                                                                                heartbeat=heartbeat,
                                                                         reason=reason))
        if rise is not None:
            rises.append((rise.rollout_id, rise.step))
    return rises


def test_one_rise_per_alarm_of_a_real_rollout() -> None:
    """The fusion node's stream around two alarmed rollouts: a rise each, none from the idle heartbeat (rollout
    0, latched or not) nor from the latched ALARM repeated after a rollout's END."""
    idle, latched_idle = (0, 0, UNKNOWN, True, "no active rollout"), (0, 0, ALARMED, True, "no active rollout")
    alarms = [
        idle, idle,                                                     # the first message sets the state
        (7, 0, OK, False, ""), (7, 1, OK, False, ""), (7, 2, ALARMED, False, "exceeded"),  # rise
        (7, 3, ALARMED, False, "latched since step 2"), (7, 3, ALARMED, True, "latched since step 2"),
        (7, 3, ALARMED, True, "latched since step 2"),                  # after END: the rollout's own heartbeat
        latched_idle, latched_idle,                                     # an idle heartbeat that says ALARM
        (8, 0, ALARMED, False, "exceeded"),                             # rise at step 0 of the next rollout
        (8, 0, UNKNOWN, True, "rnd_oe stream stale"), idle,
    ]
    assert _rises(BlackBox(before_s=10.0, max_bytes=1 << 20), alarms) == [(7, 2), (8, 0)]


def test_the_first_alarm_message_only_sets_the_state() -> None:
    """A black box started after a rollout latched: the replayed latched ALARM and its repetitions are no rise;
    the next rollout's is."""
    alarms = [(9, 4, ALARMED, True, "latched"), (9, 4, ALARMED, True, "latched"), (10, 0, OK, False, ""),
              (10, 1, ALARMED, False, "exceeded")]
    assert _rises(BlackBox(before_s=10.0, max_bytes=1 << 20), alarms) == [(10, 1)]


def test_the_alarm_states_of_the_last_rollouts_are_kept() -> None:
    box = BlackBox(before_s=10.0, max_bytes=1 << 20)
    _rises(box, [(r, 0, OK, False, "") for r in range(1, 3 * TRACKED_ROLLOUTS)])
    assert list(box.alarmed) == list(range(2 * TRACKED_ROLLOUTS, 3 * TRACKED_ROLLOUTS))


def test_the_ring_buffer_is_bounded_in_time_and_bytes() -> None:
    box = BlackBox(before_s=10.0, max_bytes=3000)
    for t in range(8):  # 1000 bytes a second: the byte bound, not the 10 s, keeps three
        box.add("/camera", "std_msgs/msg/String", T0 + t * S, bytes(1000))
    assert [(m[0] - T0) // S for m in box.buffer] == [5, 6, 7] and box.bytes == 3000
    rise = Rise(T0 + 7 * S, 1, 0)
    assert box.kept_s(rise) == 2.0  # the window was cut short, and by how much
    box.add("/camera", "std_msgs/msg/String", T0 + 8 * S, bytes(5000))  # larger than the bound: it alone stays
    assert [(m[0] - T0) // S for m in box.buffer] == [8]
    small = BlackBox(before_s=2.0, max_bytes=1 << 20)
    for t in range(8):
        small.add("/camera", "std_msgs/msg/String", T0 + t * S, bytes(1000))
    assert [(m[0] - T0) // S for m in small.buffer] == [5, 6, 7]  # from now - before on
    assert small.kept_s(Rise(T0 + 7 * S, 1, 0)) is None


def test_a_snapshot_says_when_its_before_window_was_cut_short(tmp_path: Path, session: RosSession,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    recorder = _recorder(tmp_path, session, before_s=10.0, after_s=0.0, max_bytes=3000)
    recorder.add(ALARM_TOPIC, ALARM_TYPE, T0, alarm_cdr(6, 0, OK))
    for t in range(1, 8):
        recorder.add("/camera", "std_msgs/msg/String", T0 + t * S, bytes(1000))
    recorder.add(ALARM_TOPIC, ALARM_TYPE, T0 + 8 * S, alarm_cdr(6, 1, ALARMED))
    recorder.tick(T0 + 8 * S)
    out = capsys.readouterr().out
    assert "only 2.0 s before the rise kept, not 10 s: the ring buffer reached --max-mb 0.00286102" in out, out


def test_at_most_so_many_snapshots_are_open_at_once(tmp_path: Path, session: RosSession,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    recorder = _recorder(tmp_path, session, before_s=1.0, after_s=5.0)
    recorder.add(ALARM_TOPIC, ALARM_TYPE, T0, alarm_cdr(1, 0, OK))
    for rollout_id in range(1, MAX_OPEN_SNAPSHOTS + 2):
        recorder.add(ALARM_TOPIC, ALARM_TYPE, T0 + rollout_id * S // 10, alarm_cdr(rollout_id, 3, ALARMED))
    assert len(recorder.open) == MAX_OPEN_SNAPSHOTS and recorder.skipped == 1
    assert (f"fiper snapshot: rise of rollout {MAX_OPEN_SNAPSHOTS + 1} at step 3 skipped: {MAX_OPEN_SNAPSHOTS} "
            "snapshots open (the most at once)") in capsys.readouterr().err
    recorder.close_all()
    assert len([b for b in tmp_path.iterdir() if (b / "metadata.yaml").is_file()]) == MAX_OPEN_SNAPSHOTS
