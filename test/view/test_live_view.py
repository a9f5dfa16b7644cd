"""``fiper view`` beside a running suite over loopback (issue #22): a Foxglove WebSocket client (``websockets``,
the protocol by hand) gets every score and alarm the suite published, the same values in the same order, while
another client never reads (it loses camera frames, nobody else does) and a third one disconnects mid-stream;
the server serves on and a new client is advertised every channel. The suite is fed by a recorded bag
(``fiper replay`` of a sample set, as test/bags/test_replay.py runs it).

Ground truth is a DDS subscriber of this test in the same domain: what the suite published, as DDS delivered
it. This test also publishes the wrist camera (96x96 rgb8, as the sim bridge does, at 50 Hz), so that the
client that never reads has far more coming than any buffer holds."""
from __future__ import annotations

import asyncio
import json
import math
import os
import queue
import re
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import rclpy
from helpers.dds import ros_env, spawn_python, stop
from helpers.diagnostics import DiagnosticsListener
from helpers.foxglove_client import Client, open_client
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from sensor_msgs.msg import Image

from fiper_msgs.msg import FailureAlarm, Score
from fiper_ros.core.detectors import CALIBRATED
from fiper_ros.interface import qos
from fiper_ros.interface.messages import AlarmStateName
from fiper_ros.interface.topics import (ALARM_TOPIC, CAMERA_TOPICS, CAMERA_WRIST_TOPIC, DIAGNOSTICS_TOPIC, EVENTS_TOPIC,
                                        SCORE_ACE_TOPIC, SCORE_RND_OE_TOPIC, score_topic)

ROOT = Path(os.environ["FIPER_ROOT"])
BAGS = ROOT / "bags" / "pushchair_synthetic" / "test_rollouts"  # 10 rollouts; calibration/ next to them
SCORES = (SCORE_RND_OE_TOPIC, SCORE_ACE_TOPIC)
#: Every detector's scores are served by default (a suite of any detector set is seen), not only FIPER's pair's.
SERVED = {*(score_topic(d) for d in CALIBRATED), ALARM_TOPIC, EVENTS_TOPIC, DIAGNOSTICS_TOPIC, *CAMERA_TOPICS}
IMAGE_HZ = 50.0
#: The view's queue per client in this test (messages).
BACKLOG = 64
SERVING = re.compile(r"serving ws://127\.0\.0\.1:(\d+) ")


def _number(value: float) -> float | None:
    return value if math.isfinite(value) else None


def score_of(msg: Score) -> tuple[Any, ...]:
    return msg.rollout_id, msg.step, _number(msg.windowed_score), _number(msg.threshold), msg.exceeded


def score_in(sent: dict[str, Any]) -> tuple[Any, ...]:
    return sent["rollout_id"], sent["step"], sent["windowed_score"], sent["threshold"], sent["exceeded"]


ALARM_FIELDS = ("rollout_id", "step", "state", "latched", "eta_obs", "gamma_obs", "eta_act", "gamma_act", "heartbeat",
                "reason")


def alarm_of(msg: FailureAlarm) -> tuple[Any, ...]:
    return tuple(_number(v) if isinstance(v, float) else v for v in (getattr(msg, f) for f in ALARM_FIELDS))


class Tap:
    """What the suite publishes, as a DDS subscriber of this test receives it; and the wrist camera, published
    here while ``images`` is set."""

    def __init__(self, domain: int) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = Node("test_view_tap", context=self.context)
        self.scores: dict[str, list[tuple[Any, ...]]] = {topic: [] for topic in SCORES}
        self.alarms: list[tuple[Any, ...]] = []
        for topic in SCORES:
            self.node.create_subscription(Score, topic, lambda m, t=topic: self.scores[t].append(score_of(m)),
                                          qos.SCORE_SUB)
        self.node.create_subscription(FailureAlarm, ALARM_TOPIC, lambda m: self.alarms.append(alarm_of(m)),
                                      qos.ALARM_EVERY)
        self.images = threading.Event()
        self.published_images = 0
        self._camera = self.node.create_publisher(Image, CAMERA_WRIST_TOPIC, qos.INPUT)
        self.node.create_timer(1.0 / IMAGE_HZ, self._publish_image)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self.executor.spin, daemon=True)
        self._thread.start()

    def _publish_image(self) -> None:
        if self.images.is_set():
            image = Image(height=96, width=96, encoding="rgb8", step=96 * 3, data=bytes(96 * 96 * 3))
            image.header.frame_id = str(self.published_images)
            self._camera.publish(image)
            self.published_images += 1

    def close(self) -> None:
        self.executor.shutdown()
        self._thread.join(timeout=10)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def tap(ros_domain: int) -> Iterator[Tap]:
    made = Tap(ros_domain)
    try:
        yield made
    finally:
        made.close()


def start_view(domain: int) -> tuple[subprocess.Popen[str], int, queue.Queue[str]]:
    """``fiper view --port 0`` in ``domain``; the process, its port (from its log) and its output lines."""
    view = spawn_python(["-m", "fiper_ros.cli", "view", "--port", "0", "--backlog", str(BACKLOG)], domain)
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: [lines.put(line) for line in view.stdout], daemon=True).start()  # type: ignore
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=1)
        except queue.Empty:
            assert view.poll() is None, "fiper view exited"
            continue
        if match := SERVING.search(line):
            return view, int(match.group(1)), lines
    raise AssertionError("fiper view did not say where it serves")


def view_status(client: Client) -> dict[str, str]:
    """The view node's latest diagnostics values, as the view itself sent them to ``client``."""
    for array in reversed(client.received.get(DIAGNOSTICS_TOPIC, [])):
        for status in array["status"]:
            if status["name"] == "fiper: /fiper/view_node":
                return {kv["key"]: kv["value"] for kv in status["values"]}
    return {}


async def drain(client: Client, topic: str, quiet_s: float, timeout: float = 300.0) -> None:
    """Read ``client`` until no message of ``topic`` came for ``quiet_s`` seconds (others go on: the diagnostics)."""
    async with asyncio.timeout(timeout):
        count, since = len(client.received[topic]), time.monotonic()
        while time.monotonic() - since < quiet_s:
            try:
                await asyncio.wait_for(client.read_one(), quiet_s)
            except TimeoutError:
                return
            if len(client.received[topic]) > count:
                count, since = len(client.received[topic]), time.monotonic()


async def scenario(port: int, tap: Tap, domain: int, out: Path) -> dict[str, Any]:
    reader = await open_client(port)
    await reader.read_advertised(SERVED)
    await reader.subscribe([*SCORES, ALARM_TOPIC, DIAGNOSTICS_TOPIC, CAMERA_WRIST_TOPIC])
    stalled = await open_client(port, receive_buffer=16384, max_queue=1)  # never reads once subscribed
    await stalled.read_advertised(SERVED)
    await stalled.subscribe(sorted(SERVED))
    leaving = await open_client(port)
    await leaving.read_advertised(SERVED)
    await leaving.subscribe([*SCORES, ALARM_TOPIC])
    subscriptions = 5 + len(SERVED) + 3
    await reader.read_until(lambda: view_status(reader).get("subscriptions") == str(subscriptions), 60)
    assert view_status(reader)["clients"] == "3"

    async def leave_mid_stream() -> int:
        await leaving.read_until(lambda: sum(map(len, leaving.received.values())) >= 10, 600)
        leaving.ws.transport.abort()  # gone without a closing handshake
        return sum(map(len, leaving.received.values()))

    tap.images.set()
    log = (out / "replay.log").open("w")
    replay = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "fiper_ros.cli", "replay", str(BAGS), "--fast", "--step-timeout", "30", "--domain",
        str(domain), "--report", str(out / "report.json"), env=ros_env(domain), stdout=log, stderr=subprocess.STDOUT)
    done = asyncio.Event()

    def caught_up() -> bool:
        return done.is_set() and len(reader.received[ALARM_TOPIC]) >= len(tap.alarms) and all(
            len(reader.received[t]) >= len(tap.scores[t]) for t in SCORES)

    reading = asyncio.create_task(reader.read_until(caught_up, 900))
    left = await leave_mid_stream()
    await asyncio.wait_for(replay.wait(), 600)
    log.close()
    tap.images.clear()
    assert replay.returncode == 0, (out / "replay.log").read_text()[-3000:]
    done.set()
    await reading
    await drain(stalled, CAMERA_WRIST_TOPIC, quiet_s=3.0)
    stalled_images = len(stalled.received[CAMERA_WRIST_TOPIC])
    diagnostics = len(stalled.received[DIAGNOSTICS_TOPIC])
    await stalled.read_until(lambda: len(stalled.received[DIAGNOSTICS_TOPIC]) > diagnostics, 30)  # still served
    late = await open_client(port)
    await late.read_advertised(SERVED)
    channels = late.channels
    for client in (reader, stalled, late):
        await client.ws.close()
    return {"reader": reader, "left": left, "stalled_images": stalled_images, "channels": channels}


@pytest.mark.slow
def test_a_foxglove_client_gets_what_the_suite_published_beside_a_stalled_and_a_vanished_client(
        ros_domain: int, tap: Tap, tmp_path: Path) -> None:
    view, port, _ = start_view(ros_domain)
    try:
        outcome = asyncio.run(scenario(port, tap, ros_domain, tmp_path))
        assert view.poll() is None
    finally:
        output = stop(view)
    assert view.returncode == 0, output[-3000:]
    reader: Client = outcome["reader"]
    # every score and every alarm the suite published, the same values in the same order
    for topic in SCORES:
        assert [score_in(j) for j in reader.received[topic]] == tap.scores[topic], topic
        assert len(tap.scores[topic]) >= 100
    assert [tuple(j[f] for f in ALARM_FIELDS) for j in reader.received[ALARM_TOPIC]] == tap.alarms
    # ... and what the replay reports for each step (its decision: state and windowed score)
    report = json.loads((tmp_path / "report.json").read_text())
    decisions = [j for j in reader.received[ALARM_TOPIC] if not j["heartbeat"] and j["rollout_id"]]
    assert [(j["rollout_id"], j["step"], AlarmStateName.of_code(j["state"]), j["eta_obs"]) for j in decisions] == \
        [(r["rollout_id"], s["step"], s["state"], s["windowed"][0]) for r in report["rollouts"] for s in r["steps"]]
    first_alarms = [j["reason"] for j in decisions
                    if j["state"] == FailureAlarm.STATE_ALARM and not j["reason"].startswith("latched since")]
    assert first_alarms, "the failures of the set are predicted"
    assert all(re.fullmatch(r"(RND-OE|ACE) .+ since step \d+.*: (both |one )?exceeded \(.+\)", r) for r in first_alarms)
    # the client that never read lost frames; the one that read got (nearly) all; the one that left, its first ones
    read_images = len(reader.received[CAMERA_WRIST_TOPIC])
    assert read_images > 2 * outcome["stalled_images"] > 0, (read_images, outcome["stalled_images"],
                                                            tap.published_images)
    assert outcome["left"] >= 10
    assert set(outcome["channels"]) == SERVED
    assert outcome["channels"][ALARM_TOPIC]["schemaName"] == "fiper_msgs/msg/FailureAlarm"
    assert outcome["channels"][CAMERA_WRIST_TOPIC]["schemaName"] == "foxglove.RawImage"


def test_fiper_view_refuses_a_taken_port_in_one_line(ros_domain: int) -> None:
    import socket

    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        result = subprocess.run([sys.executable, "-m", "fiper_ros.cli", "view", "--port", str(port)],
                                env=ros_env(ros_domain), capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert result.stderr == f"fiper view: port {port} on 127.0.0.1 is taken (another live view, or a Foxglove " \
                            "bridge?)\n"


def test_with_nobody_watching_the_view_reads_nothing_of_the_suite(ros_domain: int) -> None:
    """On demand (the default): no reader of a topic until a client shows it, and none again once it left; so no
    publisher of the suite sends the view anything while nobody watches (docs/benchmarks.md, the view's cost)."""
    listener = DiagnosticsListener(ros_domain)
    view, port, _ = start_view(ros_domain)
    try:
        def status() -> dict[str, str]:
            return listener.statuses.get("fiper: /fiper/view_node", {})

        def readers(topic: str) -> int:
            return listener.node.count_subscribers(topic)

        assert listener.spin_until(lambda: "topics_read" in status(), 30)  # serving, and saying what it reads
        assert status()["topics_read"] == "0" and readers(ALARM_TOPIC) == 0 and readers(CAMERA_WRIST_TOPIC) == 0

        async def watch_then_leave() -> None:
            client = await open_client(port)
            await client.read_advertised(SERVED)
            await client.subscribe([ALARM_TOPIC])
            assert await asyncio.to_thread(listener.spin_until, lambda: readers(ALARM_TOPIC) == 1, 30)
            assert readers(CAMERA_WRIST_TOPIC) == 0  # only what a client shows
            await client.ws.close()

        asyncio.run(watch_then_leave())
        assert listener.spin_until(lambda: readers(ALARM_TOPIC) == 0, 30)
        assert view.poll() is None
    finally:
        output = stop(view)
        listener.close()
    assert view.returncode == 0, output[-3000:]
