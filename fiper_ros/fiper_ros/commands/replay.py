"""``fiper replay BAG...``: play bags into the node suite (:class:`~fiper_ros.client.replay.Player`) or compute the
alarms offline (:mod:`fiper_ros.evaluation.offline`), and report them per rollout and in a closing table of TPR, TNR
and detection steps (:mod:`fiper_ros.evaluation.verdicts`), with a warning when the bags are the calibration's own
rollouts (docs/bags.md)."""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fiper_ros.bagio.atomic import atomic_output
from fiper_ros.bagio.errors import BagError
from fiper_ros.bagio.reader import BagReader, find_bags
from fiper_ros.bagio.rollout_bags import ROLLOUT_GAP_NS
from fiper_ros.client.replay import (NODE_NAME, Player, find_calibration, played_topics, readers_needed,
                                     suite_subscribers)
from fiper_ros.client.ros_session import RosSession
from fiper_ros.client.suite_process import SuiteProcess, detectors_of, installed_launch, replay_config
from fiper_ros.cluster import LOCAL
from fiper_ros.commands import options
from fiper_ros.commands.errors import UsageError
from fiper_ros.data_paths import SEARCH_RULE, data_path_argument
from fiper_ros.evaluation.verdicts import in_sample, in_sample_warning, rollout_line, table, tally
from fiper_ros.interface.topics import INPUT_TOPICS
from fiper_ros.platform.dds import allocate_domain

if TYPE_CHECKING:
    from fiper_ros.core.calibration import Calibration


def _play_all(args: argparse.Namespace, bags: list[Path], directory: Path | None) -> dict[str, Any]:
    """The live replay: launch the suite (if asked), check the calibration while it boots, wait for it,
    play every bag, collect the alarms."""
    with ExitStack() as stack:
        launch = not args.no_launch
        detectors = detectors_of(directory)
        domain = args.domain
        if domain is None and launch:
            domain = stack.enter_context(allocate_domain())
        suite = None
        if launch:
            assert directory is not None
            workdir = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="fiper-replay-")))
            view = options.view_arguments(args)
            config = replay_config(args.launch or installed_launch(), directory, detectors,
                                   workdir / "suite.launch.yaml", options.robot_from(args), view)
            suite = SuiteProcess(config, domain, echo=args.verbose)
            if view:
                print(f"fiper replay: {options.view_banner(args.view_port)}", file=sys.stderr, flush=True)
            stack.callback(suite.stop)
        calibration = checked_calibration(directory, bags)
        session = stack.enter_context(RosSession(NODE_NAME, domain))
        player = Player(session, args)
        readers = [stack.enter_context(BagReader(bag)) for bag in bags]
        for reader in readers:
            for topic, msgtype in reader.topics.items():
                if topic in played_topics(detectors) or (args.all_topics and args.no_launch):
                    player.add_topic(topic, msgtype, any(q.durability.name == "TRANSIENT_LOCAL"
                                                         for q in reader.offered_qos(topic)))
        needed = suite_subscribers(detectors) if launch else readers_needed(list(player.publishers))
        print(f"waiting for the suite in ROS domain {session.domain} ...", file=sys.stderr, flush=True)
        player.wait_for_subscribers(needed, args.wait, suite)
        started = time.monotonic()
        end = 0
        for reader in readers:
            shift = max(0, end + ROLLOUT_GAP_NS - reader.start_ns) if end else 0
            if shift:
                print(f"fiper replay: {reader.path} starts before the previous bag ended: shifted by {shift / 1e9:.3f} s",
                      file=sys.stderr)
            end = player.play(reader, shift)
            if session.stop.is_set():
                break
        seconds = time.monotonic() - started
        results = player.collect()
    return {"rollouts": results, "missing": player.missing, "seconds": seconds, "steps": player.steps,
            "calibration": calibration, "interrupted": session.stop.is_set()}


def checked_calibration(directory: Path | None, bags: list[Path]) -> Calibration | None:
    """The calibration in ``directory`` (``None`` without one), checked against every bag's layout.

    Imported here, not at the top: the core brings torch, whose import would delay the suite's start.
    """
    from fiper_ros.evaluation.offline import bag_layout, calibration_for  # noqa: PLC0415

    return None if directory is None else calibration_for(directory, [bag_layout(bag) for bag in bags])


def _offline(bags: list[Path], directory: Path, args: argparse.Namespace) -> dict[str, Any]:
    """The oracle's results for ``--offline``."""
    from fiper_ros.evaluation.offline import predict_bag  # noqa: PLC0415 - see checked_calibration

    started = time.monotonic()
    calibration = checked_calibration(directory, bags)
    if args.ray is not None:
        from fiper_ros.commands.replay_fleet import predict_bags  # noqa: PLC0415 - Ray only with --ray

        results = predict_bags(bags, calibration, options.robot_from(args), args.ray)
    else:
        fk = options.fk_of(options.robot_from(args))
        results = [r for bag in bags for r in predict_bag(bag, calibration, fk)]
    for result in results:
        print(rollout_line(result))
    return {"rollouts": results, "missing": [], "seconds": time.monotonic() - started,
            "steps": sum(len(r.steps) for r in results), "calibration": calibration, "interrupted": False}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``fiper replay``."""
    parser.add_argument("bags", nargs="+", type=Path, help="bags, or directories holding bags")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--rate", type=float, default=1.0, help="play at this multiple of real time (default 1)")
    pace.add_argument("--fast", action="store_true", help="as fast as the suite answers (flow-controlled)")
    parser.add_argument("--calibration", type=data_path_argument,
                        help=f"calibration directory (default: calibration/ next to the bags; {SEARCH_RULE})")
    suite = parser.add_mutually_exclusive_group()
    suite.add_argument("--launch", type=Path, help="launch YAML of the suite to start (default: the installed "
                                                   "fiper.launch.yaml); it declares calibration_dir, use_sim_time and, "
                                                   "for an observation-only calibration, observation_only")
    suite.add_argument("--no-launch", action="store_true", help="play into a suite already running in this domain")
    suite.add_argument("--offline", action="store_true", help="compute the alarms with the core, without DDS")
    parser.add_argument("--ray", nargs="?", const=LOCAL, default=None, metavar="ADDRESS",
                        help="with --offline: one Ray task per bag, on a local instance (no ADDRESS) or the cluster at "
                             "ADDRESS (docs/scale.md)")
    parser.add_argument("--all-topics", action="store_true", help="with --no-launch: also play recorded outputs")
    parser.add_argument("--domain", type=int, help="ROS domain (default: a free one when launching, else ROS_DOMAIN_ID)")
    parser.add_argument("--wait", type=float, default=60.0, help="seconds to wait for the suite's subscribers")
    parser.add_argument("--step-timeout", type=float, default=5.0, help="seconds to wait for a step's alarm")
    parser.add_argument("--settle", type=float, default=0.1, help="pause after each RolloutEvent START, seconds")
    parser.add_argument("--clock-hz", type=float, default=100.0, help="/clock ticks per simulated second (--rate)")
    parser.add_argument("--report", type=Path, help="write the per-step results as JSON to this file")
    parser.add_argument("--verbose", action="store_true", help="show the launched suite's output")
    options.add_strict_argument(parser)
    options.add_robot_arguments(parser, control_dt=False)
    options.add_view_arguments(parser)


def _bags_and_calibration(args: argparse.Namespace) -> tuple[list[Path], Path | None]:
    """The bags (each read once, so a bad one is refused before anything starts) and the calibration
    directory to use."""
    bags = find_bags(args.bags, strict=args.strict)
    for bag in bags:
        with BagReader(bag) as reader:
            reader.require_any(INPUT_TOPICS)
            reader.check_data()
    directory = args.calibration or find_calibration(bags)
    if directory is None and not args.no_launch:
        raise BagError("no calibration: give --calibration DIR (or put calibration/ next to the bags)")
    return bags, directory


def run(args: argparse.Namespace) -> int:
    """``fiper replay``."""
    if args.rate <= 0 or args.clock_hz <= 0:
        raise UsageError("--rate and --clock-hz must be > 0")
    if args.report is not None and args.report.is_dir():
        raise UsageError(f"--report {args.report} is a directory: give a file name")
    if args.ray is not None and not args.offline:
        raise UsageError("--ray runs the offline replay as Ray tasks: it needs --offline")
    if args.view and (args.no_launch or args.offline):
        raise UsageError("--view goes with the suite replay launches: beside a running suite, run fiper view")
    bags, directory = _bags_and_calibration(args)
    outcome = _offline(bags, directory, args) if args.offline else _play_all(args, bags, directory)
    rate = outcome["steps"] / outcome["seconds"] if outcome["seconds"] > 0 else 0.0
    print(f"{len(outcome['rollouts'])} rollouts, {outcome['steps']} steps in {outcome['seconds']:.1f} s "
          f"({rate:.1f} steps/s); {len(outcome['missing'])} steps without an alarm")
    rows, calibration = tally(outcome["rollouts"]), outcome["calibration"]
    print("\n".join(table(rows)))
    split, ids = calibration.split if calibration else {}, [r.rollout_id for r in outcome["rollouts"]]
    if warning := in_sample_warning(split, ids):
        print(f"fiper replay: {warning}", file=sys.stderr)
    if args.report:
        report = {"bags": [str(b) for b in bags], "calibration": str(directory) if directory else None,
                  "calibration_hash": calibration.content_hash if calibration else None,
                  "mode": "offline" if args.offline else "live", "seconds": outcome["seconds"],
                  "missing": outcome["missing"], "rollouts": [r.to_dict() for r in outcome["rollouts"]],
                  "verdicts": [row.to_dict() for row in rows], "in_sample": in_sample(split, ids)}
        with atomic_output(args.report, overwrite=True) as staging:
            staging.write_text(json.dumps(report, indent=1))
    if outcome["interrupted"]:
        return 130
    return 1 if outcome["missing"] else 0
