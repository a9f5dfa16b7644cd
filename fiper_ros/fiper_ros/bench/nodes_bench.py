"""``make bench-nodes``: end-to-end latency and throughput of the node suite over real DDS.

The three FIPER nodes run as separate processes (``fiper launch``) in a private ROS domain on
loopback. A driver in this process publishes an embedding and an action-chunk batch per policy step
and receives the FailureAlarm of that step; latency = alarm received - embedding published (one
monotonic clock, same process). Measured per task shape: p50 / p99 latency at 10 Hz, and the highest
sustained rate (steps/s) at which every step's alarm arrives and the backlog stays below 0.5 s.
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from fiper_ros.bench import EVERY_ALARM
from fiper_ros.core.calibration import CalibrationSettings, calibrate
from fiper_ros.core.rnd_oe import RNDConfig
from fiper_ros.core.rollout import Rollout
from fiper_ros.dds import allocate_domain, local_env
from fiper_ros.shm import clean_stale

CONFIG_DIR = Path(__file__).resolve().parents[2] / "config"


@dataclass(frozen=True)
class Shape:
    """A task's message shape."""

    name: str
    embedding_dim: int
    batch: int
    horizon: int
    action_dim: int
    exec_steps: int


SHAPES = (Shape("pusht", 64, 256, 16, 3, 8), Shape("pretzel", 512, 30, 16, 5, 8))


def shaped_calibration(shape: Shape, directory: Path, seed: int = 0) -> Path:
    """A calibration of ``shape`` (small default RND-OE, few epochs: latency does not depend on training)."""
    rng = np.random.default_rng(seed)
    rollouts = []
    for i in range(8):
        t = 20
        base = rng.uniform(-1, 1, (t, 1, shape.horizon, shape.action_dim))
        rollouts.append(Rollout(
            rollout_id=f"bench-{i}", task=shape.name, scenario="id",
            embeddings=rng.normal(size=(t, shape.embedding_dim)).astype(np.float32),
            actions=(base + rng.normal(0, 0.05, (t, shape.batch, shape.horizon, shape.action_dim))).astype(np.float32),
            exec_steps=shape.exec_steps, success=True,
        ))
    action_dims = (0, min(3, shape.action_dim))
    settings = CalibrationSettings(rnd=RNDConfig(max_epochs=3), action_dims=action_dims)
    calibrate(rollouts, settings).save(directory)
    return directory


def _launch(calibration: Path, work: Path, domain: int) -> subprocess.Popen[bytes]:
    config = work / "suite.yaml"
    params = {"calibration_dir": str(calibration)}
    config.write_text(yaml.safe_dump({
        "namespace": "/fiper", "parameter_files": [str(CONFIG_DIR / "nodes.yaml")],
        "nodes": {"rnd_oe_node": {"module": "fiper_ros.nodes.rnd_oe_node", "parameters": params},
                  "ace_node": {"module": "fiper_ros.nodes.ace_node", "parameters": params},
                  "fusion_node": {"module": "fiper_ros.nodes.fusion_node", "parameters": EVERY_ALARM}},
    }))
    return subprocess.Popen([sys.executable, "-m", "fiper_ros.cli", "launch", str(config)],  # noqa: S603
                            env=local_env(domain), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)


class Driver:
    """Publishes policy steps and times their alarms."""

    def __init__(self, shape: Shape, domain: int) -> None:
        import rclpy  # noqa: PLC0415
        from rclpy.context import Context  # noqa: PLC0415
        from rclpy.executors import SingleThreadedExecutor  # noqa: PLC0415

        from fiper_msgs.msg import ActionChunkBatch, FailureAlarm, ObservationEmbedding, RolloutEvent  # noqa: PLC0415

        from fiper_ros.interface import qos  # noqa: PLC0415

        self.shape = shape
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node("bench_driver", namespace="/fiper", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.emb_pub = self.node.create_publisher(ObservationEmbedding, "observation_embedding", qos.INPUT)
        self.act_pub = self.node.create_publisher(ActionChunkBatch, "action_chunks", qos.INPUT)
        self.event_pub = self.node.create_publisher(RolloutEvent, "rollout_events", qos.EVENT)
        self.received: dict[tuple[int, int], int] = {}
        self.node.create_subscription(FailureAlarm, "alarm", self._on_alarm, qos.ALARM_EVERY)
        rng = np.random.default_rng(1)
        self.embedding = rng.normal(size=shape.embedding_dim).astype(np.float32)
        self.actions = rng.uniform(-1, 1, (shape.batch, shape.horizon, shape.action_dim)).astype(np.float32)
        self._rclpy = rclpy

    def _on_alarm(self, msg: object) -> None:
        key = (msg.rollout_id, msg.step)  # type: ignore[attr-defined]
        if key not in self.received and not msg.heartbeat:  # type: ignore[attr-defined]
            self.received[key] = time.monotonic_ns()

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            self.executor.spin_once(timeout_sec=min(left, 0.05))

    def wait_ready(self, timeout: float = 120.0) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if (self.emb_pub.get_subscription_count() and self.act_pub.get_subscription_count()
                    and self.event_pub.get_subscription_count() >= 3):
                self.spin_for(1.0)
                return
            self.spin_for(0.1)
        raise RuntimeError("the suite did not come up")

    def run(self, rollout_id: int, steps: int, rate_hz: float) -> tuple[np.ndarray, int, float]:
        """Publish ``steps`` steps at ``rate_hz``; return latencies (ms), missing steps, final backlog (s)."""
        from fiper_msgs.msg import RolloutEvent  # noqa: PLC0415
        from fiper_ros.interface.conversions import action_batch_msg, embedding_msg, rollout_event_msg  # noqa: PLC0415

        self.event_pub.publish(rollout_event_msg(rollout_id, RolloutEvent.EVENT_START, 0))
        self.spin_for(0.3)
        sent: dict[int, int] = {}
        period = 1e9 / rate_hz
        start = time.monotonic_ns()
        for step in range(steps):
            # Sleep in the executor until the step is due: a busy loop here would take a core from the nodes.
            while (wait_ns := start + step * period - time.monotonic_ns()) > 0:
                self.executor.spin_once(timeout_sec=wait_ns / 1e9)
            stamp = (step + 1) * 100_000_000
            emb = embedding_msg(rollout_id, step, stamp, self.embedding)
            act = action_batch_msg(rollout_id, step, stamp, self.actions, self.shape.exec_steps, "ee_position")
            sent[step] = time.monotonic_ns()
            self.emb_pub.publish(emb)
            self.act_pub.publish(act)
        last_sent = time.monotonic_ns()
        end = time.monotonic() + 5.0
        while time.monotonic() < end and any((rollout_id, s) not in self.received for s in sent):
            self.executor.spin_once(timeout_sec=0.01)
        got = [self.received[(rollout_id, s)] - sent[s] for s in sent if (rollout_id, s) in self.received]
        missing = steps - len(got)
        backlog = (max(self.received.get((rollout_id, s), last_sent) for s in sent) - last_sent) / 1e9
        self.event_pub.publish(rollout_event_msg(rollout_id, RolloutEvent.EVENT_END, 0))
        return np.asarray(got) / 1e6, missing, backlog

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.context)


def bench_shape(shape: Shape, steps: int, rates: list[float]) -> dict[str, float]:
    """Latency at 10 Hz and the highest sustained rate for one shape."""
    with tempfile.TemporaryDirectory() as tmp, allocate_domain() as domain:
        work = Path(tmp)
        calibration = shaped_calibration(shape, work / "calibration")
        launch = _launch(calibration, work, domain)
        driver = Driver(shape, domain)
        try:
            driver.wait_ready()
            driver.run(1, 20, 10.0)  # warm-up
            lat, missing, _ = driver.run(2, steps, 10.0)
            result = {"p50_ms": float(np.percentile(lat, 50)), "p99_ms": float(np.percentile(lat, 99)),
                      "missing_at_10hz": float(missing), "sustained_hz": 0.0}
            for i, rate in enumerate(rates):
                lat_r, missing_r, backlog = driver.run(10 + i, max(100, int(rate * 2)), rate)
                ok = missing_r == 0 and backlog < 0.5
                print(f"  {shape.name}: {rate:6.0f} steps/s -> missing {missing_r}, backlog {backlog:.3f} s, "
                      f"p50 {np.percentile(lat_r, 50) if len(lat_r) else float('nan'):.2f} ms "
                      f"{'ok' if ok else 'NOT sustained'}", flush=True)
                if not ok:
                    break
                result["sustained_hz"] = rate
            return result
        finally:
            driver.close()
            os.killpg(launch.pid, signal.SIGINT)
            launch.wait(timeout=30)


def main() -> int:
    """Print the figures of every shape and the ratios to the targets."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=300, help="steps of the 10 Hz latency run")
    parser.add_argument("--rates", type=float, nargs="+", default=[50, 100, 200, 300, 400, 600, 800])
    args = parser.parse_args()
    print(f"machine: {os.cpu_count()} cores; nodes as separate processes; loopback DDS; {args.steps} steps at 10 Hz")
    print(clean_stale().summary(), flush=True)
    for shape in SHAPES:
        r = bench_shape(shape, args.steps, args.rates)
        print(f"{shape.name} (E {shape.embedding_dim}, B {shape.batch}, H {shape.horizon}, D {shape.action_dim}): "
              f"latency p50 {r['p50_ms']:.2f} ms, p99 {r['p99_ms']:.2f} ms (target p99 <= 15 ms: "
              f"{r['p99_ms'] / 15:.2f}x), missing {int(r['missing_at_10hz'])}; sustained {r['sustained_hz']:.0f} steps/s "
              f"(target >= 200: {r['sustained_hz'] / 200:.2f}x)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
