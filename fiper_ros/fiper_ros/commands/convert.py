"""``fiper convert {sentinel,fiper,generic} SRC -o OUT``: reference datasets and users' logs -> FIPER bags.

OUT becomes a directory with one bag per split, ``calibration_rollouts/`` and ``test_rollouts/``, or, when the
rollouts are of several tasks (``generic``), one such pair per task in ``OUT/<task>/``; rollout ids are numbered
1, 2, ... over all bags (task by task in name order, calibration first) and the time line runs on from one bag to
the next, so they can be replayed together. Each bag's ``custom_data`` names the source file of every rollout.
Logs without a split (``generic``) are split here: per task, a seeded ``--calibration-fraction`` of the successes
is calibration, every other rollout test (:mod:`fiper_ros.core.data_split`); the split is printed, written to
``OUT/split.json`` and named in the bags' ``custom_data`` (``split_rule``). The converters unpickle their input
(``generic``: its pickles): use them on trusted data only.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fiper_ros.bagio.atomic import atomic_output, check_new
from fiper_ros.bagio.errors import BagError
from fiper_ros.bagio.rollout_bags import DEFAULT_START_NS, write_rollouts
from fiper_ros.bagio.schema import BagInfo
from fiper_ros.commands.options import parse_channels
from fiper_ros.converters import fiper as convert_fiper, generic as convert_generic, sentinel as convert_sentinel
from fiper_ros.converters.options import DEFAULT_MAX_MB, EXEC_STEPS, ConvertOptions, Converted, Keys
from fiper_ros.core.data_split import (DEFAULT_FRACTION, DEFAULT_SEED, NO_SPLIT, SPLITS, DataSplitError, TaskSplit,
                                       describe, split_by_task)
from fiper_ros.core.rollout import Rollout

#: format -> (loader, description of the source in custom_data)
FORMATS: dict[str, tuple[Callable[[Path, ConvertOptions], Converted], str]] = {
    "sentinel": (convert_sentinel.load, "Sentinel episode DataFrames"),
    "fiper": (convert_fiper.load, "FIPER rollout pickles"),
    "generic": (convert_generic.load, "rollout logs (npz, parquet, pickle)"),
}
#: The file of a drawn split in OUT, and its format version.
SPLIT_FILE = "split.json"
SPLIT_FORMAT_VERSION = 1
#: What a task's name must be to name its folder in OUT (a conversion of several tasks).
TASK_FOLDER = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")


def bag_name(split: str) -> str:
    """Directory name of a split's bag."""
    return f"{split}_rollouts"


@dataclass
class Conversion:
    """What a conversion wrote.

    Attributes:
        bags: Each bag (relative to OUT) and its number of rollouts, in the order written.
        drawn: Per task, the split drawn for data without one (empty when the source gave it).
    """

    bags: dict[str, int] = field(default_factory=dict)
    drawn: dict[str, TaskSplit] = field(default_factory=dict)


def _draw(items: list[tuple[Rollout, str]],
          options: ConvertOptions) -> tuple[Converted, dict[str, TaskSplit], dict[str, Any]]:
    """The split of rollouts without one (``items``: rollout and source), the drawn split per task and the content
    of :data:`SPLIT_FILE`."""
    try:
        drawn = split_by_task(items, lambda item: item[0], options.calibration_fraction, options.split_seed)
    except DataSplitError as error:
        raise BagError(str(error)) from error
    converted: Converted = {split: [] for split in SPLITS}
    tasks: dict[str, Any] = {}
    for task, part in drawn.items():
        converted["calibration"] += part.calibration
        converted["test"] += part.test
        tasks[task] = {"successes": part.split.successes, "failures": part.split.failures,
                       "calibration": [source for _, source in part.calibration],
                       "test": [source for _, source in part.test]}
    content = {"format_version": SPLIT_FORMAT_VERSION,
               "rule": describe(options.calibration_fraction, options.split_seed),
               "calibration_fraction": options.calibration_fraction, "split_seed": options.split_seed, "tasks": tasks}
    content["content_hash"] = hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()
    return converted, {task: part.split for task, part in drawn.items()}, content


def _folders(converted: Converted) -> dict[str, str]:
    """Task -> its folder in OUT: OUT itself for one task, else ``OUT/<task>`` (names checked)."""
    tasks = sorted({rollout.task for items in converted.values() for rollout, _ in items})
    if len(tasks) == 1:
        return {tasks[0]: ""}
    for task in tasks:
        if not TASK_FOLDER.fullmatch(task) or task in {bag_name(s) for s in SPLITS}:
            raise BagError(f"task {task!r} cannot name its folder of bags in a conversion of several tasks "
                           f"({', '.join(tasks)}): give task names of letters, digits, _, - and .")
    return {task: task for task in tasks}


def convert(fmt: str, src: Path, out: Path, options: ConvertOptions, overwrite: bool = False) -> Conversion:
    """Convert ``src`` (layout ``fmt``) into bags under ``out``; returns what was written."""
    loader, description = FORMATS[fmt]
    check_new(Path(out), overwrite)  # before reading SRC, which may be large
    converted = loader(Path(src), options)
    result, split_file, rule = Conversion(), None, ""
    if NO_SPLIT in converted:
        converted, result.drawn, split_file = _draw(converted.pop(NO_SPLIT), options)
        rule = describe(options.calibration_fraction, options.split_seed)
    splits = sorted(converted, key=lambda s: (SPLITS.index(s) if s in SPLITS else len(SPLITS), s))
    with atomic_output(Path(out), overwrite) as staging:
        staging.mkdir()
        now, next_id = DEFAULT_START_NS, 1
        for task, folder in _folders(converted).items():
            for split in splits:
                items = [(rollout, source) for rollout, source in converted[split] if rollout.task == task]
                if not items:
                    continue
                ids = list(range(next_id, next_id + len(items)))
                info = BagInfo(task=task, synthetic=options.synthetic, split=split, split_rule=rule,
                               source=f"fiper convert {fmt}: {description} in {Path(src).name}",
                               rollout_sources={str(i): name for i, (_, name) in zip(ids, items)})
                bag = str(Path(folder) / bag_name(split))
                (staging / bag).parent.mkdir(parents=True, exist_ok=True)
                now = write_rollouts(staging / bag, [r for r, _ in items], ids, info, start_ns=now,
                                     env_dt_ns=round(1e9 / options.control_hz))
                next_id += len(items)
                result.bags[bag] = len(items)
        if split_file is not None:
            (staging / SPLIT_FILE).write_text(json.dumps(split_file, indent=1) + "\n")
    return result


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``fiper convert``."""
    parser.add_argument("format", choices=sorted(FORMATS), help="layout of SRC (see docs/bags.md)")
    parser.add_argument("src", type=Path, help="Sentinel data directory, a FIPER <task> (or <task>/rollouts) "
                        "directory, or generic .npz/.parquet/.pkl files (a file or a directory of them)")
    parser.add_argument("-o", "--out", type=Path, required=True,
                        help="output directory (one bag per split; with several tasks, per task and split)")
    parser.add_argument("--task", default="", help="task name (default: the source directory's name)")
    parser.add_argument("--exec-steps", type=int, default=0,
                        help=f"h, actions executed per chunk (default: from the data, else the paper's {EXEC_STEPS})")
    parser.add_argument("--channels", default="auto",
                        help="action channels kept, START:STOP, 'all' or 'auto' (Sentinel: D=7 keeps 1:4, else all)")
    parser.add_argument("--action-space", default="ee_position", help="action space of the kept channels")
    parser.add_argument("--control-hz", type=float, default=10.0, help="environment steps per second (bag time line)")
    parser.add_argument("--max-steps", type=int, default=0, help="maximum policy steps of a rollout (0: unknown)")
    parser.add_argument("--synthetic", action="store_true", help="mark the bags as synthetic data")
    parser.add_argument("--max-mb", type=float, default=DEFAULT_MAX_MB,
                        help="the most one conversion reads, MB: source files and converted arrays "
                             f"(default {DEFAULT_MAX_MB:g})")
    parser.add_argument("--force", action="store_true", help="replace OUT if it exists")
    keys = parser.add_argument_group("generic format", "names of the fields of the generic files (docs/bags.md)")
    for option, key in convert_generic.KEY_OPTIONS.items():
        default = getattr(Keys(), option)
        keys.add_argument(key, dest=f"{option}_key", default=default, metavar="KEY",
                          help=f"default {default!r}" if default else "per-step signals [N, K] or [N] (default: none)")
    keys.add_argument("--signal-names", default="", metavar="A,B,...",
                      help="names of the K columns of --signals-key (a [N] key: default the key's name)")
    split = parser.add_argument_group("no split given", "logs without a split key or split directory (generic)")
    split.add_argument("--calibration-fraction", type=float, default=DEFAULT_FRACTION,
                       help=f"fraction of each task's successes drawn into its calibration set (default "
                            f"{DEFAULT_FRACTION:g}); every other rollout is test")
    split.add_argument("--split-seed", "--calibration-seed", dest="split_seed", type=int, default=DEFAULT_SEED,
                       help=f"seed of that draw (default {DEFAULT_SEED}; fiper evaluate: --calibration-seed)")


def run(args: argparse.Namespace) -> int:
    """``fiper convert``."""
    keys = Keys(**{name: getattr(args, f"{name}_key") for name in convert_generic.KEY_OPTIONS})
    names = tuple(name.strip() for name in args.signal_names.split(",") if name.strip())
    options = ConvertOptions(task=args.task, exec_steps=args.exec_steps, channels=parse_channels(args.channels),
                             action_space=args.action_space, control_hz=args.control_hz,
                             max_steps=args.max_steps, synthetic=args.synthetic, max_mb=args.max_mb,
                             keys=keys, signal_names=names, calibration_fraction=args.calibration_fraction,
                             split_seed=args.split_seed)
    result = convert(args.format, args.src, args.out, options, args.force)
    for name, count in result.bags.items():
        print(f"{args.out / name}: {count} rollouts")
    if result.drawn:
        print(f"no split given: drawn per task with --calibration-fraction {args.calibration_fraction:g} "
              f"--split-seed {args.split_seed} ({args.out / SPLIT_FILE}):")
        for split in result.drawn.values():
            print(f"  {split.summary()}")
    return 0
