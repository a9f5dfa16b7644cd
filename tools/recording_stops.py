"""What a ``fiper record`` recording keeps when the recorder stops: Ctrl-C, SIGTERM or SIGKILL (docs/bags.md,
"What survives which stop"), and what a chunk costs to hand to the disk (the bound of a power cut).

    . ./env.sh && python tools/recording_stops.py [--kills 5] [--steps-per-s 25] [--seconds 8]

Each run starts ``fiper record -o <tmp>/runN`` (default ``--chunk-s 1``) as its own process in a private ROS
domain on loopback, publishes a synthetic rollout from this process (an embedding and an action batch per
step, fixed CDR bytes), stops the recorder, recovers the bag if it is unfinished, and counts what the bag
holds of what was published: a contiguous prefix, and how long before the stop the first lost message went
out. Then it writes the same stream into a live bag in this process and times each chunk's flush (zstd,
write, fsync).
"""
from __future__ import annotations

import argparse
import os
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rclpy.serialization import serialize_message

from fiper_msgs.msg import ActionChunkBatch, ObservationEmbedding
from fiper_ros.bagio.chunks import LiveChunks
from fiper_ros.bagio.reader import BagReader
from fiper_ros.bagio.recover import recover_in_place, unfinished
from fiper_ros.bagio.schema import normalize_cdr
from fiper_ros.bagio.storage import Salvage
from fiper_ros.bagio.writer import BagWriter
from fiper_ros.client.ros_session import RosSession
from fiper_ros.interface import qos
from fiper_ros.interface.conversions import action_batch_msg, embedding_msg
from fiper_ros.interface.topics import ACTIONS_TOPIC, EMBEDDING_TOPIC, TOPICS
from fiper_ros.platform.dds import allocate_domain, local_env

#: The shapes of the shipped Sorting policy's messages: E = 128 (embedding), B = 32, H = 16, D = 3.
E, B, H, D = 128, 32, 16, 3


def step_cdr(rollout_id: int, step: int, rng: np.random.Generator) -> list[tuple[str, bytes]]:
    """An embedding and an action batch of one step, as DDS carries them (padded to 4 bytes)."""
    stamp = (step + 1) * 100_000_000
    messages = [(EMBEDDING_TOPIC, embedding_msg(rollout_id, step, stamp, rng.normal(size=E).astype(np.float32))),
                (ACTIONS_TOPIC, action_batch_msg(rollout_id, step, stamp, rng.normal(size=(B, H, D)).astype(np.float32),
                                                 8,
                                           "ee_position"))]
    out = []
    for topic, msg in messages:
        raw = normalize_cdr(serialize_message(msg), TOPICS[topic].msgtype)
        out.append((topic, raw + bytes(-len(raw) % 4)))
    return out


class Publisher:
    """The policy side, in this process's :class:`~fiper_ros.client.ros_session.RosSession`."""

    def __init__(self, session: RosSession) -> None:
        self.session = session
        node = session.node
        self.publishers = {EMBEDDING_TOPIC: node.create_publisher(ObservationEmbedding, EMBEDDING_TOPIC, qos.INPUT),
                           ACTIONS_TOPIC: node.create_publisher(ActionChunkBatch, ACTIONS_TOPIC, qos.INPUT)}

    def spin(self, seconds: float) -> None:
        self.session.spin_until(lambda: False, seconds)

    def publish_step(self, rollout_id: int, step: int, rng: np.random.Generator) -> list[tuple[bytes, int]]:
        sent = []
        for topic, raw in step_cdr(rollout_id, step, rng):
            sent.append((raw, time.time_ns()))
            self.publishers[topic].publish(raw)
        return sent


def on_disk(bag: Path) -> bool:
    """Whether the recorder wrote a chunk with an embedding (it is matched)."""
    files = list(bag.glob("*.mcap")) if bag.is_dir() else []
    return bool(files) and any(getattr(r, "channel_id", None) is not None for r in Salvage(files[0]).records())


def one_run(kind: str, domain: int, publisher: Publisher, bag: Path, steps_per_s: float, seconds: float) -> str:
    env = local_env(domain)
    recorder = subprocess.Popen([sys.executable, "-m", "fiper_ros.cli", "record", "-o", str(bag), EMBEDDING_TOPIC,
                                 ACTIONS_TOPIC],
                                env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    rng = np.random.default_rng(0)
    try:
        for step in range(600):  # warm-up until the recorder is matched and writing
            publisher.publish_step(1, step, rng)
            publisher.spin(0.1)
            if step % 5 == 4 and on_disk(bag):
                break
        else:
            raise RuntimeError("the recorder wrote nothing within 60 s")
        sent: list[tuple[bytes, int]] = []
        for step in range(int(seconds * steps_per_s)):
            sent.extend(publisher.publish_step(2, step, rng))
            publisher.spin(1.0 / steps_per_s)
        stopped_ns = time.time_ns()
        os.killpg(recorder.pid, {"SIGINT": signal.SIGINT, "SIGTERM": signal.SIGTERM, "SIGKILL": signal.SIGKILL}[kind])
        recorder.wait(timeout=60)
        exit_s = (time.time_ns() - stopped_ns) / 1e9
    finally:
        if recorder.poll() is None:
            recorder.kill()
    was_unfinished = unfinished(bag) is not None
    if was_unfinished:
        recover_in_place(bag)
    with BagReader(bag) as reader:
        held_raw = {m.raw for m in reader.messages()}
    lost_at = [t for raw, t in sent if raw not in held_raw]
    held, lost = len(sent) - len(lost_at), len(lost_at)
    first_lost = f", the first lost sent {(stopped_ns - min(lost_at)) / 1e9:.2f} s before the stop" if lost else ""
    return (f"{kind:8s} exit after {exit_s:.2f} s, {'unfinished -> recovered' if was_unfinished else 'finished'}: "
            f"kept {held} of {len(sent)} messages, lost {lost}{first_lost}")


def flush_costs(directory: Path, steps_per_s: float, seconds: float) -> str:
    """Write the stream into a live bag (chunk = one second of messages) and time each flush."""
    rng = np.random.default_rng(0)
    writer = BagWriter(directory / "flushes", live=LiveChunks())
    costs, size = [], 0
    for second in range(int(seconds)):
        for step in range(int(steps_per_s)):
            for topic, raw in step_cdr(3, second * int(steps_per_s) + step, rng):
                writer.write(topic, time.time_ns(), raw)
                size += len(raw)
        started = time.perf_counter()
        writer.flush()
        costs.append(time.perf_counter() - started)
    writer.close()
    return (f"flush of a 1 s chunk ({size / seconds / 1e3:.0f} kB of messages): median "
            f"{statistics.median(costs) * 1e3:.1f} ms, max {max(costs) * 1e3:.1f} ms over {len(costs)} chunks")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kills", type=int, default=5, help="SIGKILL runs")
    parser.add_argument("--steps-per-s", type=float, default=25.0, help="policy steps a second (2 messages each)")
    parser.add_argument("--seconds", type=float, default=8.0, help="seconds of stream per run")
    args = parser.parse_args()
    with (tempfile.TemporaryDirectory(prefix="recording-stops-") as tmp, allocate_domain() as domain,
          RosSession("recording_stops", domain) as session):
        publisher = Publisher(session)
        for index, kind in enumerate(["SIGINT", "SIGTERM", *["SIGKILL"] * args.kills]):
            print(one_run(kind, domain, publisher, Path(tmp) / f"run{index}", args.steps_per_s, args.seconds),
                  flush=True)
        print(flush_costs(Path(tmp), args.steps_per_s, args.seconds))
    return 0


if __name__ == "__main__":
    sys.exit(main())
