"""``make bench-soak``: the demo's node set for an hour; memory and alarm latency per block.

The six node processes of ``fiper demo`` (sim bridge, policy, RND-OE, ACE, fusion, supervisor:
launch/demo.launch.yaml with the shipped Sorting model, sim time) run in a private domain with the bridge in real
time: its controller at the tasks' 10 Hz (``realtime_factor`` 1; the demo runs the sim as fast as it
can), so a Sorting policy step (h = 4 control steps plus the policy's inference) comes about every half
second. The demo's driver (:mod:`fiper_ros.client.driver`) resets rollouts back to back, in-distribution
and harmful OOD (``box_pos``) seeds in turn, until the time is up; the supervisor halts a rollout at its
alarm; the fusion node keeps every step's alarm for the driver (``EVERY_ALARM``, as ``make bench-nodes``).
Per block (5 minutes; 1 minute when ``--minutes`` is below 30) it prints: policy steps and their
rate, alarm latency p50 / p99 (the step's FailureAlarm received minus its action-chunk batch received,
both in this process on one monotonic clock; negative where the alarm overtook its batch on the way to this
process, counted as "overtaken"), steps without an alarm within :data:`UNANSWERED_S` ("unanswered"), UNKNOWN
decisions, batches of rollouts the driver never followed ("foreign": another run in the domain), the resident
memory (VmRSS) of every node process, the launcher and this driver. Flat memory and latency
are the target. ``soak.json`` in the output folder holds every block.
"""
from __future__ import annotations

import argparse
import itertools
import json
import os
import sys
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from fiper_msgs.msg import ActionChunkBatch, FailureAlarm
from fiper_ros.bench import EVERY_ALARM, memory_mb
from fiper_ros.client.driver import SETTLE_S, SimSuiteDriver, SuiteFailed
from fiper_ros.client.ros_session import RosSession
from fiper_ros.client.suite_process import FUSION_MODULE, SuiteProcess, detectors_of, installed_launch
from fiper_ros.client.trace import RolloutTrace
from fiper_ros.commands.demo import SUPERVISOR, Plan, demo_config, managed_nodes
from fiper_ros.interface import qos
from fiper_ros.interface.messages import AlarmStateName
from fiper_ros.interface.topics import ACTIONS_TOPIC
from fiper_ros.launcher.config import LaunchConfig, dump_launch
from fiper_ros.platform.dds import allocate_domain
from fiper_ros.platform.shm import clean_stale

BRIDGE_MODULE = "sim_bridge.bridge_node"
#: Seconds after which a step's action-chunk batch without an alarm counts as unanswered.
UNANSWERED_S = 10.0
#: Seconds a rollout may take per policy step it may have (plus a minute), at real time.
ROLLOUT_S_PER_STEP = 3.0
#: Rollout ids the meter remembers as followed (a batch older than UNANSWERED_S is judged by them).
FOLLOWED_KEPT = 64


@dataclass
class Block:
    """What one block of the soak measured."""

    index: int
    start_s: float
    """Seconds since the soak started."""
    full_s: float
    """The soak's block length."""
    length_s: float = 0.0
    """This block's (shorter than ``full_s`` for the last, partial one)."""
    steps: int = 0
    rollouts: int = 0
    alarms: int = 0
    """ALARM decisions (the first per rollout)."""
    unknown: int = 0
    unanswered: int = 0
    """Steps of the driver's rollouts whose alarm did not come within :data:`UNANSWERED_S`."""
    overtaken: int = 0
    """Steps whose alarm reached this process before their action-chunk batch (a negative latency)."""
    foreign: int = 0
    """Action-chunk batches older than :data:`UNANSWERED_S` of rollouts the driver never followed."""
    latency_ms: list[float] = field(default_factory=list)
    rss_mb: dict[str, float] = field(default_factory=dict)

    def line(self) -> str:
        """The block on one line."""
        lat = np.asarray(self.latency_ms)
        p50, p99 = (np.percentile(lat, 50), np.percentile(lat, 99)) if len(lat) else (float("nan"),) * 2
        rss = " ".join(f"{name} {mb:.0f}" for name, mb in self.rss_mb.items())
        span = f"{self.start_s / 60:5.1f}-{(self.start_s + self.length_s) / 60:5.1f} min"
        return (f"block {self.index:2d} ({span}{', partial' if self.length_s < self.full_s else ''}): "
                f"{self.steps:4d} steps ({self.steps / self.length_s:.2f}/s), {self.rollouts} rollouts, "
                f"{self.alarms} alarms | latency p50 {p50:6.1f} ms p99 {p99:6.1f} ms | unanswered {self.unanswered}, "
                f"overtaken {self.overtaken}, UNKNOWN {self.unknown}, foreign {self.foreign} | RSS MB: {rss}")


class StepMatcher:
    """Matches each policy step's action-chunk batch with its alarm by (rollout id, step), in whichever order
    they arrive: the alarm (policy -> detector -> fusion -> here) can overtake its batch (policy -> here) when
    this process is slow to take the batch. Times are of one monotonic clock, in ns."""

    def __init__(self, expire_ns: int) -> None:
        self.expire_ns = expire_ns
        self._batches: dict[tuple[int, int], int] = {}
        self._alarms: dict[tuple[int, int], int] = {}

    def batch(self, key: tuple[int, int], now_ns: int) -> int | None:
        """A batch arrived: its step's latency (negative) if the alarm came first, else ``None``."""
        since_alarm = self._arrived(key, now_ns, self._batches, self._alarms)
        return None if since_alarm is None else -since_alarm

    def alarm(self, key: tuple[int, int], now_ns: int) -> int | None:
        """An alarm arrived: its step's latency if the batch came first, else ``None`` (the batch may follow)."""
        return self._arrived(key, now_ns, self._alarms, self._batches)

    @staticmethod
    def _arrived(key: tuple[int, int], now_ns: int, mine: dict[tuple[int, int], int],
                 partners: dict[tuple[int, int], int]) -> int | None:
        """Time since the partner of ``key`` arrived, taking it; ``None`` (``key`` waits in ``mine``) if it has not."""
        partner = partners.pop(key, None)
        if partner is None:
            mine.setdefault(key, now_ns)
            return None
        return now_ns - partner

    def expire(self, now_ns: int) -> list[tuple[int, int]]:
        """Forget what waited longer than ``expire_ns``; the keys of the batches among it (no alarm came)."""
        stale = [key for key, at in self._batches.items() if now_ns - at > self.expire_ns]
        for key in stale:
            del self._batches[key]
        for key in [key for key, at in self._alarms.items() if now_ns - at > self.expire_ns]:
            del self._alarms[key]  # an alarm whose batch never came here (a step before the meter started)
        return stale


class Meter:
    """Times each policy step's alarm against its action-chunk batch (:class:`StepMatcher`) and closes a block
    every ``block_s``. A batch older than :data:`UNANSWERED_S` without its alarm is unanswered if its rollout
    is one the driver followed (the driver keeps the messages that arrive before the reset's answer and shows
    their alarms once it answered), foreign if not."""

    def __init__(self, session: RosSession, block_s: float) -> None:
        assert session.node is not None
        self.block_s = block_s
        self.pids: dict[str, int] = {}
        self.followed: deque[int] = deque(maxlen=FOLLOWED_KEPT)
        self.started = time.monotonic()
        self.blocks: list[Block] = []
        self.block = Block(0, 0.0, block_s)
        self.matcher = StepMatcher(int(UNANSWERED_S * 1e9))
        session.node.create_subscription(ActionChunkBatch, ACTIONS_TOPIC, self._on_batch, qos.INPUT)

    def start(self, pids: dict[str, int]) -> None:
        """Start the first block now; ``pids``: process name -> id, whose memory each block reads."""
        self.pids = pids
        self.started = time.monotonic()

    def follow(self, rollout_id: int) -> None:
        """The driver follows this rollout (its reset answered)."""
        self.followed.append(rollout_id)

    def _on_batch(self, msg: ActionChunkBatch) -> None:
        latency = self.matcher.batch((msg.rollout_id, msg.step), time.monotonic_ns())
        if latency is not None:
            self.block.overtaken += 1
            self._answered(latency)
        self.tick()

    def _answered(self, latency_ns: int) -> None:
        self.block.steps += 1
        self.block.latency_ms.append(latency_ns / 1e6)

    def on_alarm(self, trace: RolloutTrace, msg: FailureAlarm) -> None:
        """The driver's alarm display: one decision of a followed rollout."""
        latency = self.matcher.alarm((msg.rollout_id, msg.step), time.monotonic_ns())
        if latency is not None:
            self._answered(latency)
        state = AlarmStateName.of_code(msg.state)
        self.block.unknown += state == AlarmStateName.UNKNOWN
        self.block.alarms += state == AlarmStateName.ALARM and trace.alarm_step == msg.step
        self.tick()

    def rollout_done(self) -> None:
        """One more rollout ended in this block."""
        self.block.rollouts += 1

    def tick(self) -> None:
        """Close the block if its time is up."""
        if time.monotonic() - self.started >= self.block.start_s + self.block_s:
            self.close(self.block_s)

    def close(self, length_s: float) -> None:
        """Close the running block after ``length_s`` seconds: memory, unanswered steps, its line."""
        block = self.block
        block.length_s = length_s
        stale = self.matcher.expire(time.monotonic_ns())
        block.unanswered = sum(rollout in self.followed for rollout, _ in stale)
        block.foreign = len(stale) - block.unanswered
        block.rss_mb = {name: memory_mb(pid) for name, pid in self.pids.items()}
        self.blocks.append(block)
        print(block.line(), flush=True)
        self.block = Block(block.index + 1, block.start_s + length_s, self.block_s)


def plans() -> Iterator[Plan]:
    """In-distribution and harmful OOD rollouts in turn, each with a new seed."""
    for seed in itertools.count(3000):
        yield Plan("in-distribution", "id", seed)
        yield Plan("harmful OOD", "box_pos", seed)


def soak_config(model: Path, calibration: Path, detectors: tuple[str, ...], realtime_factor: float) -> LaunchConfig:
    """The demo's launch config with the bridge paced at ``realtime_factor`` and every alarm kept."""
    demo = demo_config(installed_launch("demo.launch.yaml"), model, calibration, detectors)
    extra = {BRIDGE_MODULE: {"realtime_factor": realtime_factor}, FUSION_MODULE: EVERY_ALARM}
    return demo.with_parameters(lambda spec: extra.get(spec.module, {}))


def summary(blocks: list[Block]) -> list[str]:
    """Memory and latency of the first full block against the last full one."""
    full = [b for b in blocks if b.latency_ms and b.length_s == b.full_s]
    if len(full) < 2:
        return ["fewer than two blocks with steps: no trend"]
    first, last = full[0], full[-1]
    lines = [f"latency p99: block {first.index} {np.percentile(first.latency_ms, 99):.1f} ms, block {last.index} "
             f"{np.percentile(last.latency_ms, 99):.1f} ms; p50 {np.percentile(first.latency_ms, 50):.1f} -> "
             f"{np.percentile(last.latency_ms, 50):.1f} ms"]
    lines += [f"RSS {name}: {first.rss_mb[name]:.0f} -> {last.rss_mb[name]:.0f} MB "
              f"({last.rss_mb[name] - first.rss_mb[name]:+.1f})" for name in first.rss_mb]
    return lines


def run_soak(args: argparse.Namespace) -> int:
    """The soak; returns the exit status."""
    model = args.model.resolve()
    calibration = (model / "calibration").resolve()
    block_s = 60.0 * (args.block_minutes or (5 if args.minutes >= 30 else 1))
    out = (args.out or Path("runs/soak") / datetime.now(timezone.utc).strftime("%Y%m%d-%H%M%S")).resolve()
    out.mkdir(parents=True, exist_ok=True)
    print(f"soak: {args.minutes:g} min, blocks of {block_s / 60:g} min, bridge realtime x{args.realtime_factor:g}; "
          f"{os.cpu_count()} cores; output {out}", flush=True)
    print(f"soak: {clean_stale().summary()}", flush=True)
    detectors = detectors_of(calibration)
    config = soak_config(model, calibration, detectors, args.realtime_factor)
    meter: Meter | None = None
    problem = ""
    with allocate_domain() as domain:
        print(f"soak: ROS domain {domain} (loopback only)", flush=True)
        suite = SuiteProcess(dump_launch(config, out / "launch.yaml"), domain, echo=False, log=out / "suite.log")
        try:
            with RosSession("fiper_soak", domain) as session:
                meter = Meter(session, block_s)
                driver = SimSuiteDriver(session, suite, "sorting", detectors, display=meter.on_alarm)
                driver.wait_ready(managed_nodes(config), args.ready_timeout, plain=(SUPERVISOR,))
                meter.start(suite.node_pids() | {"launcher": suite.proc.pid, "driver": os.getpid()})
                print(f"soak: all nodes active; processes {meter.pids}", flush=True)
                end = meter.started + 60.0 * args.minutes
                previous: RolloutTrace | None = None
                for plan in plans():
                    trace = driver.reset(plan.scenario, plan.seed, plan.label)
                    meter.follow(trace.rollout_id)
                    driver.follow(trace, 60.0 + ROLLOUT_S_PER_STEP * trace.max_steps)
                    driver.settle(lambda: trace.scored_steps() >= trace.steps_started, SETTLE_S)
                    if previous is not None:  # kept one rollout longer: its last alarm may follow its scores
                        del driver.traces[previous.rollout_id]  # the driver's own memory stays flat
                    previous = trace
                    meter.rollout_done()
                    if time.monotonic() >= end:
                        break
        except SuiteFailed as error:
            problem = f"{error}; its last output:\n{error.output}" if error.output else str(error)
        except KeyboardInterrupt:
            problem = "interrupted"
        finally:
            if meter is not None and meter.block.steps:  # the last, partial block, while the nodes still run
                meter.close(time.monotonic() - meter.started - meter.block.start_s)
            status = suite.stop()
    blocks = meter.blocks if meter is not None else []
    for line in summary(blocks):
        print(f"soak: {line}", flush=True)
    (out / "soak.json").write_text(json.dumps({"minutes": args.minutes, "block_s": block_s,
                                               "realtime_factor": args.realtime_factor, "problem": problem,
                                               "launcher_status": status, "blocks": [asdict(b) for b in blocks]}))
    if problem or status != 0:
        print(f"soak: FAILED: {problem or f'a node exited on its own (launcher status {status})'}", file=sys.stderr)
        return 1
    return 0


def main() -> int:
    """Parse the options and run the soak."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=60.0, help="how long to run (default: an hour)")
    parser.add_argument("--block-minutes", type=float, help="block length (default 5, or 1 below 30 minutes)")
    parser.add_argument("--realtime-factor", type=float, default=1.0, help="the bridge's pacing (1: 10 Hz control)")
    parser.add_argument("--model", type=Path, default=Path("models/sorting"), help="policy folder (Sorting)")
    parser.add_argument("--out", type=Path, help="output folder (default runs/soak/<UTC time>)")
    parser.add_argument("--ready-timeout", type=float, default=120.0, help="seconds for every node to become active")
    return run_soak(parser.parse_args())


if __name__ == "__main__":
    sys.exit(main())
