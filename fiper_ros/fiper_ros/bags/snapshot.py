"""``fiper snapshot -o DIR``: a black box for the suite.

Keeps the raw messages of the suite's topics of the last ``--before`` seconds in a ring buffer and,
``--after`` seconds after every alarm rise, writes a bag holding ``[rise - before, rise + after]``
into DIR (``alarm_<UTC time>_rollout<id>_step<step>/``, complete or not there at all).

An alarm rise is a FailureAlarm in state ALARM for a rollout whose previous state was not ALARM. The
first alarm message received only sets the initial state: it is usually the latched state replayed
to a late subscriber (TRANSIENT_LOCAL), not a new rise.
"""
from __future__ import annotations

import argparse
import collections
import time
from dataclasses import dataclass, replace
from datetime import datetime, timezone
from pathlib import Path

from fiper_msgs.msg import FailureAlarm
from fiper_ros.bags.capture import InfoTracker, TopicTap
from fiper_ros.bags.errors import BagError, fail
from fiper_ros.bags.schema import ALARM, typestore
from fiper_ros.bags.session import RosSession
from fiper_ros.bags.writer import BagWriter

GRAPH_POLL_S = 0.5


@dataclass(frozen=True)
class Rise:
    """One alarm rise."""

    time_ns: int
    rollout_id: int
    step: int


class BlackBox:
    """Ring buffer of captured messages and the snapshots it owes."""

    def __init__(self, before_s: float, after_s: float) -> None:
        self.before_ns = int(before_s * 1e9)
        self.after_ns = int(after_s * 1e9)
        self.buffer: collections.deque[tuple[int, str, str, bytes]] = collections.deque()
        self.pending: list[Rise] = []
        self._alarmed: dict[int, bool] = {}
        self._initialised = False

    def add(self, topic: str, msgtype: str, time_ns: int, raw: bytes) -> None:
        """Buffer one message; an alarm message may start a snapshot."""
        self.buffer.append((time_ns, topic, msgtype, raw))
        if topic == ALARM:
            self._on_alarm(typestore().deserialize_cdr(raw, msgtype), time_ns)
        oldest_needed = min([time_ns - self.before_ns] + [r.time_ns - self.before_ns for r in self.pending])
        while self.buffer and self.buffer[0][0] < oldest_needed:
            self.buffer.popleft()

    def _on_alarm(self, msg: object, time_ns: int) -> None:
        rollout_id, alarm = int(msg.rollout_id), int(msg.state) == FailureAlarm.STATE_ALARM  # type: ignore[attr-defined]
        was = self._alarmed.get(rollout_id, False)
        self._alarmed[rollout_id] = alarm
        if alarm and not was and self._initialised:
            self.pending.append(Rise(time_ns, rollout_id, int(msg.step)))  # type: ignore[attr-defined]
        self._initialised = True

    def due(self, now_ns: int, flush: bool = False) -> list[Rise]:
        """Rises whose ``after`` window has passed (all of them with ``flush``); removed from pending."""
        ready = [r for r in self.pending if flush or now_ns >= r.time_ns + self.after_ns]
        self.pending = [r for r in self.pending if r not in ready]
        return ready

    def window(self, rise: Rise) -> list[tuple[int, str, str, bytes]]:
        """Buffered messages within ``[rise - before, rise + after]``."""
        low, high = rise.time_ns - self.before_ns, rise.time_ns + self.after_ns
        return [m for m in self.buffer if low <= m[0] <= high]


def write_snapshot(out: Path, rise: Rise, box: BlackBox, tap: TopicTap, tracker: InfoTracker) -> Path:
    """Write the bag of one rise."""
    stamp = datetime.fromtimestamp(rise.time_ns / 1e9, tz=timezone.utc).strftime("%Y%m%dT%H%M%S.%f")
    path = out / f"alarm_{stamp}_rollout{rise.rollout_id}_step{rise.step}"
    with BagWriter(path) as writer:
        writer.info = replace(tracker.info, source=f"fiper snapshot: alarm rise of rollout {rise.rollout_id} "
                                                   f"at step {rise.step}")
        for time_ns, topic, msgtype, raw in box.window(rise):
            if not writer.has_topic(topic):
                writer.add_topic(topic, msgtype, tap.offered.get(topic, []))
            writer.write(topic, time_ns, raw)
    return path


def snapshot(out: Path, topics: list[str], before_s: float, after_s: float, duration: float | None,
             domain: int | None) -> int:
    """Run the black box until stopped; returns the number of snapshots written."""
    out.mkdir(parents=True, exist_ok=True)
    box = BlackBox(before_s, after_s)
    written = 0
    with RosSession("fiper_snapshot", domain) as session:
        tracker = InfoTracker(session, "fiper snapshot")

        def sink(topic: str, msgtype: str, time_ns: int, raw: bytes) -> None:
            box.add(topic, msgtype, time_ns, raw)
            tracker.see(topic, msgtype, raw)

        tap = TopicTap(session, [*topics, ALARM] if topics else [], sink)  # the alarm is always watched
        print(f"black box on {', '.join(sorted(tap.wanted))} in ROS domain {session.domain}: "
              f"{before_s:g} s before and {after_s:g} s after every alarm rise into {out}", flush=True)
        started = next_poll = time.monotonic()
        while not session.stop.is_set() and (duration is None or time.monotonic() - started < duration):
            if time.monotonic() >= next_poll:
                tap.poll()
                next_poll = time.monotonic() + GRAPH_POLL_S
            session.spin_once(0.05)
            for rise in box.due(tap.now_ns()):
                print(f"snapshot {write_snapshot(out, rise, box, tap, tracker)}", flush=True)
                written += 1
        for rise in box.due(tap.now_ns(), flush=True):  # stopping: write what there is
            print(f"snapshot {write_snapshot(out, rise, box, tap, tracker)} (cut short)", flush=True)
            written += 1
    return written


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``fiper snapshot``."""
    parser.add_argument("topics", nargs="*", help="topics to keep (default: the bag schema's topics)")
    parser.add_argument("-o", "--out", type=Path, required=True, help="directory for the snapshot bags")
    parser.add_argument("--before", type=float, default=10.0, help="seconds kept before an alarm rise")
    parser.add_argument("--after", type=float, default=5.0, help="seconds recorded after an alarm rise")
    parser.add_argument("--duration", type=float, help="stop after this many seconds")
    parser.add_argument("--domain", type=int, help="ROS domain (default: ROS_DOMAIN_ID)")


def run(args: argparse.Namespace) -> int:
    """``fiper snapshot``."""
    if args.before < 0 or args.after < 0:
        return fail("snapshot", "--before and --after must be >= 0")
    try:
        count = snapshot(args.out, args.topics, args.before, args.after, args.duration, args.domain)
    except BagError as error:
        return fail("snapshot", error)
    print(f"{count} snapshot(s) written to {args.out}")
    return 0
