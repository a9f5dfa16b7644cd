"""``fiper calibrate BAG... -o DIR``: fit a FIPER calibration on the successful rollouts of bags.

Reads every rollout of the bags, keeps those whose RolloutEvent END says SUCCESS, splits them (split
conformal by default: RND-OE, ``R_d`` and the thresholds' shape on one part, the thresholds' conformal
quantiles on the other; ``--split cross`` or ``--same-data`` instead), fits everything
(:func:`fiper_ros.core.calibration.calibrate`), then writes the calibration directory (under a temporary
name, renamed when complete) and closes with a summary of what it fitted: ``M`` (the successes, their
steps), the split, the windows, the thresholds and the rollouts behind each, a leave-one-out estimate of the
false-alarm rate and the guarantee. Too few successes, or a threshold that would be +inf: one line, exit
status 2. A window longer than every successful rollout is warned about (before the training and again in the
summary): the windowed score is then the sum over the whole rollout so far at every step, as any longer window
would be, which is allowed (the shipped Sorting calibration's ACE window is such a one) but rarely meant.

``--detectors`` names the detectors (FIPER's pair by default; ``rnd_oe`` alone is an observation-only
calibration, which needs no action batches; any set of rnd_oe, ace, logpzo, pca_kmeans, progress, consistency,
elapsed and logged signals ``signal_<name>``) and ``--combine`` how they vote: ``and`` / ``or`` with a threshold
each, ``max`` / ``kth:K`` under one conformal threshold. Bags without action batches for a detector that reads
them are refused with one line saying so. Rollouts of several tasks are calibrated together, each task its own
models and shapes; ``--pool`` pools the conformal factor over the tasks.

``--auto`` chooses the detectors (among ``--detectors``, default every one the successes can feed), the window,
the threshold kind and the combine from the successes alone (:mod:`fiper_ros.core.auto`: the fit part's fold
curves and failure proxies made from them; ``--auto-windows``, ``--auto-folds``, ``--auto-budget``,
``--step-limit``), calibrates that, prints its best candidates and why the winner won, and stores the choice in
the calibration (``auto``); the other configuration options are then not used. ``--auto-rule transfer`` takes the
best entry of a prior learned on other tasks' labelled rollouts (:mod:`fiper_ros.core.transfer`; ``--auto-prior
FILE``, default the one shipped in the installed package's share) that the successes can feed and whose threshold
is finite at ``--delta``, and stores the prior's content hash and the entry's rank; an OR entry of N thresholds is
calibrated at ``delta / N`` each, so the choice promises ``--delta`` whatever it is (``--auto-promise entry``: at
``delta`` each, promising ``N delta``).

``fiper calibrate --upgrade OLD -o NEW`` converts a calibration of format 1 (RND-OE's weights in the torch
file ``rnd_oe.pt``, which the nodes no longer read) or 2 to the current format: the same thresholds, weights
and scores, checked against the old content hash. ``-o OLD --force`` converts in place.
"""
from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from fiper_ros.bagio.atomic import atomic_output, check_new
from fiper_ros.bagio.errors import BagError
from fiper_ros.bagio.reader import find_bags
from fiper_ros.bagio.rollout_bags import read_rollouts
from fiper_ros.commands import options
from fiper_ros.commands.errors import UsageError
from fiper_ros.core.auto import MARGIN, PROMISES, RULES, AutoChoice, AutoSettings
from fiper_ros.core.calibration import (SPLITS, Calibration, CalibrationSettings, calibrate,
                                        upgrade_calibration)
from fiper_ros.core.calibration.auto import auto_calibrate
from fiper_ros.core.calibration_file import FORMAT_VERSION
from fiper_ros.core.detectors import info, judged_by
from fiper_ros.core.equalisation import EQUALISATIONS
from fiper_ros.core.errors import ChoiceError
from fiper_ros.core.fusion import Combine
from fiper_ros.core.kinematics import ForwardKinematics, KinematicsError
from fiper_ros.core.profiles import PROFILE_NAMES
from fiper_ros.core.rnd_oe import RNDConfig, TrainProgress
from fiper_ros.core.rollout import Rollout, successful
from fiper_ros.core.thresholds import KINDS, Threshold
from fiper_ros.core.transfer import Prior, TransferChoice, prior_promise
from fiper_ros.core.window import MODES
from fiper_ros.interface.topics import ACTIONS_TOPIC

RND_PRESETS = {"small": RNDConfig.small, "paper": RNDConfig.paper}
#: Seconds between two progress lines of the RND-OE training.
PROGRESS_PERIOD_S = 2.0


class EpochPrinter:
    """Prints RND-OE training progress to stderr, at most every :data:`PROGRESS_PERIOD_S` seconds."""

    def __init__(self) -> None:
        self._last = time.monotonic()

    def __call__(self, report: TrainProgress) -> None:
        now = time.monotonic()
        if now - self._last >= PROGRESS_PERIOD_S or report.epoch == report.max_epochs:
            self._last = now
            print(f"  RND-OE epoch {report.epoch}/{report.max_epochs}: train loss {report.train_loss:.4g}, "
                  f"validation loss {report.val_loss:.4g} (best {report.best_val_loss:.4g})", file=sys.stderr, flush=True)


def load_rollouts(bags: Sequence[Path]) -> list[Rollout]:
    """Every rollout of the bags, in order."""
    rollouts: list[Rollout] = []
    for bag in bags:
        rollouts.extend(read_rollouts(bag))
    return rollouts


def window_warnings(settings: CalibrationSettings, successes: Sequence[Rollout]) -> list[str]:
    """One warning per declared detector whose window (eqs. 2 and 5) is longer than every rollout of
    ``successes``: its windowed score is the sum over the whole rollout so far at every step, as with any window
    at least as long as the longest rollout."""
    if not successes:
        return []
    longest = max(r.length for r in successes)
    warnings = []
    for detector in settings.detectors:
        window = settings.window_of(detector)
        if settings.aggregation_of(detector) == "window" and window > longest:
            warnings.append(f"warning: the window of {info(detector).label} ({window}) is longer than every calibration "
                            f"rollout (the longest has {longest} steps): its windowed score sums the whole rollout so "
                            f"far at every step, as any window of {longest} or more would; a shorter window reacts "
                            "sooner")
    return warnings


def calibrate_bags(bags: Sequence[Path], out: Path, settings: CalibrationSettings, *, overwrite: bool = False,
                   quiet: bool = False, fk: ForwardKinematics | None = None, auto: AutoSettings | None = None,
                   candidates: Sequence[str] | None = None, prior: Prior | None = None
                   ) -> tuple[Calibration, list[Rollout]]:
    """Calibrate on the successful rollouts of ``bags`` and write the calibration directory ``out``
    (``fk``: the robot's forward kinematics, for joint-space actions); the calibration and the successes. With
    ``auto`` the configuration is chosen from the successes first (:func:`auto_calibrate`, among ``candidates`` or
    every detector they can feed; the transfer rule from ``prior``) and the choice printed."""
    check_new(out, overwrite)
    rollouts = load_rollouts(bags)
    good = successful(rollouts)
    names = ", ".join(str(b) for b in bags)
    if len(good) < settings.min_rollouts:
        raise BagError(f"too few successful rollouts to calibrate: {len(good)} of {len(rollouts)} in {names} "
                       f"(need at least {settings.min_rollouts}, see --min-rollouts)")
    without = sorted({str(r.metadata.get("bag", "")) for r in rollouts if not r.has_actions})
    readers = [info(d).label for d in (candidates or settings.detectors) if info(d).reads == "actions"]
    if readers and without and (auto is None or candidates is not None):
        raise BagError(f"no action batches ({ACTIONS_TOPIC}) in {', '.join(without)}: {' and '.join(readers)} "
                       "cannot be calibrated; for an observation-only calibration (RND-OE alone) give --detectors rnd_oe")
    if not quiet:
        print(f"calibrating on {len(good)} successful rollouts ({sum(r.length for r in good)} steps) of "
              f"{len(rollouts)} in {names}", flush=True)
        for warning in window_warnings(settings, good) if auto is None else ():
            print(f"fiper calibrate: {warning}", file=sys.stderr, flush=True)
    try:
        progress = None if quiet else EpochPrinter()
        if auto is None:
            calibration = calibrate(rollouts, settings, fk=fk, progress=progress)
        else:
            calibration, choice = auto_calibrate(rollouts, settings, auto, candidates, fk, progress,
                                                 None if quiet else _note, prior)
            if not quiet:
                print("\n".join(auto_lines(choice, pooled=settings.pooled)), flush=True)
    except KinematicsError as error:
        raise BagError(f"{error}: give the robot model with --urdf, --ee-frame and --control-dt") from error
    with atomic_output(out, overwrite) as staging:
        calibration.save(staging)
    return calibration, good


def _note(text: str) -> None:
    """A progress line of the automatic choice on stderr."""
    print(f"  auto: {text}", file=sys.stderr, flush=True)


def auto_lines(choice: AutoChoice | TransferChoice, top: int = 8, pooled: bool = False) -> list[str]:
    """What ``--auto`` chose and why, with its best candidates (lines to print): the proxy TWA and each proxy kind's
    catch (``proxy-twa``), or the margin (``margin``); the prior's entries down to the chosen one (``transfer``;
    ``pooled``: whether the calibration pools its thresholds over the tasks)."""
    if isinstance(choice, TransferChoice):
        return transfer_lines(choice, top, pooled)
    margin = choice.settings.rule == MARGIN
    kinds = [] if margin else list(choice.ranking[0].caught)
    head = "margin" if margin else "proxy TWA"
    rule = choice.settings.rule
    lines = [f"auto ({rule} v{RULES[rule]}, delta {choice.delta:g}): "
             f"{len(choice.ranking)} candidates of {', '.join(choice.detectors)}",
             f"  {'rank':>4}  {head:>9}  {'held-out FA':>11}  " + "".join(f"{k:>6}  " for k in kinds) + "candidate"]
    for rank, score in enumerate(choice.ranking[:top], 1):
        value = score.caught[MARGIN] if margin else score.score
        lines.append(f"  {rank:>4}  {value:>9.3f}  {score.false_alarms:>11.3f}  "
                     + "".join(f"{score.caught.get(k, 0.0):>6.3f}  " for k in kinds) + score.candidate.label())
    lines.append(f"chosen: {choice.why()}")
    return lines


def transfer_lines(choice: TransferChoice, top: int = 8, pooled: bool = False) -> list[str]:
    """The transfer rule's choice: the prior, its entries ranked above the chosen one (why each did not fit, the
    first ``top``) and the chosen one; a note where the prior was ranked with thresholds pooled over its tasks and the
    calibration's are per task, or the other way round (``pooled``)."""
    prior = choice.prior
    rule = choice.settings.rule
    lines = [f"auto ({rule} v{RULES[rule]}, delta {choice.delta:g}): prior {prior.content_hash[:12]} of "
             f"{len(prior.entries)} entries learned on {', '.join(prior.tasks)}; the successes feed "
             f"{', '.join(choice.detectors)}",
             f"  {'rank':>4}  {'TWA':>6}  entry"]
    for rank, entry, why in choice.skipped[:top]:
        lines.append(f"  {rank:>4}  {entry.twa:>6.3f}  {entry.label()}: skipped ({why})")
    lines.append(f"  {choice.rank:>4}  {choice.chosen.twa:>6.3f}  {choice.label()}: chosen")
    lines.append(f"chosen: {choice.why()}")
    ranked = bool(prior.calibration.get("pooled", False))
    if ranked != pooled:
        lines.append(f"note: the prior ranked its entries with thresholds {_pooling(ranked)}, this calibration's are "
                     f"{_pooling(pooled)}: its order may not carry over")
    if prior_promise(prior) != choice.settings.promise:
        lines.append(f"note: the prior ranked its entries at promise {prior_promise(prior)!r}, this choice keeps "
                     f"{choice.settings.promise!r} ({PROMISES[choice.settings.promise]}): its order may not carry over")
    return lines


def _pooling(pooled: bool) -> str:
    return "pooled over the tasks" if pooled else "per task"


def settings_from(args: argparse.Namespace) -> CalibrationSettings:
    """The calibration settings of the command line."""
    dims = None if args.action_dims is None else options.parse_channels(args.action_dims, "--action-dims")
    if isinstance(dims, str):
        raise UsageError(f"--action-dims must be START:STOP, got {dims!r}")
    rnd = RND_PRESETS[args.rnd_preset]()
    if args.max_epochs:
        rnd = RNDConfig.from_dict(rnd.to_dict() | {"max_epochs": args.max_epochs})
    windows = dict(args.windows)
    detectors = args.detectors or defaults_detectors()
    for detector, window in (("rnd_oe", args.window_obs), ("ace", args.window_act)):
        if window is not None and detector in detectors:
            windows.setdefault(detector, window)
    return CalibrationSettings(detectors=detectors, window=args.window, windows=windows,
                               aggregation=args.aggregation, alpha=args.alpha, threshold=args.threshold,
                               delta=args.delta, combine=args.combine, rnd=rnd, seed=args.seed,
                               profile=args.profile, min_rollouts=args.min_rollouts, action_dims=dims,
                               control_dt=args.control_dt, split="same" if args.same_data else args.split,
                               conformal_fraction=args.conformal_fraction, folds=args.folds,
                               shape_folds=args.shape_folds, pooled=args.pool, equalise=args.equalise,
                               equalise_level=args.equalise_level)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``fiper calibrate``."""
    defaults = CalibrationSettings()
    parser.add_argument("bags", nargs="*", type=Path, help="bags (or directories of bags) with calibration rollouts")
    parser.add_argument("-o", "--out", type=Path, required=True, help="calibration directory to write")
    parser.add_argument("--upgrade", type=Path, metavar="OLD", default=None,
                        help="instead of calibrating: convert the calibration OLD of format 1 (weights in rnd_oe.pt, "
                             f"torch) or 2 to format {FORMAT_VERSION}; -o OLD --force converts in place")
    parser.add_argument("--detectors", type=_names, default=None,
                        help="detectors calibrated and combined, a comma list of rnd_oe, ace, logpzo, pca_kmeans, "
                             "progress, consistency, elapsed and signal_<name> (default rnd_oe,ace; rnd_oe alone: "
                             "observation-only, no action batches needed); with --auto the candidates (default: "
                             "every detector the successes can feed)")
    parser.add_argument("--auto", action="store_true",
                        help="choose the detectors, window, threshold kind and combine from the successes alone "
                             "(their fit part: fold models, held-out successes and failure proxies; docs/method.md) "
                             "and calibrate that; the choice is printed and stored in the calibration")
    options.add_auto_arguments(parser, folds=True)
    parser.add_argument("--combine", type=_combine, default=defaults.combine,
                        help="how the detectors vote: and (eq. 7), or (a threshold each), max or kth:K (one "
                             "conformal threshold over all: the promise is delta)")
    parser.add_argument("--window", type=int, default=defaults.window, help="every detector's window w (eqs. 2, 5)")
    parser.add_argument("--window-obs", type=int, default=None, help="RND-OE's window w_O (eq. 2)")
    parser.add_argument("--window-act", type=int, default=None, help="ACE's window w_A (eq. 5)")
    parser.add_argument("--windows", type=_windows, default={}, metavar="DETECTOR=W,...",
                        help="per-detector windows, e.g. rnd_oe=8,ace=50")
    parser.add_argument("--aggregation", choices=MODES, default=defaults.aggregation,
                        help="window sum (eqs. 2, 5), max-pooled window, cumulative sum or the single step")
    parser.add_argument("--threshold", choices=KINDS, default=defaults.threshold, help="threshold kind")
    parser.add_argument("--delta", type=float, default=defaults.delta, help="target false-alarm rate")
    parser.add_argument("--alpha", type=float, default=None, help="ACE cell size factor (default: the profile's)")
    parser.add_argument("--seed", type=int, default=defaults.seed, help="seed of the models and of the splits")
    parser.add_argument("--split", choices=SPLITS, default=defaults.split,
                        help="which successes fit what: 'split' conformal (default; Proposition 1 holds), 'cross' "
                             "(K-fold, approximate), 'same' (the paper's same-data calibration, no guarantee)")
    parser.add_argument("--same-data", action="store_true",
                        help="models and thresholds on the same successes (= --split same; not covered by Prop. 1)")
    parser.add_argument("--conformal-fraction", type=float, default=defaults.conformal_fraction,
                        help="with --split split: the share of the successes the thresholds' quantiles use")
    parser.add_argument("--shape-folds", type=int, default=defaults.shape_folds, metavar="K",
                        help="with --split split: the thresholds' per-step shapes from K-fold cross-fitted scores of "
                             "the fit part (0: in-sample)")
    parser.add_argument("--pool", action="store_true",
                        help="rollouts of several tasks: one conformal factor over every task's conformal rollouts "
                             "(each task normalised by its own shapes); the promise is then over all tasks")
    parser.add_argument("--equalise", choices=EQUALISATIONS, default=defaults.equalise,
                        help="with --combine max or kth:K: map each detector's normalised score by an equaliser fitted "
                             "on the fit part's out-of-fold maxima before combining: 'quantile' (divide by their "
                             "--equalise-level quantile), 'tail' (their -log survival function), 'none' (default)")
    parser.add_argument("--equalise-level", type=float, default=defaults.equalise_level, metavar="Q",
                        help="with --equalise quantile: the quantile of the maxima mapped to 1")
    parser.add_argument("--folds", type=int, default=defaults.folds, help="with --split cross: the folds K")
    parser.add_argument("--min-rollouts", type=int, default=defaults.min_rollouts, help="fewest successes accepted")
    parser.add_argument("--profile", choices=PROFILE_NAMES, default=defaults.profile,
                        help="'paper' definitions or the authors' 'reference' code")
    parser.add_argument("--rnd-preset", choices=sorted(RND_PRESETS), default="small",
                        help="RND-OE size: 'small' (CPU default) or 'paper' (App. A.2, slow on CPU)")
    parser.add_argument("--max-epochs", type=int, default=0, help="cap RND-OE training epochs (0: the preset's)")
    parser.add_argument("--action-dims", default=None, help="action channels ACE uses, START:STOP (default: 0:3)")
    parser.add_argument("--force", action="store_true", help="replace DIR if it exists")
    options.add_strict_argument(parser)
    options.add_robot_arguments(parser)


def run(args: argparse.Namespace) -> int:
    """``fiper calibrate``."""
    if args.upgrade is not None or not args.bags:
        return upgrade(args)
    settings = settings_from(args)
    auto = options.auto_from(args)
    prior = options.prior_from(args, default=True)
    fk = options.fk_of(options.robot_from(args))
    bags = find_bags(args.bags, strict=args.strict)
    calibration, successes = calibrate_bags(bags, args.out, settings, overwrite=args.force, fk=fk, auto=auto,
                                            candidates=args.detectors, prior=prior)
    settings = calibration.settings
    shown = {k: v for k, v in settings.to_dict().items() if k not in ("rnd", "progress", "consistency", "logpzo",
                                                                        "pca_kmeans")}
    print(f"settings: {shown}; RND-OE {args.rnd_preset} (max {settings.rnd.max_epochs} epochs)")
    layout = calibration.layout
    if layout.has_actions:
        print(f"layout: E={layout.embedding_dim} H={layout.horizon} D={layout.action_dim} h={layout.exec_steps} "
              f"{layout.action_space}")
    else:
        print(f"layout: E={layout.embedding_dim}; no detector reads the action batches (observation-only)")
    print(f"calibration {args.out} written (hash {calibration.content_hash}):")
    lengths = [r.length for r in successes]
    for line in [f"M = {len(successes)} successful rollouts fitted it ({sum(lengths)} steps, {min(lengths)} to "
                 f"{max(lengths)} per rollout)", *summary(calibration), *window_warnings(settings, successes)]:
        print(f"  {line}")
    return 0


def upgrade(args: argparse.Namespace) -> int:
    """``fiper calibrate --upgrade OLD -o NEW``: the calibration ``OLD`` of format 1 or 2 in the current format."""
    if args.upgrade is None or args.bags:
        raise UsageError("give either the bags to calibrate on or --upgrade OLD (a calibration to convert)")
    check_new(args.out, args.force)
    calibration = upgrade_calibration(args.upgrade)
    with atomic_output(args.out, args.force) as staging:
        calibration.save(staging)
    print(f"calibration {args.upgrade} converted to format {FORMAT_VERSION}: {args.out} written "
          f"(hash {calibration.content_hash})")
    return 0


def summary(calibration: Calibration) -> list[str]:
    """What the calibration fitted on which rollouts, and what it promises (lines to print)."""
    estimate, settings = calibration.false_alarms, calibration.settings
    lines = [f"judged by {judged_by(calibration.detectors, settings.combine)}",
             "windows: " + ", ".join(f"{info(d).label} {settings.window_of(d)} ({settings.aggregation_of(d)})"
                                     for d in calibration.detectors) + " policy steps"]
    for task, part in calibration.tasks.items():
        split = part.split
        where = f"task {task}: " if len(calibration.tasks) > 1 else ""
        lines.append(f"{where}split: {split['mode']}: {len(split['fit'])} successes fitted the models, "
                     f"{len(split['conformal'])} the thresholds"
                     + (f" ({len(split['folds'])} folds)" if "folds" in split else "")
                     + (f"; shapes cross-fitted in {len(split['shape_folds'])} folds" if "shape_folds" in split else ""))
        for detector in calibration.detectors:
            threshold = part.detectors[detector].threshold
            behind = ", ".join(f"{k} {v}" for k, v in split["behind_thresholds"][detector].items())
            lines.append(f"{where}threshold {info(detector).label}: {threshold.kind}, delta {threshold.delta:g}, "
                         f"gamma {value_range(threshold)} ({behind} rollouts)")
    if settings.combine_rule.joint and len(calibration.detectors) > 1:
        joint = calibration.joint
        pooled = f", k {joint['k']:.4g} over {joint['m']} conformal rollouts of every task" if "k" in joint else ""
        equalised = f", tails equalised ({settings.equalise})" if settings.equalise != "none" else ""
        lines.append(f"combine {settings.combine}: an alarm needs {settings.votes} of {len(calibration.detectors)} "
                     f"detectors above thresholds with one conformal factor{pooled}{equalised}")
    lines.append(f"false alarms on held-out successes, {estimate['method']}: {estimate['false_alarms']} of "
                 f"{estimate['rollouts']} ({estimate['rate']:.3f} +- {estimate['standard_error']:.3f})"
                 + ("" if estimate["held_out_from_models"] else "; optimistic: the models saw these rollouts"))
    lines.append(f"guarantee: {calibration.guarantee}")
    if settings.split == "same":
        lines.append("warning: same-data calibration (--same-data): not covered by Proposition 1")
    return lines


def _names(text: str) -> tuple[str, ...]:
    """``--detectors``: a comma list of names (checked with the other settings)."""
    return tuple(part.strip() for part in text.split(",") if part.strip())


def defaults_detectors() -> tuple[str, ...]:
    """The detectors calibrated without ``--detectors``: the settings' default (FIPER's pair)."""
    return CalibrationSettings().detectors


def _combine(text: str) -> str:
    """``--combine``: and, or, max or kth:K."""
    try:
        return str(Combine.parse(text))
    except ChoiceError as error:
        raise argparse.ArgumentTypeError(str(error)) from error


def _windows(text: str) -> dict[str, int]:
    """``--windows``: ``DETECTOR=W,...``."""
    windows = {}
    for part in (p.strip() for p in text.split(",") if p.strip()):
        name, _, value = part.partition("=")
        if not value.isdigit():
            raise argparse.ArgumentTypeError(f"--windows expects DETECTOR=W,..., got {part!r}")
        windows[name.strip()] = int(value)
    return windows


def value_range(threshold: Threshold) -> str:
    """``gamma_t`` of a threshold: its one value, or its first and last, rounded."""
    values = threshold.values
    return f"{values[0]:.4g}" if values.min() == values.max() else f"{values[0]:.4g} .. {values[-1]:.4g}"
