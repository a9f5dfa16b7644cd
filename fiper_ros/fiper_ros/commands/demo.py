"""``fiper demo`` (``make demo``): the whole suite live on the shipped Sorting model, as separate processes.

The demo removes the Fast DDS shared-memory files of dead processes (:mod:`fiper_ros.platform.shm`), starts
``fiper launch`` on ``launch/demo.launch.yaml`` (sim bridge, policy node, RND-OE, ACE, fusion and
the example supervisor, each its own OS process) in a ROS domain of its own, then drives it like an
operator would from this process: it waits until every node is active, resets the bridge into one
in-distribution and one harmful out-of-distribution rollout, prints a progress line per policy step and
each alarm (the windowed scores against their thresholds), and records everything it sees (suite
topics and both cameras) into one MCAP bag. Unless ``--no-view``, the suite includes the live view
(``view_node``, docs/view.md): the demo prints its address and the Foxglove layout to import; a view port that
is taken only turns the view off, with a line that says so. Afterwards it writes a PNG per rollout and ``summary.json``.
The exit status is 1 if any part failed: a node died or never became active, a rollout did not end,
a score stream stayed silent, or the monitor reported UNKNOWN.

The suite runs the detectors the calibration declares (:mod:`fiper_ros.core.detectors`): with an
observation-only calibration (``fiper calibrate --detectors rnd_oe``) there is no ACE node, the fusion node
judges with RND-OE alone, and the progress lines, figures and summary show RND-OE alone and say so.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from fiper_msgs.msg import FailureAlarm
from fiper_ros.bagio.atomic import remove
from fiper_ros.client.driver import SETTLE_S, AlarmDisplay, SimSuiteDriver, SuiteFailed, alarm_line
from fiper_ros.client.figure import plot_trace
from fiper_ros.client.record import Recorder
from fiper_ros.client.ros_session import RosSession
from fiper_ros.client.suite_process import SuiteProcess, declared_of, installed_launch, suite_arguments, suite_topics
from fiper_ros.client.trace import RolloutTrace
from fiper_ros.commands import options
from fiper_ros.commands.errors import UsageError
from fiper_ros.core.detectors import judged_by
from fiper_ros.data_paths import SEARCH_RULE, data_path_argument
from fiper_ros.errors import FiperError
from fiper_ros.interface.messages import AlarmStateName
from fiper_ros.interface.topics import (ACTIONS_TOPIC, CAMERA_THIRD_TOPIC, CAMERA_WRIST_TOPIC, CLOCK_TOPIC,
                                        EMBEDDING_TOPIC, SIM_ACTION_TOPIC, SIM_PROPRIO_TOPIC)
from fiper_ros.launcher.config import LaunchConfig, dump_launch, load_launch
from fiper_ros.platform.dds import allocate_domain
from fiper_ros.platform.shm import clean_stale

#: The supervisor is a plain node: it must be visible in the graph (every other node of the demo is a lifecycle
#: node that must report ``lifecycle_state: active`` on /diagnostics before the first reset).
SUPERVISOR = "/fiper/supervisor_node"
#: The live view (``--no-view`` leaves it out) is a plain node too.
VIEW = "/fiper/view_node"
PLAIN = (SUPERVISOR, VIEW)
#: The demo's own node, the operator's (in the root namespace; its SROS2 enclave, docs/security.md).
NODE_NAME = "fiper_demo"
#: Seconds spun once the bag seems to hold every step, for a last message still on its way to the driver's readers.
IN_FLIGHT_S = 0.5
#: Recorded besides the bag schema's topics.
EXTRA_TOPICS = (CAMERA_WRIST_TOPIC, CAMERA_THIRD_TOPIC, SIM_PROPRIO_TOPIC, SIM_ACTION_TOPIC, CLOCK_TOPIC)
#: Without a terminal, one progress line every this many policy steps (a terminal gets every step).
PROGRESS_EVERY = 5


@dataclass(frozen=True)
class Plan:
    """One rollout the demo runs."""

    label: str
    scenario: str
    seed: int


class Display:
    """The demo's live output: a progress line per policy step (on a terminal, rewritten in place) and
    every alarm and UNKNOWN on a line of its own."""

    def __init__(self, tty: bool) -> None:
        self.tty = tty

    def say(self, line: str) -> None:
        """Print ``line`` on a line of its own."""
        print(("\r" if self.tty else "") + line + " " * 8, flush=True)

    def alarm(self, trace: RolloutTrace, msg: FailureAlarm) -> None:
        """Show one alarm decision of ``trace``'s rollout."""
        state, line = AlarmStateName.of_code(msg.state), alarm_line(msg)
        if state == AlarmStateName.UNKNOWN:
            self.say(f"  UNKNOWN at step {msg.step}: {msg.reason}")
        elif state == AlarmStateName.ALARM and trace.alarm_step == msg.step:
            self.say(f"  ALARM  {line}\n         why: {msg.reason}")
        elif self.tty:
            print(f"\r  {line}", end="", flush=True)
        elif msg.step % PROGRESS_EVERY == 0:
            print(f"  {line}", flush=True)


def operator(session: RosSession, suite: SuiteProcess, task: str, detectors: tuple[str, ...],
             display: AlarmDisplay | None = None) -> tuple[Recorder, SimSuiteDriver]:
    """The demo's side of ``session`` for a suite of ``detectors``: a recorder of its topics, both cameras,
    ``/sim/*`` and ``/clock``, and the driver."""
    recorder = Recorder(session, (*suite_topics(detectors), *EXTRA_TOPICS), source="fiper demo")
    return recorder, SimSuiteDriver(session, suite, task, detectors, recorder=recorder, display=display)


def run_rollout(driver: SimSuiteDriver, display: Display, plan: Plan, timeout_s: float) -> RolloutTrace:
    """Reset the bridge into ``plan``, follow the rollout to its end and wait for its last scores."""
    trace = driver.reset(plan.scenario, plan.seed, plan.label)
    display.say(f"rollout {trace.rollout_id}: {driver.task}/{plan.scenario} seed {plan.seed} ({plan.label}), "
                f"at most {trace.max_steps} policy steps")
    driver.follow(trace, timeout_s)
    driver.settle(lambda: trace.scored_steps() >= trace.steps_started, SETTLE_S)
    display.say(f"  ended: {trace.outcome} after {trace.steps_started} policy steps; {trace.verdict()}")
    return trace


def recorded_every_step(counts: Mapping[str, int], traces: Sequence[RolloutTrace]) -> bool:
    """Whether a bag that got ``counts`` messages per topic holds an embedding and an action batch of each policy
    step the driver saw in ``traces`` (their ``steps_started``)."""
    steps = sum(trace.steps_started for trace in traces)
    return counts.get(EMBEDDING_TOPIC, 0) >= steps and counts.get(ACTIONS_TOPIC, 0) >= steps


def problems_of(trace: RolloutTrace) -> list[str]:
    """What went wrong in the suite during ``trace`` (empty: every part did its job)."""
    problems = []
    for name in trace.detectors:
        if not trace.scores[name].windowed:
            problems.append(f"no {name} score for rollout {trace.rollout_id}")
    if trace.scored_steps() < trace.steps_started:
        problems.append(f"rollout {trace.rollout_id}: {trace.steps_started} policy steps, only "
                        f"{trace.scored_steps()} scored by {' and '.join(trace.detectors)}")
    if trace.unknown_steps:
        problems.append(f"rollout {trace.rollout_id}: the monitor said UNKNOWN at steps {sorted(trace.unknown_steps)}")
    return problems


def demo_config(source: Path, model: Path, calibration: Path, detectors: tuple[str, ...],
                view: dict[str, str] | None = None) -> LaunchConfig:
    """The launch file ``source`` read with ``model:=`` and the calibration's arguments (``calibration_dir:=``, and
    ``observation_only:=true`` for one that declares RND-OE alone: no ACE node; ``detectors``: those it declares),
    and ``view``'s (:func:`~fiper_ros.commands.options.view_arguments`: the live view)."""
    return load_launch(source, {"model": str(model), **suite_arguments(calibration, detectors), **(view or {})})


def managed_nodes(config: LaunchConfig) -> list[str]:
    """The nodes of ``config`` (``/ns/name``) that must report ``active``: all but the plain ones (:data:`PLAIN`)."""
    return [path for spec in config.nodes if (path := spec.fqn) not in PLAIN]


def plain_nodes(config: LaunchConfig) -> list[str]:
    """The plain nodes of ``config`` (``/ns/name``), which only have to be in the graph."""
    return [path for spec in config.nodes if (path := spec.fqn) in PLAIN]


def check_calibration(model: Path, calibration: Path) -> None:
    """Refuse in one line naming the file a model whose ``policy.yaml`` holds no configuration (:class:`PolicyError`)
    and a calibration that does not load or does not fit the model's policy (:class:`EvaluationError`), instead of
    scoring nodes that never configure. Imported here: it needs torch."""
    from fiper_ros.evaluation.offline import calibration_for, policy_layout  # noqa: PLC0415
    from fiper_ros.policy.config import PolicyConfig  # noqa: PLC0415

    config = PolicyConfig.read(model / "policy.yaml")
    calibration_for(calibration, [policy_layout(config, model)])


def run_demo(args: argparse.Namespace) -> int:
    """Run the demo; returns the exit status."""
    model, calibration = args.model.resolve(), (args.calibration or args.model / "calibration").resolve()
    if not (model / "policy.yaml").is_file():
        print(f"fiper demo: no policy at {model} (see docs/policies.md and docs/results.md)", file=sys.stderr)
        return 2
    declared = declared_of(calibration)  # one line for a calibration that declares none (or is not there)
    detectors, judged = declared.detectors, judged_by(declared.detectors, declared.combine)
    out = (args.out or Path("runs/demo") / datetime.now(timezone.utc).strftime("%Y%m%d-%H%M%S")).resolve()
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    plans = [Plan("in-distribution", "id", args.id_seed), Plan("harmful OOD", args.ood_scenario, args.ood_seed)]
    started = time.monotonic()
    try:
        view = options.view_arguments(args)
    except UsageError as error:  # the demo's main job goes on without it
        print(f"fiper demo: the live view is off: {error}", flush=True)
        view = {}
    config = demo_config(args.config or installed_launch("demo.launch.yaml"), model, calibration, detectors, view)
    launch = dump_launch(config, out / "launch.yaml")  # as it runs: every value literal
    traces: list[RolloutTrace] = []
    problems: list[str] = []
    print(f"fiper demo: {clean_stale().summary()}", flush=True)
    with allocate_domain() as domain:
        print(f"fiper demo: ROS domain {domain} (loopback only), output {out}", flush=True)
        if view:
            print(f"fiper demo: {options.view_banner(args.view_port)}", flush=True)
        suite = SuiteProcess(launch, domain, echo=args.verbose, log=out / "suite.log")
        try:
            check_calibration(model, calibration)  # while the nodes boot
        except FiperError:
            suite.stop()
            if created:
                remove(out)  # a refused demo leaves no run folder
            raise
        try:
            with RosSession(NODE_NAME, domain) as session:
                display = Display(sys.stdout.isatty())
                recorder, driver = operator(session, suite, args.task, detectors, display.alarm)
                recorder.start(out / "bag")
                try:
                    print(f"starting {', '.join(spec.name for spec in config.nodes)}; judged by "
                          f"{judged} ...", flush=True)
                    driver.wait_ready(managed_nodes(config), args.ready_timeout, plain=plain_nodes(config))
                    print(f"all nodes active after {time.monotonic() - started:.1f} s", flush=True)
                    for plan in plans:
                        traces.append(run_rollout(driver, display, plan, args.rollout_timeout))
                    # the last step's messages into the bag: the recorder's readers are not the driver's, so either
                    # may still have them in flight when the other has them
                    def landed() -> bool:
                        return recorded_every_step(recorder.counts, traces)
                    driver.settle(landed, SETTLE_S)
                    driver.spin(IN_FLIGHT_S)
                    if not driver.settle(landed, SETTLE_S):
                        problems.append(f"the bag got {recorder.counts[EMBEDDING_TOPIC]} embeddings and "
                                        f"{recorder.counts[ACTIONS_TOPIC]} action batches of "
                                        f"{sum(t.steps_started for t in traces)} policy steps")
                except SuiteFailed as error:
                    problems.append(f"{error}; its last output:\n{error.output}" if error.output else str(error))
                finally:
                    count = recorder.finish()
                    print(f"bag {out / 'bag'}: {count} messages", flush=True)
        finally:
            status = suite.stop()
    if status != 0:
        problems.append(f"a node exited on its own (launcher status {status}); see {out / 'suite.log'}")
    for trace in traces:
        problems += problems_of(trace)
        png = plot_trace(trace, out / f"rollout_{trace.scenario}_{trace.seed}.png", args.task)
        print(f"  {png}", flush=True)
    summary = {"task": args.task, "model": str(model), "calibration": str(calibration), "detectors": list(detectors),
               "combine": declared.combine,
               "judged_by": judged, "seconds": round(time.monotonic() - started, 1),
               "rollouts": [t.to_dict() for t in traces], "problems": problems}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    for trace in traces:
        print(f"{trace.label:>16}: {trace.scenario} seed {trace.seed}: {trace.outcome or 'no end'}, "
              f"{trace.steps_started} policy steps; {trace.verdict()}")
    print(f"judged by {judged}; demo took {summary['seconds']} s; results in {out}")
    for problem in problems:
        print(f"fiper demo: FAILED: {problem}", file=sys.stderr)
    return 1 if problems else 0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``fiper demo``."""
    parser.add_argument("--task", default="sorting", help="sim task (the model's)")
    parser.add_argument("--model", type=data_path_argument, default="models/sorting", help=f"policy folder ({SEARCH_RULE})")
    parser.add_argument("--calibration", type=data_path_argument, help="calibration folder (default MODEL/calibration)")
    parser.add_argument("--config", type=Path, help="launch YAML declaring model and calibration_dir (default: the "
                                                    "installed launch/demo.launch.yaml)")
    parser.add_argument("--out", type=Path, help="output folder (default runs/demo/<UTC time>)")
    parser.add_argument("--id-seed", type=int, default=1002, help="seed of the in-distribution rollout")
    parser.add_argument("--ood-scenario", default="box_pos", help="harmful OOD scenario of the second rollout")
    parser.add_argument("--ood-seed", type=int, default=1000, help="seed of the OOD rollout")
    parser.add_argument("--ready-timeout", type=float, default=90.0, help="seconds for every node to become active")
    parser.add_argument("--rollout-timeout", type=float, default=120.0, help="seconds one rollout may take")
    parser.add_argument("-v", "--verbose", action="store_true", help="show the nodes' output")
    options.add_view_arguments(parser, on_by_default=True)


def run(args: argparse.Namespace) -> int:
    """``fiper demo``."""
    return run_demo(args)

