"""The recorder of ``fiper record -o BAG [TOPICS...]`` (:mod:`fiper_ros.commands.record`): the suite's topics into
a FIPER bag.

Subscribes to the given topics (default: every topic of the bag schema, as soon as it has a
publisher) with raw subscriptions and writes the CDR bytes as received, with each connection's
offered QoS and the receive time as log time, until Ctrl-C / SIGTERM or ``--duration``. The bag is live
(:class:`~fiper_ros.bagio.chunks.LiveChunks`): at its path from the start, a chunk on disk at least every
``--chunk-s`` seconds, ``metadata.yaml`` written when recording stops; a killed recorder leaves an
unfinished bag that ``fiper bag recover`` finishes. ``fiper record`` reports on ``/diagnostics`` (as
``/fiper_record``) how many publishers each of its subscriptions has matched, as the suite's nodes do, so a
policy can wait until the recorder receives its VOLATILE steps (:mod:`fiper_ros.publishing`,
``wait_for_suite(also=["/fiper_record"])``). :class:`Recorder` also serves ``fiper demo`` (one bag)
and ``fiper collect --ros`` (a bag per rollout), both staged (complete or not there).
"""
from __future__ import annotations

import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path

from fiper_ros.bagio.chunks import LiveChunks
from fiper_ros.bagio.errors import BagError
from fiper_ros.bagio.schema import BagInfo
from fiper_ros.bagio.writer import BagWriter
from fiper_ros.client.capture import InfoTracker, TopicTap, report_matches
from fiper_ros.client.ros_session import RosSession

#: The node of ``fiper record`` (in the root namespace; its SROS2 enclave, docs/security.md).
NODE_NAME = "fiper_record"
#: Seconds between two looks at the ROS graph for new topics.
GRAPH_POLL_S = 0.5


class Recorder:
    """Records wanted topics of a session into bags as they appear (``poll`` regularly).

    The subscriptions live as long as the recorder; bags come and go: :meth:`start` opens one,
    :meth:`finish` completes it (it appears under its name) or :meth:`abort` drops it. Messages that
    arrive while no bag is open are dropped, so one recorder writes a bag per rollout without
    missing the first messages of the next one (a new subscription would, during discovery).

    Args:
        session: The rclpy session whose node subscribes.
        topics: Topics to record; empty: the bag schema's topics.
        source: ``custom_data`` source of the bags.
    """

    def __init__(self, session: RosSession, topics: Sequence[str], source: str = "fiper record") -> None:
        self.tracker = InfoTracker(session, source)
        self.tap = TopicTap(session, topics, self._sink)
        self.writer: BagWriter | None = None
        self.counts: Counter[str] = Counter()
        """Messages per topic written into the open bag."""
        self._next_poll = 0.0

    def _sink(self, topic: str, msgtype: str, log_time_ns: int, raw: bytes) -> None:
        self.tracker.see(topic, msgtype, raw)
        if self.writer is None:
            return
        if not self.writer.has_topic(topic):
            self.writer.add_topic(topic, msgtype, self.tap.offered[topic])
        self.writer.write(topic, log_time_ns, raw)
        self.counts[topic] += 1

    @property
    def info(self) -> BagInfo:
        """``custom_data`` learned so far (shapes, task, calibration hash, source)."""
        return self.tracker.info

    def start(self, out: Path, overwrite: bool = False, live: LiveChunks | None = None) -> None:
        """Open a bag at ``out`` (``overwrite``: replace an existing one; ``live``: write it live, else staged)."""
        if self.writer is not None:
            raise BagError(f"{out}: the bag {self.writer.path} is still open")
        self.writer = BagWriter(out, overwrite=overwrite, live=live)
        self.counts = Counter()

    def poll(self) -> list[str]:
        """Hand a live bag's chunk to the disk when due (with the ``custom_data`` learned so far); subscribe
        to wanted topics that appeared (at most every :data:`GRAPH_POLL_S`); the new ones."""
        if self.writer is not None:
            self.writer.info = self.info
            self.writer.tick()
        if time.monotonic() < self._next_poll:
            return []
        self._next_poll = time.monotonic() + GRAPH_POLL_S
        return self.tap.poll()

    def missing(self) -> set[str]:
        """Wanted topics not subscribed yet (those of an unknown type are never subscribed)."""
        return self.tap.wanted - set(self.tap.types) - self.tap.skipped

    def finish(self, info: BagInfo | None = None) -> int:
        """Complete the open bag with ``info`` as ``custom_data`` (default :attr:`info`); it appears under its
        name. Returns the number of messages written."""
        writer = self._take()
        writer.info = self.info if info is None else info
        writer.close()
        return writer.count

    def abort(self) -> None:
        """Drop the open bag, if any."""
        if self.writer is not None:
            self._take().abort()

    def _take(self) -> BagWriter:
        if self.writer is None:
            raise BagError("no bag is open")
        writer, self.writer = self.writer, None
        return writer


def record(out: Path, topics: list[str], duration: float | None, domain: int | None, overwrite: bool,
           live: LiveChunks) -> int:
    """Record until stopped; returns the number of messages written. An error stops the recording and leaves
    the bag unfinished (with everything received)."""
    with RosSession(NODE_NAME, domain) as session:
        recorder = Recorder(session, topics)
        recorder.start(out, overwrite, live)
        report_matches(session.node, recorder.tap.matched_publishers)
        print(f"recording {', '.join(sorted(recorder.tap.wanted))} in ROS domain {session.domain} to {out} "
              f"({'Ctrl-C to stop' if duration is None else f'{duration:g} s'})", flush=True)
        try:
            started = time.monotonic()
            while not session.stop.is_set() and (duration is None or time.monotonic() - started < duration):
                for topic in recorder.poll():
                    print(f"  subscribed to {topic} ({recorder.tap.types[topic]})", flush=True)
                session.spin_once(0.05)
        except BaseException:
            recorder.abort()
            raise
        return recorder.finish()

