"""``fiper demo`` (``make demo``): the whole suite live on the shipped Sorting model, as separate processes.

The demo starts ``fiper launch`` on ``config/demo.yaml`` (sim bridge, policy node, RND-OE, ACE, fusion and
the example supervisor, each its own OS process) in a ROS domain of its own, then drives it like an
operator would from this process: it waits until every node is active, resets the bridge into one
in-distribution and one harmful out-of-distribution rollout, prints a progress line per policy step and
each alarm (both windowed scores against their thresholds), and records everything it sees (suite
topics and both cameras) into one MCAP bag. Afterwards it writes a PNG per rollout and ``summary.json``.
The exit status is 1 if any part failed: a node died or never became active, a rollout did not end,
a score stream stayed silent, or the monitor reported UNKNOWN.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, replace
from datetime import datetime, timezone
from pathlib import Path

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from fiper_msgs.msg import ActionChunkBatch, FailureAlarm, RolloutEvent, Score
from fiper_msgs.srv import ResetRollout
from fiper_ros.bags.errors import BagError
from fiper_ros.bags.record import Recorder
from fiper_ros.bags.schema import ACTIONS, ALARM, EVENTS, SCORE_ACE, SCORE_RND_OE, TOPICS
from fiper_ros.bags.session import RosSession
from fiper_ros.bags.suite_process import SuiteProcess
from fiper_ros.dds import allocate_domain
from fiper_ros.demo.figure import plot_trace
from fiper_ros.demo.trace import ACE, RND_OE, RolloutTrace
from fiper_ros.launch import LaunchError, dump_config, load_config
from fiper_ros.nodes import qos

#: Nodes that must report ``lifecycle_state: active`` on /diagnostics before the first reset.
MANAGED_NODES = ("/sim/bridge_node", "/fiper/policy_node", "/fiper/rnd_oe_node", "/fiper/ace_node",
                 "/fiper/fusion_node")
#: The supervisor is a plain node: it must be visible in the graph.
SUPERVISOR = ("supervisor_node", "/fiper")
#: Recorded besides the bag schema's topics.
EXTRA_TOPICS = ("/camera/wrist/image_raw", "/camera/third/image_raw", "/sim/proprio", "/sim/action", "/clock")
#: Deep history for what the driver displays (the contract's KEEP_LAST(1) would skip steps here).
DISPLAY_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=200, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
STATE_NAMES = {FailureAlarm.STATE_OK: "OK", FailureAlarm.STATE_ALARM: "ALARM", FailureAlarm.STATE_UNKNOWN: "UNKNOWN"}
OUTCOMES = {RolloutEvent.OUTCOME_SUCCESS: "success", RolloutEvent.OUTCOME_FAILURE: "failure"}
#: Without a terminal, one progress line every this many policy steps (a terminal gets every step).
PROGRESS_EVERY = 5
#: Seconds to wait for the last scores of a rollout after its END.
SETTLE_S = 2.0


class DemoFailed(RuntimeError):
    """A part of the suite did not do its job."""


@dataclass(frozen=True)
class Plan:
    """One rollout the demo runs."""

    label: str
    scenario: str
    seed: int


class Driver:
    """The operator: readiness, resets, live display and recording, in one rclpy session."""

    def __init__(self, session: RosSession, bag: Path, task: str, tty: bool) -> None:
        self.session = session
        self.task = task
        self.tty = tty
        node = session.node
        assert node is not None
        self.node = node
        self.recorder = Recorder(session, bag, (*TOPICS, *EXTRA_TOPICS), overwrite=False, source="fiper demo")
        self.states: dict[str, str] = {}
        self.traces: dict[int, RolloutTrace] = {}
        self._reset = node.create_client(ResetRollout, "/sim/reset")
        node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, qos.DIAGNOSTICS)
        node.create_subscription(Score, SCORE_RND_OE, self._on_score, DISPLAY_QOS)
        node.create_subscription(Score, SCORE_ACE, self._on_score, DISPLAY_QOS)
        node.create_subscription(FailureAlarm, ALARM, self._on_alarm, DISPLAY_QOS)
        node.create_subscription(RolloutEvent, EVENTS, self._on_event, qos.EVENT)
        node.create_subscription(ActionChunkBatch, ACTIONS, self._on_actions, qos.INPUT)

    # callbacks ----------------------------------------------------------------------------------------
    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            values = {v.key: v.value for v in status.values}
            if "lifecycle_state" in values:
                self.states[status.hardware_id] = values["lifecycle_state"]

    def _on_score(self, msg: Score) -> None:
        trace = self.traces.get(msg.rollout_id)
        if trace is not None and msg.detector in trace.scores:
            trace.scores[msg.detector].add(msg.step, msg.windowed_score, msg.threshold, msg.exceeded)

    def _on_actions(self, msg: ActionChunkBatch) -> None:
        trace = self.traces.get(msg.rollout_id)
        if trace is not None:
            trace.steps_started = max(trace.steps_started, msg.step + 1)

    def _on_event(self, msg: RolloutEvent) -> None:
        trace = self.traces.get(msg.rollout_id)
        if trace is not None and msg.event == RolloutEvent.EVENT_END:
            trace.outcome = OUTCOMES.get(msg.outcome, "unknown")

    def _on_alarm(self, msg: FailureAlarm) -> None:
        trace = self.traces.get(msg.rollout_id)
        if trace is None or msg.heartbeat:
            return
        state = STATE_NAMES.get(msg.state, "UNKNOWN")
        line = (f"step {msg.step:3d} | RND-OE {msg.eta_obs:8.3f} / {msg.gamma_obs:8.3f} "
                f"{'>' if msg.obs_exceeded else ' '} | ACE {msg.eta_act:8.3f} / {msg.gamma_act:8.3f} "
                f"{'>' if msg.act_exceeded else ' '} | {state}")
        if state == "UNKNOWN":
            trace.unknown_steps.add(msg.step)
            self._say(f"  UNKNOWN at step {msg.step}: {msg.reason}")
        elif state == "ALARM" and trace.alarm_step is None:
            trace.alarm_step = msg.step
            trace.alarm_text = line
            self._say(f"  ALARM  {line}")
        elif self.tty:
            print(f"\r  {line}", end="", flush=True)
        elif msg.step % PROGRESS_EVERY == 0:
            print(f"  {line}", flush=True)

    def _say(self, line: str) -> None:
        print(("\r" if self.tty else "") + line + " " * 8, flush=True)

    # driving ------------------------------------------------------------------------------------------
    def spin(self, seconds: float, suite: SuiteProcess) -> None:
        """Spin (and record) for ``seconds``, failing if the suite died."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self._check(suite)
            self.session.spin_once(0.02)

    def _check(self, suite: SuiteProcess) -> None:
        self.recorder.poll()
        if not suite.alive():
            raise DemoFailed("the suite's launcher exited (a required node died); its last output:\n"
                             + suite.output())
        if self.session.stop.is_set():
            raise KeyboardInterrupt

    def wait_ready(self, suite: SuiteProcess, timeout_s: float) -> None:
        """Until every managed node is active, the supervisor runs and the bridge's reset is served."""
        deadline = time.monotonic() + timeout_s

        def missing() -> list[str]:
            names = set(self.node.get_node_names_and_namespaces())
            waiting = [n for n in MANAGED_NODES if self.states.get(n) != "active"]
            waiting += ["/fiper/supervisor_node"] if SUPERVISOR not in names else []
            waiting += ["/sim/reset service"] if not self._reset.service_is_ready() else []
            return waiting

        while missing():
            if time.monotonic() > deadline:
                states = ", ".join(f"{n}: {self.states.get(n, 'no diagnostics')}" for n in MANAGED_NODES)
                raise DemoFailed(f"not ready after {timeout_s:g} s, waiting for {', '.join(missing())} ({states})")
            self.spin(0.1, suite)
        self.spin(1.0, suite)  # discovery of the policy node's subscriptions by the bridge

    def run_rollout(self, plan: Plan, suite: SuiteProcess, timeout_s: float) -> RolloutTrace:
        """Reset the bridge into ``plan`` and follow the rollout to its end."""
        request = ResetRollout.Request(task=self.task, scenario=plan.scenario, seed=plan.seed)
        future = self._reset.call_async(request)
        deadline = time.monotonic() + 30.0
        while not future.done():
            if time.monotonic() > deadline:
                raise DemoFailed("/sim/reset did not answer within 30 s")
            self.spin(0.02, suite)
        response = future.result()
        if response is None or not response.success:
            raise DemoFailed(f"/sim/reset refused {plan}: {response.message if response else 'no response'}")
        trace = RolloutTrace(plan.label, plan.scenario, plan.seed, rollout_id=response.rollout_id)
        self.traces[response.rollout_id] = trace
        self._say(f"rollout {response.rollout_id}: {self.task}/{plan.scenario} seed {plan.seed} ({plan.label}), "
                  f"at most {response.max_steps} policy steps")
        deadline = time.monotonic() + timeout_s
        last_progress, progress_at = -1, time.monotonic()
        while not trace.ended:
            if trace.steps_started != last_progress:
                last_progress, progress_at = trace.steps_started, time.monotonic()
            if time.monotonic() > deadline:
                raise DemoFailed(f"rollout {response.rollout_id} did not end within {timeout_s:g} s "
                                 f"({trace.steps_started} policy steps)")
            if time.monotonic() - progress_at > 30.0:
                raise DemoFailed(f"rollout {response.rollout_id}: no action-chunk batch for 30 s after step "
                                 f"{trace.steps_started} (is the policy node running?)")
            self.spin(0.05, suite)
        settle = time.monotonic() + SETTLE_S
        while trace.scored_steps() < trace.steps_started and time.monotonic() < settle:
            self.spin(0.05, suite)
        self._say(f"  ended: {trace.outcome} after {trace.steps_started} policy steps; {trace.verdict()}")
        return trace


def problems_of(trace: RolloutTrace) -> list[str]:
    """What went wrong in the suite during ``trace`` (empty: every part did its job)."""
    problems = []
    for name in (RND_OE, ACE):
        if not trace.scores[name].windowed:
            problems.append(f"no {name} score for rollout {trace.rollout_id}")
    if trace.scored_steps() < trace.steps_started:
        problems.append(f"rollout {trace.rollout_id}: {trace.steps_started} policy steps, only "
                        f"{trace.scored_steps()} scored by both detectors")
    if trace.unknown_steps:
        problems.append(f"rollout {trace.rollout_id}: the monitor said UNKNOWN at steps {sorted(trace.unknown_steps)}")
    return problems


def demo_config(source: Path, model: Path, calibration: Path, out: Path) -> Path:
    """``source`` with the model and calibration paths made absolute, written to ``out``."""
    config = load_config(source)
    paths = {"model": str(model), "calibration_dir": str(calibration)}
    nodes = tuple(replace(spec, parameters=spec.parameters | {k: v for k, v in paths.items() if k in spec.parameters})
                  for spec in config.nodes)
    return dump_config(replace(config, nodes=nodes), out)


def installed_config() -> Path:
    """The installed ``fiper_ros/config/demo.yaml``."""
    from ament_index_python.packages import get_package_share_directory  # noqa: PLC0415

    return Path(get_package_share_directory("fiper_ros")) / "config" / "demo.yaml"


def run_demo(args: argparse.Namespace) -> int:
    """Run the demo; returns the exit status."""
    model, calibration = args.model.resolve(), (args.calibration or args.model / "calibration").resolve()
    for path, what in ((model / "policy.yaml", "policy"), (calibration / "calibration.yaml", "calibration")):
        if not path.is_file():
            print(f"fiper demo: no {what} at {path.parent} (see docs/policies.md and docs/results.md)", file=sys.stderr)
            return 2
    out = (args.out or Path("runs/demo") / datetime.now(timezone.utc).strftime("%Y%m%d-%H%M%S")).resolve()
    out.mkdir(parents=True, exist_ok=True)
    plans = [Plan("in-distribution", "id", args.id_seed), Plan("harmful OOD", args.ood_scenario, args.ood_seed)]
    started = time.monotonic()
    config = demo_config(args.config or installed_config(), model, calibration, out / "launch.yaml")
    traces: list[RolloutTrace] = []
    problems: list[str] = []
    with allocate_domain() as domain:
        print(f"fiper demo: ROS domain {domain} (loopback only), output {out}", flush=True)
        suite = SuiteProcess(config, domain, echo=args.verbose, log=out / "suite.log")
        try:
            with RosSession("fiper_demo", domain) as session:
                driver = Driver(session, out / "bag", args.task, sys.stdout.isatty())
                try:
                    print("starting bridge, policy, RND-OE, ACE, fusion and supervisor nodes ...", flush=True)
                    driver.wait_ready(suite, args.ready_timeout)
                    print(f"all nodes active after {time.monotonic() - started:.1f} s", flush=True)
                    for plan in plans:
                        traces.append(driver.run_rollout(plan, suite, args.rollout_timeout))
                except DemoFailed as error:
                    problems.append(str(error))
                finally:
                    count = driver.recorder.close()
                    print(f"bag {out / 'bag'}: {count} messages", flush=True)
        finally:
            status = suite.stop()
    if status != 0:
        problems.append(f"a node exited on its own (launcher status {status}); see {out / 'suite.log'}")
    for trace in traces:
        problems += problems_of(trace)
        png = plot_trace(trace, out / f"rollout_{trace.scenario}_{trace.seed}.png", args.task)
        print(f"  {png}", flush=True)
    summary = {"task": args.task, "model": str(model), "calibration": str(calibration), "seconds":
               round(time.monotonic() - started, 1), "rollouts": [t.to_dict() for t in traces], "problems": problems}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    for trace in traces:
        print(f"{trace.label:>16}: {trace.scenario} seed {trace.seed}: {trace.outcome or 'no end'}, "
              f"{trace.steps_started} policy steps; {trace.verdict()}")
    print(f"demo took {summary['seconds']} s; results in {out}")
    for problem in problems:
        print(f"fiper demo: FAILED: {problem}", file=sys.stderr)
    return 1 if problems else 0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``fiper demo``."""
    parser.add_argument("--task", default="sorting", help="sim task (the model's)")
    parser.add_argument("--model", type=Path, default=Path("models/sorting"), help="policy folder")
    parser.add_argument("--calibration", type=Path, help="calibration folder (default MODEL/calibration)")
    parser.add_argument("--config", type=Path, help="launch YAML (default: the installed config/demo.yaml)")
    parser.add_argument("--out", type=Path, help="output folder (default runs/demo/<UTC time>)")
    parser.add_argument("--id-seed", type=int, default=1002, help="seed of the in-distribution rollout")
    parser.add_argument("--ood-scenario", default="box_pos", help="harmful OOD scenario of the second rollout")
    parser.add_argument("--ood-seed", type=int, default=1000, help="seed of the OOD rollout")
    parser.add_argument("--ready-timeout", type=float, default=90.0, help="seconds for every node to become active")
    parser.add_argument("--rollout-timeout", type=float, default=120.0, help="seconds one rollout may take")
    parser.add_argument("-v", "--verbose", action="store_true", help="show the nodes' output")


def run(args: argparse.Namespace) -> int:
    """``fiper demo``."""
    try:
        return run_demo(args)
    except (LaunchError, BagError) as error:
        print(f"fiper demo: {error}", file=sys.stderr)
        return 2

