"""``make bench-nodes``: start-up, memory, end-to-end latency and throughput of the node suite over real DDS.

The three FIPER nodes run as separate processes (``fiper launch``) in a private ROS domain on
loopback. A driver in this process publishes an embedding and an action-chunk batch per policy step
and receives the FailureAlarm of that step; latency = alarm received - embedding published (one
monotonic clock, same process). Measured per task shape: p50 / p99 latency at 10 Hz, and the highest
sustained rate (steps/s) at which every step's alarm arrives and the backlog stays below 0.5 s; for each rate
tried, its p50 / p99 and the CPU milliseconds per step of each suite process and of the driver (``/proc``: all
threads, DDS's included), which say where the time goes; for the rate that is not sustained, where its steps went
(the nodes' ``/diagnostics`` counters, :data:`LOSS_COUNTERS`). Every figure is printed with its ratio to its
target (docs/benchmarks.md). The nodes and the driver spin the executor :mod:`fiper_ros.platform.process` chooses
(``FIPER_EXECUTOR``).

Start-up, per shape before the latency runs, each start repeated (:data:`NODE_STARTS`,
:data:`SUITE_STARTS`: DDS discovery takes a few ms or one to three seconds from one start to the next): each
node started alone (its command line as ``fiper launch`` builds it), the seconds from its exec to ACTIVE by the
node's own ``ACTIVE`` log line (:func:`fiper_ros.platform.process.process_age_s`), and until the driver sees it ACTIVE
(it asks the node's lifecycle ``get_state`` service every 20 ms: discovery included, the figure's resolution),
its peak RSS then (``VmHWM``); then the suite: the seconds from the exec of ``fiper launch`` until all three
nodes are ACTIVE and discovered one another (the driver's inputs matched by the scoring nodes, the events by
all three, the scores subscribed by the fusion node and the alarm published, as the driver's graph shows them).
The targets are judged on the median start. For reference, the same discovery without our code: a plain rclpy
node's publisher (:data:`PLAIN_NODE`), seconds from its creation until the driver's graph shows it. After the
runs: each suite node's peak RSS. The load average is printed before and after: the figures depend on what
else runs.

``--profile DIR`` profiles the suite's nodes (``cProfile`` of their main thread's CPU time, ``FIPER_PROFILE_DIR``)
and the driver's timed runs into ``DIR/<shape>/<process>.prof`` (``python -m pstats``); profiled figures are slower.

``--compose`` runs RND-OE and the fusion node composed in one process (``fiper.launch.yaml compose:=true``,
:mod:`fiper_ros.nodes.container`), ACE in its own: the start-up of that container alone stands for those two nodes'.

After each shape, the platform's floor (unless ``--no-floor``): the same driver's 10 Hz run and a run at the shape's
target rate through :mod:`fiper_ros.bench.null_suite`, the suite's topology with no work (three processes named as
the suite's nodes, on its topics with its QoS, executor and wire codec, relaying). The suite's figures less the
floor's are what the nodes' own work costs; a target below the floor cannot be met by the nodes on this machine.

``--view`` runs the live view (``fiper view``) beside the suite, with no client connected: the
figures with and without it say what the view costs the suite when nobody watches.
"""
from __future__ import annotations

import argparse
import cProfile
import os
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np

from fiper_ros.bench import EVERY_ALARM, memory_mb, null_suite
from fiper_ros.client.suite_process import installed_launch
from fiper_ros.core.calibration import CalibrationSettings, calibrate
from fiper_ros.core.rnd_oe import RNDConfig
from fiper_ros.core.rollout import Rollout
from fiper_ros.launcher.config import NodeSpec, load_launch
from fiper_ros.launcher.overrides import Overrides, rewrite
from fiper_ros.nodes import container
from fiper_ros.nodes.base import ACTIVE_LOG, ACTIVE_LOG_END
from fiper_ros.platform.dds import allocate_domain, interrupt_group, local_env
from fiper_ros.platform.process import EXECUTOR_ENV, PROFILE_ENV, proc_stat, use_discovery_profile
from fiper_ros.platform.shm import clean_stale
from fiper_ros.runtime.trusted_publishers import fully_qualified

#: Issue #24: a scoring node ACTIVE within this long of its exec on this machine, the three-node suite (discovery
#: included) within :data:`TARGET_SUITE_S`; alarm latency p99 at 10 Hz at most :data:`TARGET_P99_MS`; each node's
#: peak RSS at most :data:`TARGET_RSS_MB` (the hour-long figure is the soak benchmark's); the sustained rate of a
#: shape: :attr:`Shape.target_rate`.
TARGET_NODE_S = 1.5
TARGET_SUITE_S = 3.0
TARGET_P99_MS = 5.0
TARGET_RSS_MB = 150.0
#: Period of the lifecycle ``get_state`` requests while waiting for ACTIVE: the resolution of the start-up figures.
POLL_S = 0.02
#: A ``get_state`` request not answered within this long is asked again. One went unanswered for good in about 70
#: suite starts (every node had logged ACTIVE within 0.9 s; the driver waited 120 s): likely sent before the new
#: server's endpoints matched the client, which the driver keeps from the suite's previous start.
GET_STATE_TIMEOUT_S = 1.0
#: Longest wait for a node or the suite to come up.
STARTUP_TIMEOUT_S = 120.0
#: Starts of each node alone, and of the suite, per shape; and of the plain rclpy node (:data:`PLAIN_NODE`).
NODE_STARTS, SUITE_STARTS, PLAIN_STARTS = 3, 5, 8
#: A node without any of our code: prints ``created`` and ``time.monotonic()`` once its node exists, then creates a
#: publisher of topic ``argv[1]`` and lives until killed (the driver's graph times the discovery).
PLAIN_NODE = ("import sys, time, rclpy; from std_msgs.msg import String; rclpy.init(); n = rclpy.create_node('plain'); "
              "print('created', time.monotonic(), flush=True); n.create_publisher(String, sys.argv[1], 10); "
              "time.sleep(60)")
#: Lines the plain node may print before its ``created`` line (Fast DDS writes its own log to standard output).
PLAIN_OUTPUT_LINES = 100
#: Lines of the suite's output printed when it does not come up.
FAILED_OUTPUT_LINES = 60
#: A node's log line saying it reached ACTIVE, with the seconds since its process started.
ACTIVE_LINE = re.compile(rf"\]: {ACTIVE_LOG} (\d+(?:\.\d+)?) {re.escape(ACTIVE_LOG_END)}")


@dataclass(frozen=True)
class Shape:
    """A task's message shape."""

    name: str
    embedding_dim: int
    batch: int
    horizon: int
    action_dim: int
    exec_steps: int
    target_rate: float
    """Issue #24: the steps/s the suite sustains at this shape, every step's alarm received."""


SHAPES = (Shape("pusht", 64, 256, 16, 2, 8, 1000.0), Shape("pretzel", 512, 30, 16, 5, 8, 600.0))
#: The ``/diagnostics`` counters that say where a rate run's steps went, per node: the scores each scoring node
#: published; the steps the fusion node fused (``matched``), dropped from its full buffer of unmatched steps
#: (``evicted``: the other score of the step was more than ``buffer_size`` steps late; a step whose other score
#: comes after the eviction waits, and may be evicted, again) and dropped as older than a fused step (``unmatched``:
#: their other score never came, e.g. lost from a full reader history).
LOSS_COUNTERS = {"rnd_oe_node": ("published",), "ace_node": ("published",),
                 "fusion_node": ("matched", "evicted", "unmatched")}
#: The launch entry of the composed RND-OE and fusion nodes (``compose:=true``), named by its executable.
CONTAINER = "container"
#: Longest wait for a fresh ``/diagnostics`` message of every suite node (they publish every second).
DIAGNOSTICS_WAIT_S = 3.0


def status_node(name: str) -> str:
    """The node a suite node's /diagnostics status name (``fiper: /fiper/<node>``) is of."""
    return name.rsplit("/", 1)[-1]


def loss_counters(diagnostics: dict[str, dict[str, str]]) -> dict[str, int]:
    """The :data:`LOSS_COUNTERS` of the suite's nodes, ``<node>.<key>``, from their latest ``/diagnostics`` values
    (by status name, ``fiper: /fiper/<node>``)."""
    counts = {}
    for name, values in diagnostics.items():
        node = status_node(name)
        for key in LOSS_COUNTERS.get(node, ()):
            if key in values:
                counts[f"{node}.{key}"] = int(values[key])
    return counts


def where_lost(before: dict[str, int], after: dict[str, int], steps: int) -> str:
    """Where the steps of a run of ``steps`` steps went, from the :func:`loss_counters` before and after it."""
    delta = {key: after.get(key, 0) - before.get(key, 0) for key in after}
    return (f"scores published: rnd_oe {delta.get('rnd_oe_node.published', 0)}, ace "
            f"{delta.get('ace_node.published', 0)} of {steps}; the fusion node fused "
            f"{delta.get('fusion_node.matched', 0)}, evicted {delta.get('fusion_node.evicted', 0)} (from its full buffer of "
            f"unmatched steps; a step counts once per score evicted) and dropped "
            f"{delta.get('fusion_node.unmatched', 0)} (the other score never came)")


def shaped_calibration(shape: Shape, directory: Path, seed: int = 0) -> Path:
    """A calibration of ``shape`` (small default RND-OE, few epochs; 8 rollouts, so CP constant thresholds at
    delta 0.25, finite with 4 conformal rollouts and 3 in the leave-one-out estimate: latency and start-up
    depend neither on the training nor on the thresholds' values)."""
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
    settings = CalibrationSettings(rnd=RNDConfig(max_epochs=3), action_dims=action_dims, threshold="cp_constant",
                                   delta=0.25)
    calibrate(rollouts, settings).save(directory)
    return directory


def _suite_config(calibration: Path, work: Path, compose: bool = False) -> Path:
    """The installed suite (``fiper.launch.yaml``) on ``calibration``, its fusion node keeping every alarm
    (``compose``: RND-OE and the fusion node in one process, ``compose:=true``)."""
    every = Overrides(by_name={"fusion_node": EVERY_ALARM, CONTAINER: EVERY_ALARM})
    return rewrite(installed_launch(), every, work / "suite.launch.yaml",
                   {"calibration_dir": str(calibration), "compose": str(compose).lower()})


def spec_nodes(spec: NodeSpec) -> list[str]:
    """The names of the nodes a launch entry's process runs: its one node, or those its ``args`` give a container."""
    return container.contained(list(spec.arguments)) if spec.module == container.__name__ else [spec.name]


def spec_fqns(spec: NodeSpec) -> list[str]:
    """The fully qualified names of the nodes a launch entry's process runs."""
    return [fully_qualified(spec.namespace, name) for name in spec_nodes(spec)]


def _start(command: list[str], domain: int, env: dict[str, str] | None = None,
           output: Path | None = None) -> subprocess.Popen[bytes]:
    """Start ``command`` in its own process group; its output into the file ``output``, else discarded."""
    with open(output or os.devnull, "wb") as sink:  # the child holds its own descriptor
        return subprocess.Popen(command, env=env or local_env(domain), stdout=sink,  # noqa: S603
                                stderr=subprocess.STDOUT, start_new_session=True)


def own_active_s(output: Path) -> dict[str, float]:
    """Each node's seconds from its exec to ACTIVE by its own log line in ``output``, by node name (the last word
    of the logger's name: ``[fiper.ace_node]``)."""
    seconds = {}
    for line in output.read_text(errors="replace").splitlines():
        if match := ACTIVE_LINE.search(line):
            logger = line[:match.start()].rsplit("[", 1)[-1]
            seconds[logger.rsplit(".", 1)[-1]] = float(match.group(1))
    return seconds


def _stop(process: subprocess.Popen[bytes]) -> None:
    """SIGINT to the process group (the launcher passes it on to its nodes), then wait."""
    interrupt_group(process.pid)
    process.wait(timeout=30)


def node_pids(launcher: int) -> dict[str, int]:
    """The pid of each node process ``fiper launch`` (pid ``launcher``) started, by module."""
    pids = {}
    for child in Path(f"/proc/{launcher}/task/{launcher}/children").read_text().split():
        command = Path(f"/proc/{child}/cmdline").read_bytes().split(b"\0")
        if b"-m" in command:
            pids[command[command.index(b"-m") + 1].decode().rsplit(".", 1)[-1]] = int(child)
    return pids


def node_peaks(launcher: int) -> dict[str, float]:
    """Peak RSS (MB) of each node process ``fiper launch`` (pid ``launcher``) started, by module."""
    return {name: memory_mb(pid, "VmHWM") for name, pid in node_pids(launcher).items()}


def cpu_seconds(pid: int) -> float:
    """The CPU time (user + system, all threads) a live process has used, in seconds."""
    fields = proc_stat(pid)
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime + stime, fields 14 and 15


@dataclass(frozen=True)
class Startup:
    """One node started alone: seconds from its exec to ACTIVE by its own log and as the driver saw it (discovery
    included), and its peak RSS then."""

    own_s: float
    seen_s: float
    peak_mb: float


def node_startup(spec: NodeSpec, driver: PolicyStepDriver, domain: int) -> Startup:
    """Start the node of ``spec`` alone (its ``fiper launch`` command line) and time it to ACTIVE (a container:
    its last node)."""
    with tempfile.TemporaryDirectory() as work:  # its parameter files, read at its start, and its output
        command, output = spec.command(Path(work)), Path(work) / "output.log"
        started = time.monotonic()
        process = _start(command, domain, output=output)
        try:
            active = driver.wait_active(spec_fqns(spec))
            peak = memory_mb(process.pid, "VmHWM")
        finally:
            _stop(process)
        own = own_active_s(output)
        nodes = spec_nodes(spec)  # a container's last node; NaN if any node's log line is missing
        own_s = max(own[name] for name in nodes) if all(name in own for name in nodes) else float("nan")
        return Startup(own_s, active - started, peak)


def _created(output: IO[bytes]) -> float:
    """The ``time.monotonic()`` of the plain node's ``created`` line."""
    for _ in range(PLAIN_OUTPUT_LINES):
        words = output.readline().split()
        if len(words) == 2 and words[0] == b"created":
            return float(words[1])
    raise RuntimeError(f"the plain node printed no 'created' line in {PLAIN_OUTPUT_LINES} lines")


def plain_discovery(driver: PolicyStepDriver, domain: int, starts: int) -> list[float]:
    """Seconds from a plain rclpy node's creation (:data:`PLAIN_NODE`, a new process each start) until the driver's
    graph shows its publisher: DDS discovery alone, without any code of ours."""
    seconds = []
    for start in range(starts):
        topic = f"/bench_plain_{start}"
        process = subprocess.Popen([sys.executable, "-c", PLAIN_NODE, topic], env=local_env(domain),  # noqa: S603
                                   stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            created = _created(process.stdout)  # type: ignore[arg-type]
            end = time.monotonic() + STARTUP_TIMEOUT_S
            while not driver.node.count_publishers(topic) and time.monotonic() < end:
                driver.executor.spin_once(timeout_sec=0.002)
            seconds.append(time.monotonic() - created)
        finally:
            process.kill()
            process.wait()
    return seconds


class PolicyStepDriver:
    """Publishes policy steps and times their alarms."""

    def __init__(self, shape: Shape, domain: int) -> None:
        import rclpy  # noqa: PLC0415
        from rclpy.context import Context  # noqa: PLC0415

        from diagnostic_msgs.msg import DiagnosticArray  # noqa: PLC0415

        from fiper_msgs.msg import ActionChunkBatch, FailureAlarm, ObservationEmbedding, RolloutEvent  # noqa: PLC0415

        from fiper_ros.interface import qos  # noqa: PLC0415
        from fiper_ros.interface.cdr import codec  # noqa: PLC0415
        from fiper_ros.interface.topics import DIAGNOSTICS_TOPIC  # noqa: PLC0415
        from fiper_ros.platform.process import EXECUTOR_EVENTS, new_executor  # noqa: PLC0415

        self.shape = shape
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node("bench_driver", namespace="/fiper", context=self.context)
        self.executor = new_executor(default=EXECUTOR_EVENTS, context=self.context)  # as the suite's nodes
        self.executor.add_node(self.node)
        self.emb_pub = self.node.create_publisher(ObservationEmbedding, "observation_embedding", qos.INPUT)
        self.act_pub = self.node.create_publisher(ActionChunkBatch, "action_chunks", qos.INPUT)
        self.event_pub = self.node.create_publisher(RolloutEvent, "rollout_events", qos.EVENT)
        self.received: dict[tuple[int, int], int] = {}
        #: Steps published whose alarm has not arrived yet.
        self.waiting: set[tuple[int, int]] = set()
        self.clients: dict[str, Any] = {}
        # As the suite's nodes take their inputs: the CDR bytes, read by the wire codec.
        self._alarm = codec(FailureAlarm)
        self.node.create_subscription(FailureAlarm, "alarm", self._on_alarm, qos.ALARM_EVERY, raw=True)
        #: The latest ``/diagnostics`` values of each status name, and when (``time.monotonic()``) they came.
        self.diagnostics: dict[str, dict[str, str]] = {}
        self.diagnostics_at: dict[str, float] = {}
        #: ``/diagnostics`` messages not read yet (bytes, arrival): read when asked for, not while a run is timed.
        self._unread: list[tuple[bytes, float]] = []
        self._diagnostics = codec(DiagnosticArray)
        self.node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self._on_diagnostics, qos.DIAGNOSTICS,
                                      raw=True)
        rng = np.random.default_rng(1)
        self.embedding = rng.normal(size=shape.embedding_dim).astype(np.float32)
        self.actions = rng.uniform(-1, 1, (shape.batch, shape.horizon, shape.action_dim)).astype(np.float32)
        self._rclpy = rclpy

    def _on_alarm(self, data: bytes) -> None:
        now = time.monotonic_ns()
        msg = self._alarm.decode(data)
        key = (msg.rollout_id, msg.step)
        if key not in self.received and not msg.heartbeat:
            self.received[key] = now
            self.waiting.discard(key)

    def _on_diagnostics(self, data: bytes) -> None:
        self._unread.append((data, time.monotonic()))

    def read_diagnostics(self) -> None:
        """Read the ``/diagnostics`` messages that came since the last call into :attr:`diagnostics`."""
        unread, self._unread = self._unread, []
        for data, arrived in unread:
            for status in self._diagnostics.decode(data).status:
                self.diagnostics[status.name] = {value.key: value.value for value in status.values}
                self.diagnostics_at[status.name] = arrived

    def fresh_counters(self) -> dict[str, int]:
        """The suite's :func:`loss_counters`, once every node that reports them has published ``/diagnostics``
        after this call (at most :data:`DIAGNOSTICS_WAIT_S`)."""
        asked = time.monotonic()
        end = asked + DIAGNOSTICS_WAIT_S
        while time.monotonic() < end:
            self.read_diagnostics()
            reporting = [name for name in self.diagnostics if status_node(name) in LOSS_COUNTERS]
            if len(reporting) == len(LOSS_COUNTERS) and all(self.diagnostics_at[n] > asked for n in reporting):
                break
            self.executor.spin_once(timeout_sec=0.05)
        return loss_counters(self.diagnostics)

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            self.executor.spin_once(timeout_sec=min(left, 0.05))

    def wait_active(self, nodes: Sequence[str]) -> float:
        """Ask the lifecycle state of the nodes (fully qualified names) every :data:`POLL_S` until each is ACTIVE;
        the ``time.monotonic()`` of the answer that made the last one ACTIVE."""
        from lifecycle_msgs.msg import State  # noqa: PLC0415
        from lifecycle_msgs.srv import GetState  # noqa: PLC0415

        clients = {node: self.clients.get(node) or self.node.create_client(GetState, f"{node}/get_state")
                   for node in nodes}
        self.clients.update(clients)
        #: Each node's request in flight and when it was sent (None: none in flight).
        pending: dict[str, tuple[Any, float] | None] = dict.fromkeys(nodes)
        unanswered = 0
        end = time.monotonic() + STARTUP_TIMEOUT_S
        while (now := time.monotonic()) < end:
            for node, asked in list(pending.items()):
                if asked is not None:
                    future, sent = asked
                    if future.done():
                        if future.result().current_state.id == State.PRIMARY_STATE_ACTIVE:
                            del pending[node]
                            if not pending:
                                return time.monotonic()
                            continue
                        asked = None
                    elif now - sent > GET_STATE_TIMEOUT_S:
                        clients[node].remove_pending_request(future)  # lost: ask again
                        unanswered += 1
                        asked = None
                if asked is None and clients[node].service_is_ready():
                    asked = (clients[node].call_async(GetState.Request()), now)
                pending[node] = asked
            self.executor.spin_once(timeout_sec=POLL_S)
        raise RuntimeError(f"not ACTIVE after {STARTUP_TIMEOUT_S:.0f} s: {', '.join(pending)} ({unanswered} "
                           f"get_state requests unanswered within {GET_STATE_TIMEOUT_S:g} s)")

    def wired(self) -> bool:
        """Whether the suite's topics are matched as far as the driver sees: its inputs by the scoring nodes, its
        events by all three, the scores subscribed by the fusion node, the alarm published."""
        count = self.node.count_subscribers
        return bool(self.emb_pub.get_subscription_count() and self.act_pub.get_subscription_count()
                    and self.event_pub.get_subscription_count() >= 3 and count("scores/rnd_oe") and count("scores/ace")
                    and self.node.count_publishers("alarm"))

    def wait_wired(self, what: str = "the suite") -> float:
        """Wait until :meth:`wired` (at most :data:`STARTUP_TIMEOUT_S`; ``what``: whose topics, for the error); the
        ``time.monotonic()`` of that."""
        end = time.monotonic() + STARTUP_TIMEOUT_S
        while not self.wired():
            if time.monotonic() > end:
                raise RuntimeError(f"{what} did not come up")
            self.executor.spin_once(timeout_sec=POLL_S)
        return time.monotonic()

    def wait_ready(self, nodes: Sequence[str]) -> float:
        """Wait until the nodes are ACTIVE and :meth:`wired`; the ``time.monotonic()`` of that."""
        self.wait_active(nodes)
        return self.wait_wired()

    def run(self, rollout_id: int, steps: int, rate_hz: float) -> tuple[np.ndarray, int, float]:
        """Publish ``steps`` steps at ``rate_hz``; return latencies (ms), missing steps, final backlog (s)."""
        from fiper_msgs.msg import RolloutEvent  # noqa: PLC0415
        from fiper_ros.interface.conversions import action_batch_cdr, embedding_cdr, rollout_event_msg  # noqa: PLC0415

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
            # What FiperPublisher.step publishes, the suite's policy side.
            emb = embedding_cdr(rollout_id, step, stamp, self.embedding)
            act = action_batch_cdr(rollout_id, step, stamp, self.actions, self.shape.exec_steps, "ee_position")
            sent[step] = time.monotonic_ns()
            self.waiting.add((rollout_id, step))
            self.emb_pub.publish(emb)
            self.act_pub.publish(act)
        last_sent = time.monotonic_ns()
        end = time.monotonic() + 5.0
        while time.monotonic() < end and self.waiting:  # not a scan of every step per alarm: that took a core's time
            self.executor.spin_once(timeout_sec=0.01)
        self.waiting.clear()
        got = [self.received[(rollout_id, s)] - sent[s] for s in sent if (rollout_id, s) in self.received]
        missing = steps - len(got)
        backlog = (max(self.received.get((rollout_id, s), last_sent) for s in sent) - last_sent) / 1e9
        self.event_pub.publish(rollout_event_msg(rollout_id, RolloutEvent.EVENT_END, 0))
        return np.asarray(got) / 1e6, missing, backlog

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.context)


def bench_startup(shape: Shape, config: Path, domain: int, starts: int = NODE_STARTS) -> dict[str, list[Startup]]:
    """Each node of the launch YAML ``config`` started alone, one after the other, ``starts`` rounds."""
    driver = PolicyStepDriver(shape, domain)
    nodes = load_launch(config).nodes
    try:
        rounds = [[node_startup(spec, driver, domain) for spec in nodes] for _ in range(starts)]
        return {spec.name: [one[i] for one in rounds] for i, spec in enumerate(nodes)}
    finally:
        driver.close()


def cpu_per_step(pids: dict[str, int], before: dict[str, float], steps: int) -> dict[str, float]:
    """The CPU milliseconds per step each process used since ``before`` (its :func:`cpu_seconds` then)."""
    return {name: (cpu_seconds(pid) - before[name]) / steps * 1e3 for name, pid in pids.items()}


def steps_at(rate: float) -> int:
    """The steps of a run at ``rate`` steps/s: two seconds' worth, at least 100."""
    return max(100, int(rate * 2))


def rate_run(driver: PolicyStepDriver, pids: dict[str, int], rollout_id: int,
             rate: float) -> tuple[np.ndarray, int, float, dict[str, float]]:
    """One run of :func:`steps_at` steps at ``rate``: :meth:`PolicyStepDriver.run`'s latencies, missing steps and
    backlog, and the CPU milliseconds per step of each process of ``pids``."""
    before = {name: cpu_seconds(pid) for name, pid in pids.items()}
    steps = steps_at(rate)
    latencies, missing, backlog = driver.run(rollout_id, steps, rate)
    return latencies, missing, backlog, cpu_per_step(pids, before, steps)


def rate_line(shape: Shape, rate: float, latencies: np.ndarray, missing: int, backlog: float, ok: bool,
              cpu: dict[str, float]) -> str:
    """One sustained-rate run: lost steps, backlog, latency, and where the CPU went (ms per step per process)."""
    p50, p99 = (np.percentile(latencies, q) if len(latencies) else float("nan") for q in (50, 99))
    where = ", ".join(f"{name} {ms:.2f}" for name, ms in sorted(cpu.items()))
    return (f"  {shape.name}: {rate:6.0f} steps/s -> missing {missing}, backlog {backlog:.3f} s, p50 {p50:.2f} ms, "
            f"p99 {p99:.2f} ms {'ok' if ok else 'NOT sustained'}; CPU ms/step: {where}, total "
            f"{sum(cpu.values()):.2f}")


def bench_shape(shape: Shape, steps: int, rates: list[float], view: bool = False,
                profile: Path | None = None, compose: bool = False) -> dict[str, Any]:
    """Start-up, latency at 10 Hz, the highest sustained rate and the nodes' peak memory for one shape (``view``:
    with ``fiper view`` running beside the suite, no client connected; ``profile``: the suite's nodes and the
    driver's timed runs profiled into that folder; ``compose``: RND-OE and the fusion node in one process)."""
    with tempfile.TemporaryDirectory() as tmp, allocate_domain() as domain:
        work = Path(tmp)
        config = _suite_config(shaped_calibration(shape, work / "calibration"), work, compose)
        startup = bench_startup(shape, config, domain)
        driver = PolicyStepDriver(shape, domain)
        plain = plain_discovery(driver, domain, PLAIN_STARTS)
        env = local_env(domain) | ({PROFILE_ENV: str(profile / shape.name)} if profile else {})
        fqns = [fqn for spec in load_launch(config).nodes for fqn in spec_fqns(spec)]
        suite_s: list[float] = []
        suite_own_s: list[float] = []
        for start in range(SUITE_STARTS):  # the last start's suite stays up for the latency runs
            output = work / f"suite.{start}.log"
            started = time.monotonic()
            launch = _start([sys.executable, "-m", "fiper_ros.cli", "launch", str(config)], domain, env, output)
            try:
                suite_s.append(driver.wait_ready(fqns) - started)
            except BaseException:
                _stop(launch)
                lines = output.read_text(errors="replace").splitlines()[-FAILED_OUTPUT_LINES:]
                print(f"the suite's last {len(lines)} lines of output:", *lines, sep="\n", file=sys.stderr)
                raise
            suite_own_s.append(max(own_active_s(output).values(), default=float("nan")))
            if start < SUITE_STARTS - 1:
                _stop(launch)
        viewer = _start([sys.executable, "-m", "fiper_ros.cli", "view", "--port", "0"], domain) if view else None
        driver_profile = cProfile.Profile(time.thread_time)
        try:
            pids = node_pids(launch.pid) | {"driver": os.getpid()}
            driver.spin_for(1.0)
            driver.run(1, 20, 10.0)  # warm-up
            if profile:
                driver_profile.enable()
            lat, missing, _ = driver.run(2, steps, 10.0)
            result: dict[str, Any] = {"p50_ms": float(np.percentile(lat, 50)), "p99_ms": float(np.percentile(lat, 99)),
                                      "missing_at_10hz": float(missing), "sustained_hz": 0.0, "startup": startup,
                                      "suite_s": suite_s, "suite_own_s": suite_own_s, "plain_s": plain}
            for i, rate in enumerate(rates):
                counted = driver.fresh_counters()
                lat_r, missing_r, backlog, cpu = rate_run(driver, pids, 10 + i, rate)
                ok = missing_r == 0 and backlog < 0.5
                print(rate_line(shape, rate, lat_r, missing_r, backlog, ok, cpu), flush=True)
                if not ok:
                    print(f"  {shape.name}: {rate:6.0f} steps/s, where the steps went: "
                          f"{where_lost(counted, driver.fresh_counters(), steps_at(rate))}", flush=True)
                    break
                result["sustained_hz"] = rate
            driver_profile.disable()
            result["peaks_mb"] = node_peaks(launch.pid)
            return result
        finally:
            driver.close()
            _stop(launch)
            if viewer is not None:
                _stop(viewer)
            if profile:
                driver_profile.dump_stats(profile / shape.name / "driver.prof")


def ratio(value: float, target: float, unit: str, most: bool = True) -> str:
    """``value`` as a ratio to its ``target`` (``most``: the target is an upper bound, else a lower one)."""
    return f"(target {'<=' if most else '>='} {target:g} {unit}: {value / target:.2f}x)"


def seconds(values: Sequence[float]) -> str:
    """Start-up figures in seconds, in the order measured."""
    return " / ".join(f"{value:.2f}" for value in values)


def startup_lines(shape: Shape, result: dict[str, Any]) -> list[str]:
    """The start-up and memory figures of one shape, each with its ratio to the target (on the median start) where
    there is one."""
    lines = []
    for name, starts in result["startup"].items():
        own = [start.own_s for start in starts]
        median, peak = float(np.median(own)), max(start.peak_mb for start in starts)
        target = f" {ratio(median, TARGET_NODE_S, 's')}" if "fusion" not in name else ""
        lines.append(f"{shape.name}: {name} alone, {len(starts)} starts: ACTIVE {seconds(own)} s after exec by its own "
                     f"log (median {median:.2f} s{target}); seen ACTIVE by the driver (discovery included) "
                     f"{seconds([start.seen_s for start in starts])} s; peak RSS "
                     f"{peak:.0f} MB {ratio(peak, TARGET_RSS_MB, 'MB')}")
    suite = result["suite_s"]
    suite_median = float(np.median(suite))
    lines.append(f"{shape.name}: suite, {len(suite)} starts: all three ACTIVE and wired {seconds(suite)} s after "
                 f"exec of fiper launch (median {suite_median:.2f} s {ratio(suite_median, TARGET_SUITE_S, 's')}); the "
                 f"last node ACTIVE by its own log {seconds(result['suite_own_s'])} s after its exec")
    lines.append(f"{shape.name}: reference, DDS discovery without our code: a plain rclpy node's publisher seen by "
                 f"the driver {seconds(result['plain_s'])} s after the node's creation")
    peaks = ", ".join(f"{name} {mb:.0f} MB" for name, mb in sorted(result["peaks_mb"].items()))
    worst = max(result["peaks_mb"].values())
    lines.append(f"{shape.name}: peak RSS in the suite after the runs: {peaks}; the largest "
                 f"{ratio(worst, TARGET_RSS_MB, 'MB')}")
    return lines


def bench_floor(shape: Shape, steps: int) -> dict[str, Any]:
    """The platform's floor at ``shape``: the driver's runs through the suite's topology with no work
    (:mod:`fiper_ros.bench.null_suite`): the latency at 10 Hz, and at the shape's target rate the lost steps, the
    backlog and the CPU per step of each process."""
    with allocate_domain() as domain:
        driver = PolicyStepDriver(shape, domain)
        procs = {f"{role} stand-in": _start([sys.executable, "-m", null_suite.__name__, role], domain)
                 for role in null_suite.ROLES}
        try:
            driver.wait_wired("the null suite")
            driver.spin_for(1.0)
            driver.run(1, 20, 10.0)  # warm-up, as the suite's
            lat, missing, _ = driver.run(2, steps, 10.0)
            pids = {name: proc.pid for name, proc in procs.items()} | {"driver": os.getpid()}
            _, missing_r, backlog, cpu = rate_run(driver, pids, 3, shape.target_rate)
            return {"p50_ms": float(np.percentile(lat, 50)), "p99_ms": float(np.percentile(lat, 99)),
                    "missing_at_10hz": missing, "missing_at_rate": missing_r, "backlog_s": backlog, "cpu": cpu}
        finally:
            driver.close()
            for proc in procs.values():
                _stop(proc)


def floor_line(shape: Shape, floor: dict[str, Any], suite: dict[str, Any]) -> str:
    """The platform's floor at ``shape`` (:func:`bench_floor`), and the suite's 10 Hz p99 as a multiple of it."""
    where = ", ".join(f"{name} {ms:.2f}" for name, ms in sorted(floor["cpu"].items()))
    return (f"{shape.name}: platform floor (the suite's topology, no work; fiper_ros.bench.null_suite): latency at "
            f"10 Hz p50 {floor['p50_ms']:.2f} ms, p99 {floor['p99_ms']:.2f} ms, missing {floor['missing_at_10hz']}; "
            f"at {shape.target_rate:.0f} steps/s missing {floor['missing_at_rate']}, backlog {floor['backlog_s']:.3f} s, "
            f"CPU ms/step: {where}, total {sum(floor['cpu'].values()):.2f}; the suite's 10 Hz p50 / p99 are "
            f"{suite['p50_ms'] / floor['p50_ms']:.2f}x / {suite['p99_ms'] / floor['p99_ms']:.2f}x the floor's")


def latency_line(shape: Shape, result: dict[str, Any]) -> str:
    """The 10 Hz latency and the sustained rate of one shape, with their ratios to the targets."""
    return (f"{shape.name} (E {shape.embedding_dim}, B {shape.batch}, H {shape.horizon}, D {shape.action_dim}): "
            f"latency at 10 Hz p50 {result['p50_ms']:.2f} ms, p99 {result['p99_ms']:.2f} ms "
            f"{ratio(result['p99_ms'], TARGET_P99_MS, 'ms')}, missing {int(result['missing_at_10hz'])}; sustained "
            f"{result['sustained_hz']:.0f} steps/s "
            f"{ratio(result['sustained_hz'], shape.target_rate, 'steps/s', most=False)}")


def load_average() -> str:
    """The 1, 5 and 15 minute load averages."""
    return " ".join(f"{load:.2f}" for load in os.getloadavg())


def main() -> int:
    """Print the figures of every shape and the ratios to the targets."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--steps", type=int, default=300, help="steps of the 10 Hz latency run")
    parser.add_argument("--rates", type=float, nargs="+", default=[100, 200, 300, 400, 600, 800, 1000, 1200, 1500])
    parser.add_argument("--view", action="store_true", help="with fiper view beside the suite (no client connected)")
    parser.add_argument("--default-dds", action="store_true",
                        help="the driver on Fast DDS's defaults, not the suite's discovery profile (as a supervisor "
                             "that does not set FASTRTPS_DEFAULT_PROFILES_FILE; the nodes use it either way)")
    parser.add_argument("--compose", action="store_true",
                        help="RND-OE and the fusion node in one process (fiper.launch.yaml compose:=true)")
    parser.add_argument("--no-floor", action="store_true",
                        help="skip the platform's floor (the suite's topology with no work) after each shape")
    parser.add_argument("--profile", type=Path, metavar="DIR",
                        help="profile the suite's nodes (their main thread's CPU time) and the driver's timed runs "
                             "into DIR/<shape>/<node>.prof (python -m pstats); the figures are then not comparable")
    args = parser.parse_args()
    dds_profile = None if args.default_dds else use_discovery_profile()  # before the driver's rclpy.init
    layout = "RND-OE and fusion composed in one process, ACE in its own" if args.compose else "separate processes"
    print(f"machine: {os.cpu_count()} cores; nodes as {layout}; loopback DDS; {args.steps} steps at 10 Hz; "
          f"{'with' if args.view else 'without'} the live view; executor of the nodes and the driver: "
          f"{os.environ.get(EXECUTOR_ENV) or 'default'}; the driver's DDS profile: {dds_profile or 'Fast DDS defaults'}; "
          f"load average {load_average()}")
    print(clean_stale().summary(), flush=True)
    for shape in SHAPES:
        if args.profile:
            (args.profile / shape.name).mkdir(parents=True, exist_ok=True)
        r = bench_shape(shape, args.steps, args.rates, args.view, args.profile, args.compose)
        for line in [*startup_lines(shape, r), latency_line(shape, r)]:
            print(line, flush=True)
        if not args.no_floor:
            print(floor_line(shape, bench_floor(shape, args.steps), r), flush=True)
    print(f"load average at the end {load_average()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
