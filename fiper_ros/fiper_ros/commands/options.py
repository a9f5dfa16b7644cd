"""Options shared by several ``fiper`` commands.

Live bags (``fiper record``, ``fiper snapshot``): how a live bag goes to disk (``--chunk-s``, ``--chunk-mb``:
:class:`~fiper_ros.bagio.chunks.LiveChunks`), i.e. how much a crash can lose. Reading commands (``fiper
replay``, ``calibrate`` and ``evaluate``): whether an unfinished bag is taken (``--strict``). Lists of integers
(:func:`int_list`), action channels (:func:`parse_channels`) and the automatic choice of ``fiper calibrate --auto``
and ``fiper evaluate --auto`` (:func:`add_auto_arguments`, :func:`auto_from`). No heavy imports:
``fiper evaluate`` reads its options without the ROS message build, and ``fiper launch`` without numpy or
pinocchio (the robot model is imported where one is built: the launcher's start-up).

The robot model of the offline commands (``fiper calibrate``, ``evaluate``, ``replay``):

ACE bins end-effector positions (App. A.1); a joint-space policy's actions reach them through the
robot's forward kinematics (``--urdf``, ``--ee-frame``), joint velocities through the control period
first (``--control-dt``). The ACE node takes the same as parameters (``urdf_path``, ``ee_frame``).
"""
from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from fiper_ros.bagio.chunks import DEFAULT_CHUNK_MB, DEFAULT_CHUNK_S, LiveChunks
from fiper_ros.commands.errors import UsageError

if TYPE_CHECKING:
    from fiper_ros.core.auto import AutoSettings
    from fiper_ros.core.kinematics import PinocchioFK, RobotModel
    from fiper_ros.core.transfer import Prior

#: The prior ``--auto-rule transfer`` reads without ``--auto-prior``: this path of the installed package's share,
#: ranked at equal promise (``selection.promise: delta``, the default ``--auto-promise``).
DEFAULT_PRIOR = Path("models") / "priors" / "sim-three-tasks.yaml"
#: ... and with ``--auto-promise entry``: the same tasks' prior ranked at each entry's own promise.
ENTRY_PRIOR = Path("models") / "priors" / "sim-three-tasks-entry.yaml"

#: The most integers one list option (:func:`int_list`) expands to: a range is bounded before it is built.
MAX_INTS = 10_000


def int_list(text: str) -> tuple[int, ...]:
    """``"1-50"``, ``"1,5,10"`` or a mix -> the sorted distinct integers (a negative one alone, ``"-1"``, is an
    integer, not a range); :class:`argparse.ArgumentTypeError` for no integers, a reversed range or more than
    :data:`MAX_INTS`."""
    values: set[int] = set()
    for part in (p.strip() for p in text.split(",")):
        if "-" in part[1:]:
            cut = part.index("-", 1)
            low, high = int(part[:cut]), int(part[cut + 1:])
            if low > high or high - low + 1 > MAX_INTS:
                raise argparse.ArgumentTypeError(f"range {part!r}: expected LOW-HIGH with LOW <= HIGH, at most "
                                                 f"{MAX_INTS} integers")
            values.update(range(low, high + 1))
        elif part:
            values.add(int(part))
        if len(values) > MAX_INTS:
            raise argparse.ArgumentTypeError(f"{text!r} names more than {MAX_INTS} integers")
    if not values:
        raise argparse.ArgumentTypeError(f"no integers in {text!r}")
    return tuple(sorted(values))


def parse_channels(text: str, flag: str = "--channels") -> tuple[int, int] | str:
    """The action channel option ``flag`` (``fiper convert --channels``): ``"START:STOP"`` (a Python slice of the
    action channels), ``"all"`` or ``"auto"`` (:data:`fiper_ros.converters.options.ALL`, ``AUTO``);
    :class:`UsageError` naming ``flag`` otherwise."""
    from fiper_ros.converters.options import ALL, AUTO  # noqa: PLC0415 - numpy only for the commands that convert

    if text in (ALL, AUTO):
        return text
    try:
        start, stop = (int(part) for part in text.split(":"))
    except ValueError:
        raise UsageError(f"{flag} must be START:STOP, 'all' or 'auto', got {text!r}") from None
    if not 0 <= start < stop:
        raise UsageError(f"{flag} {text}: need 0 <= START < STOP")
    return start, stop


def add_auto_arguments(parser: argparse.ArgumentParser | argparse._ArgumentGroup, folds: bool = False) -> None:
    """The options of the automatic choice (:class:`~fiper_ros.core.auto.AutoSettings`): ``--auto-rule``,
    ``--auto-prior``, ``--auto-promise``, ``--auto-windows``, ``--auto-budget``, ``--step-limit`` and (``folds``:
    ``fiper calibrate``, whose fit part it splits) ``--auto-folds``."""
    from fiper_ros.core.auto import (  # noqa: PLC0415 - numpy only for the commands that choose
        DELTA_PROMISE, PROMISES, RULES, AutoSettings)

    defaults = AutoSettings()
    parser.add_argument("--auto-rule", choices=tuple(RULES), default=defaults.rule,
                        help="with --auto: proxy-twa scores failure proxies made from the successes, margin the "
                             "held-out successes only, transfer takes the best entry of a prior learned on other "
                             "tasks' labelled rollouts (docs/method.md)")
    parser.add_argument("--auto-prior", type=Path, default=None, metavar="FILE",
                        help="with --auto-rule transfer: the prior (fiper evaluate --write-prior); default: "
                             + ("each task's of the other tasks of the run" if not folds else
                                f"{DEFAULT_PRIOR} of the installed fiper_ros share ({ENTRY_PRIOR.name} with "
                                "--auto-promise entry)"))
    parser.add_argument("--auto-promise", choices=tuple(PROMISES), default=defaults.promise,
                        help=f"with --auto-rule transfer: {DELTA_PROMISE} (default) keeps delta whatever the entry (an "
                             "OR of N thresholds at delta/N each); entry keeps each entry's own promise (an OR of N "
                             "at delta each: N delta)" + ("; also the promise the priors of the run (--write-prior's, "
                                                          "the transfer rule's) rank their entries at" if not folds
                                                          else ""))
    parser.add_argument("--auto-windows", type=int_list, default=defaults.windows, metavar="W,...",
                        help="with --auto: the windows tried, a comma list and/or ranges, e.g. 1,3,5-10 (default "
                             f"{','.join(map(str, defaults.windows))})")
    if folds:
        parser.add_argument("--auto-folds", type=int, default=defaults.folds, metavar="K",
                            help="with --auto: folds of the fit part (also the calibration's --shape-folds)")
    parser.add_argument("--auto-budget", type=int, default=defaults.budget, metavar="N",
                        help="with --auto: most candidate configurations per task (more is refused)")
    parser.add_argument("--step-limit", type=int, default=None, metavar="STEPS",
                        help="with --auto: every task's step limit (a stalled proxy rollout runs to it)")


def prior_from(args: argparse.Namespace, default: bool) -> Prior | None:
    """The prior of ``--auto-prior`` (:class:`~fiper_ros.core.transfer.PriorError` in one line for a bad file);
    without it ``None``, or with ``default`` the shipped one (:data:`DEFAULT_PRIOR`; with ``--auto-promise entry``
    :data:`ENTRY_PRIOR`, ranked at that promise), looked up in the installed package's share only, never the
    working directory. ``--auto-prior`` without ``--auto-rule transfer`` is a :class:`UsageError`."""
    from fiper_ros.core.auto import ENTRY_PROMISE, TRANSFER  # noqa: PLC0415
    from fiper_ros.core.transfer import Prior  # noqa: PLC0415
    from fiper_ros.data_paths import package_share  # noqa: PLC0415

    if args.auto_rule != TRANSFER or not args.auto:
        if args.auto_prior is not None:
            raise UsageError("--auto-prior is the prior of --auto --auto-rule transfer")
        return None
    if args.auto_prior is not None:
        return Prior.load(args.auto_prior)
    if not default:
        return None
    path = ENTRY_PRIOR if args.auto_promise == ENTRY_PROMISE else DEFAULT_PRIOR
    share = package_share()
    if share is None:
        raise UsageError(f"the default prior ({path}) is in the installed fiper_ros share, which is not on "
                         "AMENT_PREFIX_PATH (. ./env.sh): give --auto-prior FILE")
    return Prior.load(share / path)


def auto_from(args: argparse.Namespace) -> AutoSettings | None:
    """The :class:`~fiper_ros.core.auto.AutoSettings` of :func:`add_auto_arguments`' options (``None`` without
    ``--auto``); the settings refuse a bad value themselves (:class:`~fiper_ros.core.auto.AutoError`)."""
    if not args.auto:
        return None
    from fiper_ros.core.auto import AutoSettings  # noqa: PLC0415

    folds = {"folds": args.auto_folds} if hasattr(args, "auto_folds") else {}
    return AutoSettings(rule=args.auto_rule, windows=args.auto_windows, budget=args.auto_budget,
                        step_limit=args.step_limit, promise=args.auto_promise, **folds)


def add_robot_arguments(parser: argparse.ArgumentParser | argparse._ArgumentGroup, control_dt: bool = True) -> None:
    """``--urdf``, ``--ee-frame`` and (unless the calibration holds it already) ``--control-dt``."""
    parser.add_argument("--urdf", help="robot URDF, for joint-space actions (e.g. "
                        "sim_bridge/sim_bridge/assets/panda/urdf/panda.urdf)")
    parser.add_argument("--ee-frame", default="panda_hand", help="URDF frame ACE tracks (default panda_hand)")
    if control_dt:
        parser.add_argument("--control-dt", type=float, help="seconds per action, for joint-velocity actions "
                            "(the Stacking sim: 0.1)")


def robot_from(args: argparse.Namespace) -> RobotModel | None:
    """The robot model of the command line, ``None`` without ``--urdf``."""
    control_dt = getattr(args, "control_dt", None)
    if args.urdf is None:
        if control_dt is not None:
            raise UsageError("--control-dt needs --urdf (joint velocities are mapped through the robot's FK)")
        return None
    if control_dt is not None and control_dt <= 0:
        raise UsageError(f"--control-dt must be > 0, got {control_dt}")
    from fiper_ros.core.kinematics import RobotModel  # noqa: PLC0415 - numpy and pinocchio only where needed

    return RobotModel(args.urdf, args.ee_frame, control_dt)


def fk_of(robot: RobotModel | None) -> PinocchioFK | None:
    """The robot's FK, checked now (a missing URDF or frame is a :class:`UsageError`)."""
    if robot is None:
        return None
    from fiper_ros.core.kinematics import KinematicsError  # noqa: PLC0415

    try:
        return robot.forward_kinematics()
    except KinematicsError as error:
        raise UsageError(str(error)) from error


def add_chunk_arguments(parser: argparse.ArgumentParser) -> None:
    """``--chunk-s`` and ``--chunk-mb``."""
    parser.add_argument("--chunk-s", type=float, default=DEFAULT_CHUNK_S,
                        help=f"write the open chunk to disk at least this often, seconds (default {DEFAULT_CHUNK_S:g}; "
                             "a crash loses at most this much)")
    parser.add_argument("--chunk-mb", type=float, default=DEFAULT_CHUNK_MB,
                        help=f"... or once it holds this many MB of messages (default {DEFAULT_CHUNK_MB:g})")


def chunks_from(args: argparse.Namespace) -> LiveChunks:
    """The chunking of the command line (:class:`~fiper_ros.commands.errors.UsageError` unless both are > 0)."""
    return LiveChunks(args.chunk_s, args.chunk_mb)


def add_strict_argument(parser: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """``--strict``: refuse an unfinished bag instead of reading it up to its last complete chunk."""
    parser.add_argument("--strict", action="store_true",
                        help="refuse an unfinished bag (a recording that did not stop cleanly) instead of reading "
                             "it up to its last complete chunk with a warning")



def add_view_arguments(parser: argparse.ArgumentParser, on_by_default: bool = False) -> None:
    """The live view beside the suite a command starts (docs/view.md): ``--view`` (``--no-view`` where it is on by
    default, as in ``fiper demo``) and ``--view-port``."""
    from fiper_ros.view.server import DEFAULT_HOST, DEFAULT_PORT  # noqa: PLC0415 - only the commands that have it

    if on_by_default:
        parser.add_argument("--no-view", dest="view", action="store_false",
                            help="do not serve the live view (Foxglove WebSocket, docs/view.md)")
    else:
        parser.add_argument("--view", action="store_true",
                            help=f"also serve the suite live to Foxglove (WebSocket on {DEFAULT_HOST}, docs/view.md)")
    parser.add_argument("--view-port", type=int, default=DEFAULT_PORT,
                        help=f"port of the live view (default {DEFAULT_PORT}; 0: any free port, logged by view_node)")


def view_arguments(args: argparse.Namespace) -> dict[str, str]:
    """The launch arguments (``fiper.launch.yaml``) that add the live view asked for on the command line; none
    without it. :class:`~fiper_ros.commands.errors.UsageError` for a port that cannot be served (one line, naming it)."""
    from fiper_ros.view.server import DEFAULT_HOST, port_problem  # noqa: PLC0415

    if not args.view:
        return {}
    if not 0 <= args.view_port <= 65535:
        raise UsageError(f"--view-port must be in 0..65535, got {args.view_port}")
    problem = port_problem(DEFAULT_HOST, args.view_port)
    if problem:
        raise UsageError(f"live view: {problem}: give another --view-port")
    return {"view": "true", "view_port": str(args.view_port)}


def view_banner(port: int) -> str:
    """The line that tells where the live view is and which layout to import in Foxglove."""
    from fiper_ros.view.layout import installed_layout  # noqa: PLC0415
    from fiper_ros.view.server import DEFAULT_HOST, HOW_TO_OPEN, address  # noqa: PLC0415

    where = address(DEFAULT_HOST, port) if port else f"{address(DEFAULT_HOST, 0)} (any free port: view_node logs it)"
    return f"live view {where} ({HOW_TO_OPEN}); layout {installed_layout()}"
