"""The black box of ``fiper snapshot [-o DIR]`` (:mod:`fiper_ros.commands.snapshot`).

Keeps the raw messages of the suite's topics of the last ``--before`` seconds in a ring buffer, bounded in
bytes too (``--max-mb``: the oldest messages go first). At every alarm rise it opens a live bag
``DIR/alarm_<UTC time>_rollout<id>_step<step>/`` (:class:`~fiper_ros.bagio.chunks.LiveChunks`), writes the
buffered ``[rise - before, rise]`` into it and hands it to the disk at once, then adds every message up to
``rise + after`` as it arrives (a chunk on disk at least every ``--chunk-s``) and finishes the bag
(``metadata.yaml``) at ``rise + after``. A crash of the suite loses nothing of it; a crash of the black box
itself leaves an unfinished bag that ``fiper bag recover`` finishes, holding all but the last chunk.

An alarm rise is a FailureAlarm in state ALARM for a rollout whose previous state was not ALARM, one bag
per rise. The idle heartbeat (``rollout_id`` 0, "no active rollout") names no rollout and is never a rise;
after a latched rollout's END the fusion node's heartbeat repeats that rollout's ALARM, which is its state
already, not a new rise. The first alarm message received only sets the initial state of its rollout: it
is usually the latched state replayed to a late subscriber (TRANSIENT_LOCAL), not a new rise. The alarm
states of the last :data:`TRACKED_ROLLOUTS` rollouts are kept, and at most :data:`MAX_OPEN_SNAPSHOTS` bags
are open at once (a rise beyond that is skipped, and said).
"""
from __future__ import annotations

import collections
import sys
import time
from dataclasses import dataclass, replace
from datetime import datetime, timezone
from pathlib import Path

from fiper_msgs.msg import FailureAlarm
from fiper_ros.bagio.chunks import LiveChunks
from fiper_ros.bagio.schema import typestore
from fiper_ros.bagio.writer import BagWriter
from fiper_ros.client.capture import InfoTracker, TopicTap
from fiper_ros.client.ros_session import RosSession
from fiper_ros.interface.messages import NO_ROLLOUT
from fiper_ros.interface.topics import ALARM_TOPIC

GRAPH_POLL_S = 0.5
#: The node of ``fiper snapshot`` (in the root namespace; its SROS2 enclave, docs/security.md).
NODE_NAME = "fiper_snapshot"
#: Rollouts whose alarm state the black box keeps (the most recent ones).
TRACKED_ROLLOUTS = 64
#: Snapshot bags open at once (rises of several rollouts within one ``--after``).
MAX_OPEN_SNAPSHOTS = 8
#: Default of ``--max-mb``, the ring buffer's bound in bytes (10 s of the PushChair stream, B = 256, take 12 MB).
DEFAULT_MAX_MB = 256.0
#: Default of ``-o``.
DEFAULT_OUT = Path("runs/snapshots")

#: (receive time in ns, topic, message type, CDR bytes)
Captured = tuple[int, str, str, bytes]


@dataclass(frozen=True)
class Rise:
    """One alarm rise."""

    time_ns: int
    rollout_id: int
    step: int


class BlackBox:
    """Ring buffer of captured messages (the last ``before_s`` seconds, at most ``max_bytes`` of CDR data; the
    newest message always stays) and the alarm state of the last ``tracked`` rollouts."""

    def __init__(self, before_s: float, max_bytes: int, tracked: int = TRACKED_ROLLOUTS) -> None:
        self.before_ns = int(before_s * 1e9)
        self.max_bytes = max_bytes
        self.tracked = tracked
        self.buffer: collections.deque[Captured] = collections.deque()
        self.bytes = 0
        """CDR bytes in :attr:`buffer`."""
        self.evicted_ns: int | None = None
        """Receive time of the newest message the byte bound pushed out."""
        self.alarmed: collections.OrderedDict[int, bool] = collections.OrderedDict()
        """Rollout id -> whether its last alarm message said ALARM, least recent first."""
        self._initialised = False

    def add(self, topic: str, msgtype: str, time_ns: int, raw: bytes) -> Rise | None:
        """Buffer one message; the rise it is, if it is an alarm message that rises."""
        self.buffer.append((time_ns, topic, msgtype, raw))
        self.bytes += len(raw)
        rise = self._on_alarm(typestore().deserialize_cdr(raw, msgtype), time_ns) if topic == ALARM_TOPIC else None
        while self.buffer and self.buffer[0][0] < time_ns - self.before_ns:
            self.bytes -= len(self.buffer.popleft()[3])
        while self.bytes > self.max_bytes and len(self.buffer) > 1:
            evicted = self.buffer.popleft()
            self.bytes -= len(evicted[3])
            self.evicted_ns = evicted[0]
        return rise

    def _on_alarm(self, msg: object, time_ns: int) -> Rise | None:
        rollout_id = int(msg.rollout_id)  # type: ignore[attr-defined]
        first, self._initialised = not self._initialised, True
        if rollout_id == NO_ROLLOUT:
            return None
        alarm = int(msg.state) == FailureAlarm.STATE_ALARM  # type: ignore[attr-defined]
        was = self.alarmed.pop(rollout_id, False)
        self.alarmed[rollout_id] = alarm
        if len(self.alarmed) > self.tracked:
            self.alarmed.popitem(last=False)
        if alarm and not was and not first:
            return Rise(time_ns, rollout_id, int(msg.step))  # type: ignore[attr-defined]
        return None

    def before(self, rise: Rise) -> list[Captured]:
        """The buffered messages from ``rise - before`` on."""
        return [m for m in self.buffer if m[0] >= rise.time_ns - self.before_ns]

    def kept_s(self, rise: Rise) -> float | None:
        """Seconds before ``rise`` the buffer still holds if the byte bound cut the ``before`` window short,
        else None."""
        if self.evicted_ns is None or self.evicted_ns < rise.time_ns - self.before_ns:
            return None
        return (rise.time_ns - self.buffer[0][0]) / 1e9


class Snapshot:
    """The live bag of one rise, open until ``rise + after``."""

    def __init__(self, out: Path, rise: Rise, after_s: float, live: LiveChunks, tap: TopicTap,
                 tracker: InfoTracker) -> None:
        stamp = datetime.fromtimestamp(rise.time_ns / 1e9, tz=timezone.utc).strftime("%Y%m%dT%H%M%S.%f")
        self.rise = rise
        self.end_ns = rise.time_ns + int(after_s * 1e9)
        self._tap, self._tracker = tap, tracker
        self.writer = BagWriter(out / f"alarm_{stamp}_rollout{rise.rollout_id}_step{rise.step}", live=live)
        self._update_info()

    def _update_info(self) -> None:
        self.writer.info = replace(self._tracker.info, source=f"fiper snapshot: alarm rise of rollout "
                                                                f"{self.rise.rollout_id} at step {self.rise.step}")

    def write(self, message: Captured) -> None:
        """Add one captured message."""
        time_ns, topic, msgtype, raw = message
        if not self.writer.has_topic(topic):
            self.writer.add_topic(topic, msgtype, self._tap.offered.get(topic, []))
        self.writer.write(topic, time_ns, raw)

    def tick(self) -> None:
        """Hand the open chunk to the disk when due."""
        self._update_info()
        self.writer.tick()

    def close(self) -> Path:
        """Finish the bag."""
        self._update_info()
        return self.writer.close()


class Recorder:
    """The black box at work: the buffer, the open snapshots and what it says."""

    def __init__(self, out: Path, before_s: float, after_s: float, max_bytes: int, live: LiveChunks,
                 tap: TopicTap, tracker: InfoTracker) -> None:
        self.box = BlackBox(before_s, max_bytes)
        self.out, self.after_s, self.live, self.tap, self.tracker = out, after_s, live, tap, tracker
        self.max_mb = max_bytes / 2**20
        self.open: list[Snapshot] = []
        self.written = 0
        self.skipped = 0

    def add(self, topic: str, msgtype: str, time_ns: int, raw: bytes) -> None:
        """One captured message: into the buffer and every open snapshot; a rise opens one."""
        self.tracker.see(topic, msgtype, raw)
        rise = self.box.add(topic, msgtype, time_ns, raw)
        for snapshot in self.open:
            if time_ns <= snapshot.end_ns:
                snapshot.write((time_ns, topic, msgtype, raw))
        if rise is not None:
            self._open(rise)

    def _open(self, rise: Rise) -> None:
        if len(self.open) >= MAX_OPEN_SNAPSHOTS:
            self.skipped += 1
            print(f"fiper snapshot: rise of rollout {rise.rollout_id} at step {rise.step} skipped: "
                  f"{MAX_OPEN_SNAPSHOTS} snapshots open (the most at once)", file=sys.stderr, flush=True)
            return
        snapshot = Snapshot(self.out, rise, self.after_s, self.live, self.tap, self.tracker)
        for message in self.box.before(rise):
            snapshot.write(message)
        snapshot.writer.flush()
        self.open.append(snapshot)
        kept = self.box.kept_s(rise)
        short = "" if kept is None else (f"; only {kept:.1f} s before the rise kept, not {self.box.before_ns / 1e9:g} "
                                         f"s: the ring buffer reached --max-mb {self.max_mb:g}")
        print(f"snapshot {snapshot.writer.path} opened (rollout {rise.rollout_id} rose at step {rise.step}){short}",
              flush=True)

    def tick(self, now_ns: int) -> None:
        """Chunks to disk when due; snapshots whose ``after`` window has passed are finished."""
        for snapshot in list(self.open):
            if now_ns >= snapshot.end_ns:
                self._close(snapshot, "")
            else:
                snapshot.tick()

    def close_all(self) -> None:
        """Stopping: finish every open snapshot with what there is."""
        for snapshot in list(self.open):
            self._close(snapshot, " (cut short)")

    def _close(self, snapshot: Snapshot, note: str) -> None:
        self.open.remove(snapshot)
        print(f"snapshot {snapshot.close()} written{note}", flush=True)
        self.written += 1


def black_box(session: RosSession, out: Path, topics: list[str], before_s: float, after_s: float, max_bytes: int,
              live: LiveChunks) -> Recorder:
    """The black box of ``session``: it watches ``topics`` (empty: the bag schema's) and always the alarm."""
    tracker = InfoTracker(session, "fiper snapshot")
    recorder: Recorder | None = None

    def sink(topic: str, msgtype: str, time_ns: int, raw: bytes) -> None:
        assert recorder is not None
        recorder.add(topic, msgtype, time_ns, raw)

    tap = TopicTap(session, [*topics, ALARM_TOPIC] if topics else [], sink)
    recorder = Recorder(out, before_s, after_s, max_bytes, live, tap, tracker)
    return recorder


def snapshot(out: Path, topics: list[str], before_s: float, after_s: float, max_bytes: int, live: LiveChunks,
             duration: float | None, domain: int | None) -> Recorder:
    """Run the black box until stopped; returns it (snapshots written, rises skipped)."""
    out.mkdir(parents=True, exist_ok=True)
    with RosSession(NODE_NAME, domain) as session:
        recorder = black_box(session, out, topics, before_s, after_s, max_bytes, live)
        tap = recorder.tap
        print(f"black box on {', '.join(sorted(tap.wanted))} in ROS domain {session.domain}: {before_s:g} s "
              f"(at most {max_bytes / 2**20:g} MB) before and {after_s:g} s after every alarm rise into {out}",
              flush=True)
        started = next_poll = time.monotonic()
        try:
            while not session.stop.is_set() and (duration is None or time.monotonic() - started < duration):
                if time.monotonic() >= next_poll:
                    tap.poll()
                    next_poll = time.monotonic() + GRAPH_POLL_S
                session.spin_once(0.05)
                recorder.tick(tap.now_ns())
        except BaseException:
            for open_snapshot in recorder.open:
                open_snapshot.writer.abort()  # what is on disk stays, unfinished
            raise
        recorder.close_all()
    return recorder
