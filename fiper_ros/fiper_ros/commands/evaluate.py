"""``fiper evaluate``: FIPER and the baselines over rollout datasets, with the paper's protocol.

Examples::

    fiper evaluate --data sorting=rollouts/sorting.npz --data push_t=rollouts/push_t/ --out results/
    fiper evaluate --synthetic sorting,stacking,push_t --seeds 0,1,2 --protocol paper,clean --out results/
    fiper evaluate --data sorting=data/study/sorting --split same --out results-same/   # the paper's Remark 1

Each ``--data TASK=PATH[,PATH...]`` names a task and its rollout files (``RolloutSet.save_npz``) or
directories of them or of bags; data of several tasks (``fiper convert generic`` of many tasks) is one dataset per
task, named by the task. Bags without a split are split per task (``--calibration-fraction``,
``--calibration-seed``: a seeded fraction of each task's successes is calibration, as ``fiper convert`` splits
logs without one), and the split is printed. ``--synthetic`` generates the SYNTHETIC benchmark instead.
``--split`` chooses which calibration successes fit the score models and which the thresholds (default ``split``:
split conformal, as ``fiper calibrate``; ``cross``: K-fold cross-fitting; ``same``: the paper's same-data
calibration, not covered by Proposition 1). The output directory
receives ``results.md``, ``results.json`` and PNG figures. Per-step scores are cached in
``--cache-dir`` (default ``.cache/fiper-eval``), so a second run with other sweep or protocol options
only re-runs the sweep.

Observation-only data (rollouts without action batches): by default only the methods that need none are
evaluated (the elapsed time, PCA-kmeans, logpZO, RND-OE), with a note; ``--methods`` naming one that needs
action batches (ACE, FIPER, STAC, RND-A) is refused in one line.

``--scores NAME=FILE`` evaluates per-step scores computed elsewhere (:mod:`fiper_ros.evaluation.external`) as the
method ``external_<NAME>``, alone and in the default combination, like a built-in method. ``--dump DIR`` writes
every configuration's thresholds per step and first alarm per rollout (:mod:`fiper_ros.evaluation.dump`).
``--auto --auto-rule transfer`` chooses each task's configuration by a prior: of the other tasks' labelled metrics of
the run (two tasks or more), or ``--auto-prior FILE`` (:mod:`fiper_ros.evaluation.transfer`). ``--write-prior FILE``
writes the prior of every task of the run (its best ``--prior-top`` configurations), for ``fiper calibrate --auto
--auto-rule transfer --auto-prior FILE``; both rank by ``--prior-statistic``
(:data:`fiper_ros.core.transfer.STATISTICS`).
``--or-promise delta`` sets each threshold of an OR of ``N`` at ``delta / N``, so every table compares every
configuration at the promise delta (default ``entry``: the paper's, each at delta, promising ``N delta``).
``--ray [ADDRESS]`` computes the scores and the sweep as Ray tasks (:mod:`fiper_ros.evaluation.distributed`) on a
local instance (``--ray-cpus N`` CPUs) or an existing cluster, to the same results (docs/scale.md).
"""

from __future__ import annotations

import os

# One BLAS thread: on a shared 2-core machine multi-threaded OpenBLAS is several times slower (STAC's
# matrix products). Only effective when numpy is not imported yet, as under ``fiper evaluate``.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import logging
import shlex
import sys
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path

import numpy as np

from fiper_ros.bagio.atomic import atomic_files, check_directory
from fiper_ros.cluster import LOCAL
from fiper_ros.commands import ARGV, options
from fiper_ros.commands.errors import UsageError
from fiper_ros.core.auto import ENTRY_PROMISE, PROMISES
from fiper_ros.core.calibration import SPLITS
from fiper_ros.core.combination import SHAPE_KINDS
from fiper_ros.core.combine_mode import COMBINES
from fiper_ros.core.data_split import DEFAULT_FRACTION, DEFAULT_SEED, DataSplitError, check_draw
from fiper_ros.core.equalisation import DEFAULT_LEVEL, EQUALISATIONS
from fiper_ros.core.errors import ChoiceError
from fiper_ros.core.fusion import Combine
from fiper_ros.core.transfer import DEFAULT_STATISTICS, PRIOR_TOP, STATISTICS
from fiper_ros.evaluation.cache import DEFAULT_DIRECTORY, ScoreCache
from fiper_ros.evaluation.data import Dataset, DatasetError, load_datasets
from fiper_ros.evaluation.dump import INDEX
from fiper_ros.evaluation.early import DEFAULT_Q
from fiper_ros.evaluation.engine import EngineSettings, EvaluationResult, check_evaluation, run_evaluation, run_prior
from fiper_ros.evaluation.external import ExternalScores, parse_scores
from fiper_ros.evaluation.joint_sweep import JOINT_COMBINE_DEFAULTS
from fiper_ros.evaluation.methods import (ELAPSED, METHODS, Combination, MethodSettings, default_combinations,
                                          observation_methods, parse_combination, signal_methods)
from fiper_ros.evaluation.protocol import PROTOCOLS
from fiper_ros.evaluation.report import config_text, gain, write_reports
from fiper_ros.evaluation.sweep import DELTAS, MAX_POOL_WINDOWS, PAIR_GRIDS, SweepSettings
from fiper_ros.evaluation.synthetic import TASKS, make_task
from fiper_ros.evaluation.threshold_grid import GRID_KINDS

LOG = logging.getLogger(__name__)


def window_list(text: str) -> tuple[int, ...]:
    """:func:`~fiper_ros.commands.options.int_list`, or ``"none"`` for no windows."""
    return () if text == "none" else options.int_list(text)


def delta_list(text: str) -> tuple[float, ...]:
    """``"0.01,0.05"`` -> deltas; ``"paper"`` -> 0.01..0.10."""
    if text == "paper":
        return DELTAS
    deltas = tuple(float(part) for part in text.split(",") if part.strip())
    if not deltas:
        raise argparse.ArgumentTypeError(f"no deltas in {text!r}")
    return deltas


def name_list(choices: tuple[str, ...]) -> Callable[[str], tuple[str, ...]]:
    """A parser of comma-separated names from ``choices``."""

    def parse(text: str) -> tuple[str, ...]:
        names = tuple(part.strip() for part in text.split(",") if part.strip())
        unknown = [n for n in names if n not in choices]
        if unknown or not names:
            raise argparse.ArgumentTypeError(f"unknown {unknown or text!r}; choose from {', '.join(choices)}")
        return names

    return parse


def combine_list(text: str) -> tuple[str, ...]:
    """``"max,kth:2,and"`` -> combines (each checked by :meth:`Combine.parse`)."""
    combines = tuple(part.strip() for part in text.split(",") if part.strip())
    if not combines:
        raise argparse.ArgumentTypeError(f"no combines in {text!r}")
    for combine in combines:
        try:
            Combine.parse(combine)
        except ChoiceError as error:
            raise argparse.ArgumentTypeError(str(error)) from error
    return combines


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``fiper evaluate``."""
    data = parser.add_argument_group("data")
    data.add_argument("--data", action="append", default=[], metavar="TASK=PATH[,PATH]",
                      help="a task and its rollout .npz files or directories of them or of bags (repeatable; data "
                           "of several tasks: one dataset per task, named by the task)")
    data.add_argument("--calibration-fraction", type=float, default=DEFAULT_FRACTION,
                      help="bags without a split: fraction of each task's successes drawn into its calibration set "
                           f"(default {DEFAULT_FRACTION:g}; every other rollout is test), as fiper convert draws it")
    data.add_argument("--calibration-seed", type=int, default=DEFAULT_SEED,
                      help=f"seed of that draw (default {DEFAULT_SEED}; fiper convert's --split-seed)")
    data.add_argument("--synthetic", type=name_list(tuple(TASKS)), metavar="TASKS",
                      help=f"generate the SYNTHETIC benchmark for these tasks ({', '.join(TASKS)})")
    data.add_argument("--synthetic-test", type=int, default=240, help="synthetic test rollouts per task")
    data.add_argument("--synthetic-scale", type=float, default=1.0, help="shrink synthetic shapes (tests)")
    options.add_strict_argument(data)
    sweep = parser.add_argument_group("sweep")
    sweep.add_argument("--methods", type=name_list(tuple(METHODS)), default=None,
                       help="comma list (default: all; on observation-only data those that need no action batches)")
    sweep.add_argument("--windows", type=options.int_list, default=tuple(range(1, 51)), help="e.g. 1-50 (default)")
    sweep.add_argument("--no-cumulative", action="store_true", help="do not sweep the cumulative sum")
    sweep.add_argument("--max-pool", type=window_list, default=MAX_POOL_WINDOWS,
                       help="max-pooled windows, e.g. 2-10 or none (default: "
                            f"{','.join(map(str, MAX_POOL_WINDOWS))})")
    sweep.add_argument("--deltas", type=delta_list, default=DELTAS, help="comma list or 'paper' (0.01..0.10)")
    sweep.add_argument("--thresholds", type=name_list(GRID_KINDS), default=None,
                       help=f"comma list of {', '.join(GRID_KINDS)} (default: all; with --pool: "
                            f"{', '.join(SHAPE_KINDS)})")
    sweep.add_argument("--combines", type=name_list(COMBINES), default=COMBINES)
    sweep.add_argument("--pairs", choices=PAIR_GRIDS, default="coarse", help="FIPER (w_O, w_A) grid")
    sweep.add_argument("--or-promise", choices=tuple(PROMISES), default=ENTRY_PROMISE,
                       help="an OR of N thresholds: entry (each at delta, the paper's: promise N delta) or delta (each "
                            "at delta / N: every table at equal promise; needs --auto-promise delta, the default)")
    sweep.add_argument("--signals", type=lambda text: tuple(p.strip() for p in text.split(",") if p.strip()),
                       default=(), metavar="NAMES",
                       help="logged per-step signals of the rollouts to evaluate as detectors (signal_<name>), alone "
                            "and in the default combination, e.g. chunk_mse,eef_speed_3d")
    sweep.add_argument("--scores", action="append", default=[], metavar="NAME=FILE",
                       help="per-step scores of a detector computed elsewhere, to evaluate as the method "
                            "external_<NAME>, alone and in the default combination (repeatable): a .json or .npz of "
                            "{rollout_id: [one score >= 0 per policy step]} for every calibration success and test "
                            "rollout")
    sweep.add_argument("--combo", action="append", default=[], metavar="NAME=DETECTOR+DETECTOR...",
                       help="a combination of detectors (streams) to evaluate besides the default ones (repeatable; "
                            "e.g. obs=rnd_oe+logpzo+elapsed)")
    sweep.add_argument("--no-default-combos", action="store_true",
                       help="evaluate no combination but those of --combo (default: FIPER's pair under one "
                            "threshold and every evaluated stream combined)")
    sweep.add_argument("--combo-combines", type=combine_list, default=JOINT_COMBINE_DEFAULTS,
                       help="how a combination of several detectors votes: comma list of max, kth:K, and, or "
                            f"(default {','.join(JOINT_COMBINE_DEFAULTS)})")
    sweep.add_argument("--equalise", type=name_list(EQUALISATIONS[1:]), default=(), metavar="KINDS",
                       help="also evaluate every combination of several detectors with its joint combines' tails "
                            "equalised, as NAME_KIND per kind: comma list of quantile, tail (fiper calibrate "
                            "--equalise)")
    sweep.add_argument("--equalise-level", type=float, default=DEFAULT_LEVEL, metavar="Q",
                       help=f"with --equalise quantile: the quantile of the maxima mapped to 1 (default {DEFAULT_LEVEL:g})")
    sweep.add_argument("--pool", action="store_true",
                       help="one threshold per configuration pooled over the tasks (each task normalised by its own "
                            "shapes): for many tasks with few successes each; the promise is then over all tasks")
    protocol = parser.add_argument_group("protocol")
    protocol.add_argument("--protocol", type=name_list(PROTOCOLS), default=("paper",),
                          help="comma list: paper (select and report on all test rollouts), clean (select on a "
                               "validation half), loto (each task's configuration selected on the other tasks; two "
                               "tasks or more), clean-task (each task's configuration selected on its own validation "
                               "half), paper-task (each task's selected and reported on its own test rollouts: the "
                               "per-task ceiling, not a result)")
    protocol.add_argument("--auto", action="store_true",
                          help="also choose each task's configuration as fiper calibrate --auto does, from its "
                               "calibration successes alone, and report it beside the protocols")
    options.add_auto_arguments(protocol)
    protocol.add_argument("--q-auc", type=float, default=DEFAULT_Q, metavar="Q",
                          help="the q-AUC's early cut: each rollout's maximum over its first ceil(Q T_max) steps "
                               f"(default {DEFAULT_Q:g})")
    protocol.add_argument("--seeds", type=options.int_list, default=(0,), help="e.g. 0-4")
    protocol.add_argument("--split-seed", type=int, default=0, help="clean protocol's validation split")
    protocol.add_argument("--select-cumulative", action="store_true",
                          help="let the selection also pick the cumulative sum (paper: windows only)")
    protocol.add_argument("--default-window", type=int, default=5)
    protocol.add_argument("--default-threshold", choices=GRID_KINDS, default="cp_band")
    methods = parser.add_argument_group("methods")
    methods.add_argument("--split", choices=SPLITS, default="split",
                         help="calibration successes for the score models and for the thresholds: split conformal "
                              "(default), cross-fitted, or the paper's same data (not covered by Prop. 1)")
    methods.add_argument("--profile", choices=("paper", "reference"), default="paper")
    methods.add_argument("--shape-folds", type=int, default=0, metavar="K",
                         help="with --split split: thresholds' per-step shapes from K-fold cross-fitted fit-part "
                              "scores (0: in-sample, the default)")
    methods.add_argument("--tiny", action="store_true", help="tiny networks and budgets (smoke tests only)")
    options.add_robot_arguments(methods)
    output = parser.add_argument_group("output")
    output.add_argument("--out", type=Path, required=True, help="output directory")
    output.add_argument("--cache-dir", type=Path, default=DEFAULT_DIRECTORY)
    output.add_argument("--no-cache", action="store_true")
    output.add_argument("--no-plots", action="store_true")
    output.add_argument("--dump", type=Path, default=None, metavar="DIR",
                        help="also write every configuration's thresholds per step and first alarm per rollout: one "
                             f".npz per task and seed and {INDEX} naming the configurations (docs/evaluation.md)")
    output.add_argument("--write-prior", type=Path, default=None, metavar="FILE",
                        help="also write the prior of every task of the run for fiper calibrate --auto --auto-rule "
                             "transfer: its best --prior-top configurations a calibration can declare, ranked by their "
                             "--prior-statistic on all test rollouts (docs/method.md, 'The third rule')")
    output.add_argument("--prior-top", type=int, default=PRIOR_TOP, metavar="N",
                        help=f"entries a prior made of the run keeps (default {PRIOR_TOP})")
    output.add_argument("--prior-statistic", choices=tuple(STATISTICS), default=None,
                        help="what a prior made of the run ranks its configurations by: the transfer rule's "
                             "leave-one-task-out priors and --write-prior's, at the promise of --auto-promise "
                             "(default " + ", ".join(f"{s} at {p}" for p, s in DEFAULT_STATISTICS.items())
                             + "; docs/method.md, 'The third rule')")
    output.add_argument("--quiet", action="store_true", help="no progress lines")
    cluster = parser.add_argument_group("cluster")
    cluster.add_argument("--ray", nargs="?", const=LOCAL, default=None, metavar="ADDRESS",
                         help="compute the scores as Ray tasks, one per task, seed and stream, and the sweep, one per "
                              "seed; without ADDRESS on a "
                              "local Ray instance bound to 127.0.0.1, with 'auto', HOST:PORT or ray://HOST:10001 on "
                              "that cluster (docs/scale.md); the results are those of the single-process run")
    cluster.add_argument("--ray-cpus", type=int, default=None, metavar="N",
                         help="CPUs of the local Ray instance of --ray (default: all cores)")


def datasets_from(args: argparse.Namespace) -> list[Dataset]:
    """The datasets named by ``--data`` and ``--synthetic``."""
    datasets: list[Dataset] = []
    try:
        check_draw(args.calibration_fraction, args.calibration_seed, ("--calibration-fraction", "--calibration-seed"))
    except DataSplitError as error:
        raise DatasetError(str(error)) from error
    for spec in args.data:
        task, sep, paths = spec.partition("=")
        if not sep or not task or not paths:
            raise DatasetError(f"--data expects TASK=PATH[,PATH...], got {spec!r}")
        loaded, drawn = load_datasets(task, paths.split(","), strict=args.strict, fraction=args.calibration_fraction,
                                      seed=args.calibration_seed)
        datasets += loaded
        if drawn:
            print(f"fiper evaluate: {task}: no split in the data: drawn per task with --calibration-fraction "
                  f"{args.calibration_fraction:g} --calibration-seed {args.calibration_seed}:")
            for split in drawn.values():
                print(f"  {split.summary()}")
    for task in args.synthetic or ():
        rollouts = make_task(task, test=args.synthetic_test, scale=args.synthetic_scale)
        datasets.append(Dataset(task, rollouts.calibration, rollouts.test))
    if not datasets:
        raise DatasetError("no data: give --data TASK=PATH and/or --synthetic TASKS")
    return datasets


def methods_for(requested: tuple[str, ...] | None, datasets: list[Dataset]) -> tuple[str, ...]:
    """The methods to evaluate: ``requested`` (``None``: all), and on observation-only data those that need no
    action batches (a requested one that needs them is a :class:`DatasetError`)."""
    methods = requested or tuple(METHODS)
    without = [d.task for d in datasets if not d.has_actions]
    needing = [METHODS[m].label for m in methods if METHODS[m].needs_actions]
    if not without or not needing:
        return methods
    kept = observation_methods(methods)
    what = f"task(s) {', '.join(without)} have no action batches (observation-only data)"
    cannot = f"{', '.join(needing)} cannot run without them"
    if requested is not None:
        kept = kept or observation_methods(tuple(METHODS))
        raise DatasetError(f"{what}; {cannot}: evaluate {', '.join(METHODS[m].label for m in kept)} "
                           f"(--methods {','.join(kept)})")
    print(f"fiper evaluate: {what}; {cannot}: evaluating {', '.join(METHODS[m].label for m in kept)}", file=sys.stderr)
    return kept


def settings_from(args: argparse.Namespace, external: tuple[ExternalScores, ...] = ()) -> EngineSettings:
    """Engine settings from the parsed options (``--methods`` resolved by :func:`methods_for`, with the methods
    of the ``external`` scores of ``--scores``)."""
    method_settings = MethodSettings.tiny(args.profile) if args.tiny else MethodSettings(profile=args.profile)
    method_settings = replace(method_settings, robot=options.robot_from(args), split=args.split,
                              shape_folds=args.shape_folds, external=external)
    kinds = args.thresholds or (SHAPE_KINDS if args.pool else SweepSettings().kinds)
    sweep = SweepSettings(windows=args.windows, cumulative=not args.no_cumulative, deltas=args.deltas,
                          kinds=kinds, combines=args.combines, pairs=args.pairs, max_pool=args.max_pool,
                          or_promise=args.or_promise)
    return EngineSettings(methods=args.methods, seeds=args.seeds, sweep=sweep, method_settings=method_settings,
                          protocols=args.protocol, split_seed=args.split_seed, default_window=args.default_window,
                          default_kind=args.default_threshold,
                          select_aggregations=("window", "max", "cumulative") if args.select_cumulative
                          else ("window", "max"),
                          progress=not args.quiet, combinations=combinations_from(args),
                          combines=args.combo_combines, pooled=args.pool, q_auc=args.q_auc,
                          auto=options.auto_from(args), auto_prior=options.prior_from(args, default=False),
                          prior_top=args.prior_top, prior_statistic=args.prior_statistic, promise=args.auto_promise)


def combinations_from(args: argparse.Namespace) -> tuple[Combination, ...]:
    """The default combinations of the evaluated methods (unless ``--no-default-combos``, or a split without a fit
    part) and ``--combo``'s, and each of several detectors again per ``--equalise`` kind (``<name>_<kind>``)."""
    signals = signal_methods(args.signals)
    defaults = not args.no_default_combos and args.split == "split"  # the shapes need a fit part
    chosen = list(signals)
    if defaults:
        chosen += default_combinations(args.methods, tuple(s.name for s in signals))
    chosen += [parse_combination(text) for text in args.combo]
    chosen += [c.equalised(kind, args.equalise_level) for c in list(chosen) if len(c.detectors) > 1
               for kind in args.equalise]
    return tuple(chosen)


def summary(result: EvaluationResult, markdown: Path) -> str:
    """The closing line: size, time, cache and the best method by average TWA (and its gain over the
    elapsed-time baseline)."""
    protocol = next(iter(result.protocols.values()))
    ranked = sorted(protocol.selected.values(), key=lambda r: -np.nan_to_num(r.average()[0][0], nan=-np.inf))
    label = result.settings.catalogue()[ranked[0].method].label
    config = "chosen per task" if ranked[0].per_task_choice else config_text(ranked[0].group)
    best = f"best TWA {label} {ranked[0].average()[0][0]:.3f} ({config}"
    floor = protocol.selected.get(ELAPSED)
    best += f", {gain(ranked[0], floor, None)[0]:+.3f} over the elapsed time)" if floor is not None else ")"
    t = result.timings
    return (f"fiper evaluate: {len(result.tasks)} task(s), {len(result.settings.methods)} method(s), "
            f"{len(result.settings.seeds)} seed(s), {len(result.groups) * len(result.settings.sweep.deltas)} "
            f"configurations per task and seed; scores {t['scores']:.1f} s (cache {result.cache_hits} hit(s), "
            f"{result.cache_misses} miss(es)), sweep {t['sweep']:.1f} s; {best} [{protocol.protocol} protocol] "
            f"-> {markdown}")


def check_cluster(args: argparse.Namespace) -> None:
    """Refuse ``--ray-cpus`` without a local Ray instance (:class:`UsageError`)."""
    if args.ray_cpus is None:
        return
    if args.ray is None:
        raise UsageError("--ray-cpus sets the CPUs of the local Ray instance of --ray: give --ray too")
    if args.ray != LOCAL:
        raise UsageError(f"--ray-cpus sets the CPUs of a local Ray instance: the cluster at {args.ray} has its own")
    if args.ray_cpus < 1:
        raise UsageError(f"--ray-cpus must be >= 1, got {args.ray_cpus}")


def run(args: argparse.Namespace) -> int:
    """Run the evaluation; 0 on success, 2 on bad input."""
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    if args.default_window not in args.windows:  # before any data is read
        raise UsageError(f"the default window {args.default_window} is not among the swept windows")
    check_directory(args.out)
    for directory in ([] if args.no_cache else [args.cache_dir]) + ([] if args.dump is None else [args.dump]):
        check_directory(directory)
    datasets = datasets_from(args)
    external = parse_scores(args.scores)
    args.methods = (*methods_for(args.methods, datasets), *(e.stream for e in external))
    settings = settings_from(args, external)
    options.fk_of(settings.method_settings.robot)
    check_evaluation(datasets, settings)
    check_cluster(args)
    if args.write_prior is not None:
        if not args.write_prior.parent.is_dir():
            raise UsageError(f"--write-prior {args.write_prior}: no directory {args.write_prior.parent}")
    cache = None if args.no_cache else ScoreCache(args.cache_dir)
    # +inf CP thresholds (ceil((M+1)(1-delta)) > M for the smallest deltas) are expected in a sweep.
    threshold_log = logging.getLogger("fiper_ros.core.thresholds")
    previous = threshold_log.level
    threshold_log.setLevel(logging.ERROR)
    try:
        # Written beside --out (and --dump) and moved in when complete: a failed run leaves no partial results.
        with ExitStack() as dumped:
            dump = None if args.dump is None else dumped.enter_context(atomic_files(args.dump))
            result = run_evaluation(datasets, settings, cache, dump, args.ray, args.ray_cpus)
            with atomic_files(args.out) as staging:
                figures: list[str] = []
                if not args.no_plots:
                    from fiper_ros.evaluation.plots import write_figures  # noqa: PLC0415 - matplotlib

                    figures = write_figures(result, staging)
                markdown, _ = write_reports(result, staging, figures)
    finally:
        threshold_log.setLevel(previous)
    print(summary(result, args.out / markdown.name) + ("" if args.dump is None else f"; dump -> {args.dump / INDEX}"))
    if args.write_prior is not None:
        argv = getattr(args, ARGV, None)
        prior = run_prior(result, shlex.join(argv) if argv else "fiper evaluate (command line not given)")
        prior.save(args.write_prior)
        print(f"fiper evaluate: prior of {', '.join(prior.tasks)} ({len(prior.entries)} entries, hash "
              f"{prior.content_hash[:12]}) -> {args.write_prior}")
    return 0
