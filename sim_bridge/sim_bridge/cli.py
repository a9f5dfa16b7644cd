"""Command line of the simulation core: ``python -m sim_bridge.cli {demos,eval,bench,figures}``."""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from .demos import EpisodeSummary, record_dataset
from .evaluate import expert_success, step_cost
from .figures import write_camera_figures
from .scenarios import SCENARIOS, TASK_NAMES


def _demos(args: argparse.Namespace) -> int:
    successes = 0

    def progress(index: int, summary: EpisodeSummary) -> None:
        nonlocal successes
        successes += summary.success
        state = "skipped (exists)" if summary.skipped else f"{summary.seconds:.1f} s"
        print(f"\r[{index + 1}/{args.episodes}] seed {summary.seed}: success={summary.success} "
              f"steps={summary.steps} {state}; successes {successes}/{index + 1}   ", end="", file=sys.stderr,
              flush=True)

    tasks = TASK_NAMES if args.task == "all" else (args.task,)
    for task in tasks:
        successes = 0
        out = Path(args.out) / task if args.task == "all" else Path(args.out)
        print(f"{task} -> {out}", file=sys.stderr)
        record_dataset(task, out, args.episodes, args.seed, args.scenario, progress)
        print(file=sys.stderr)
    return 0


def _eval(args: argparse.Namespace) -> int:
    tasks = TASK_NAMES if args.task == "all" else (args.task,)
    print("| task | scenario | kind | episodes | expert success | mean policy steps (successes) |")
    print("| --- | --- | --- | --- | --- | --- |")
    for task in tasks:
        names = list(SCENARIOS[task]) if args.scenario == "all" else [args.scenario]
        for name in names:
            episodes = args.episodes if name == "id" else args.ood_episodes
            result = expert_success(task, name, range(args.seed, args.seed + episodes))
            print(f"| {task} | {name} | {SCENARIOS[task][name].kind} | {result.episodes} | "
                  f"{result.rate:.2f} | {result.mean_policy_steps:.1f} |", flush=True)
    return 0


def _bench(args: argparse.Namespace) -> int:
    print("| task | sim + control [ms/step] | render 2 cameras [ms/step] | build model [ms] |")
    print("| --- | --- | --- | --- |")
    for task in TASK_NAMES:
        cost = step_cost(task, args.steps)
        print(f"| {task} | {cost.sim_ms:.2f} | {cost.render_ms:.2f} | {cost.build_ms:.0f} |", flush=True)
    return 0


def _figures(args: argparse.Namespace) -> int:
    for path in write_camera_figures(Path(args.out), args.seed):
        print(path)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point."""
    parser = argparse.ArgumentParser(prog="sim_bridge", description=__doc__)
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)
    demos = sub.add_parser("demos", help="record expert demonstrations (resumable)")
    demos.add_argument("--task", choices=(*TASK_NAMES, "all"), required=True,
                       help="a task, or 'all' (then OUT/<task> per task)")
    demos.add_argument("--episodes", type=int, default=100)
    demos.add_argument("--out", required=True, help="output folder, one .npz per episode (OUT/<task> with --task all)")
    demos.add_argument("--seed", type=int, default=0, help="seed of the first episode")
    demos.add_argument("--scenario", default="id")
    demos.set_defaults(func=_demos)
    evaluate = sub.add_parser("eval", help="expert success rates (markdown table)")
    evaluate.add_argument("--task", choices=(*TASK_NAMES, "all"), default="all")
    evaluate.add_argument("--scenario", default="all", help="scenario name or 'all'")
    evaluate.add_argument("--episodes", type=int, default=50, help="episodes of the ID scenario")
    evaluate.add_argument("--ood-episodes", type=int, default=20, help="episodes of every other scenario")
    evaluate.add_argument("--seed", type=int, default=1000, help="first seed")
    evaluate.set_defaults(func=_eval)
    bench = sub.add_parser("bench", help="per-control-step simulation and rendering cost")
    bench.add_argument("--steps", type=int, default=100)
    bench.set_defaults(func=_bench)
    figures = sub.add_parser("figures", help="write the camera PNGs of docs/sim.md")
    figures.add_argument("--out", default="docs/img")
    figures.add_argument("--seed", type=int, default=0)
    figures.set_defaults(func=_figures)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
