"""``fiper convert {sentinel,fiper,generic} SRC -o OUT``: reference datasets and users' logs -> FIPER bags.

OUT becomes a directory with one bag per split, ``calibration_rollouts/`` and ``test_rollouts/``;
rollout ids are numbered 1, 2, ... over both (calibration first) and the time line runs on from one
bag to the next, so the two can be replayed together. Each bag's ``custom_data`` names the source
file of every rollout. The converters unpickle their input (``generic``: its pickles): use them on trusted
data only.
"""
from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

from fiper_ros.bagio.atomic import atomic_output, check_new
from fiper_ros.bagio.errors import BagError, fail
from fiper_ros.bagio.rollout_bags import DEFAULT_START_NS, write_rollouts
from fiper_ros.bagio.schema import BagInfo
from fiper_ros.converters import fiper as convert_fiper, generic as convert_generic, sentinel as convert_sentinel
from fiper_ros.converters.options import DEFAULT_MAX_MB, EXEC_STEPS, ConvertOptions, Converted, Keys, parse_channels

#: format -> (loader, description of the source in custom_data)
FORMATS: dict[str, tuple[Callable[[Path, ConvertOptions], Converted], str]] = {
    "sentinel": (convert_sentinel.load, "Sentinel episode DataFrames"),
    "fiper": (convert_fiper.load, "FIPER rollout pickles"),
    "generic": (convert_generic.load, "rollout logs (npz, parquet, pickle)"),
}
SPLIT_ORDER = ("calibration", "test")


def bag_name(split: str) -> str:
    """Directory name of a split's bag."""
    return f"{split}_rollouts"


def convert(fmt: str, src: Path, out: Path, options: ConvertOptions, overwrite: bool = False) -> dict[str, int]:
    """Convert ``src`` (layout ``fmt``) into bags under ``out``; returns rollouts per written bag."""
    loader, description = FORMATS[fmt]
    check_new(Path(out), overwrite)  # before reading SRC, which may be large
    converted = loader(Path(src), options)
    counts: dict[str, int] = {}
    with atomic_output(Path(out), overwrite) as staging:
        staging.mkdir()
        now, next_id = DEFAULT_START_NS, 1
        for split in sorted(converted, key=lambda s: (SPLIT_ORDER.index(s) if s in SPLIT_ORDER else len(SPLIT_ORDER), s)):
            items = converted[split]
            ids = list(range(next_id, next_id + len(items)))
            info = BagInfo(task=items[0][0].task, synthetic=options.synthetic, split=split,
                           source=f"fiper convert {fmt}: {description} in {Path(src).name}",
                           rollout_sources={str(i): name for i, (_, name) in zip(ids, items)})
            now = write_rollouts(staging / bag_name(split), [r for r, _ in items], ids, info, start_ns=now,
                                 env_dt_ns=round(1e9 / options.control_hz))
            next_id += len(items)
            counts[bag_name(split)] = len(items)
    return counts


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``fiper convert``."""
    parser.add_argument("format", choices=sorted(FORMATS), help="layout of SRC (see docs/bags.md)")
    parser.add_argument("src", type=Path, help="Sentinel data directory, a FIPER <task> (or <task>/rollouts) "
                        "directory, or generic .npz/.parquet/.pkl files (a file or a directory of them)")
    parser.add_argument("-o", "--out", type=Path, required=True, help="output directory (one bag per split)")
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
    for option, field in convert_generic.KEY_OPTIONS.items():
        keys.add_argument(field, dest=f"{option}_key", default=getattr(Keys(), option), metavar="KEY",
                          help=f"default {getattr(Keys(), option)!r}")


def run(args: argparse.Namespace) -> int:
    """``fiper convert``."""
    try:
        keys = Keys(**{name: getattr(args, f"{name}_key") for name in convert_generic.KEY_OPTIONS})
        options = ConvertOptions(task=args.task, exec_steps=args.exec_steps, channels=parse_channels(args.channels),
                                 action_space=args.action_space, control_hz=args.control_hz,
                                 max_steps=args.max_steps, synthetic=args.synthetic, max_mb=args.max_mb,
                                 keys=keys)
        counts = convert(args.format, args.src, args.out, options, args.force)
    except BagError as error:
        return fail("convert", error)
    for name, count in counts.items():
        print(f"{args.out / name}: {count} rollouts")
    return 0
