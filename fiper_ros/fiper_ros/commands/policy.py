"""Command line: ``python -m fiper_ros.commands.policy {train,eval,plot,fit}``.

Examples::

    python -m fiper_ros.commands.policy train --task sorting --demos data/demos/sorting --out models/sorting
    python -m fiper_ros.commands.policy eval --task sorting --scenario id --episodes 50 --seed 1000 --record r.npz
    python -m fiper_ros.commands.policy fit --task stacking --model runs/models/stacking --demos data/demos/stacking
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

import torch

from fiper_ros.commands.errors import UsageError
from fiper_ros.errors import FiperError, fail
from fiper_ros.policy.config import PRESETS


def _train(args: argparse.Namespace) -> int:
    from fiper_ros.policy.train import train  # noqa: PLC0415

    overrides = {"epochs": args.epochs} if args.epochs is not None else {}
    config = PRESETS[args.task].with_overrides(**overrides)
    run_dir = Path(args.run_dir or f"runs/policy/{args.task}_seed{args.seed}")
    train(config, args.demos, args.out, run_dir, seed=args.seed, max_episodes=args.max_episodes,
          stop_after=args.stop_after)
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


def _eval(args: argparse.Namespace) -> int:
    from sim_bridge.policy_evaluation import EvaluationResult, evaluate, save_rollouts  # noqa: PLC0415
    from fiper_ros.policy.policy import Policy  # noqa: PLC0415
    from sim_bridge.closed_loop import EpisodeResult  # noqa: PLC0415

    policy = Policy.load(args.model or f"models/{args.task}")
    if policy.config.task != args.task:
        raise SystemExit(f"model {args.model} is a {policy.config.task} policy, not {args.task}")
    successes = 0

    def progress(index: int, episode: EpisodeResult) -> None:
        nonlocal successes
        successes += episode.success
        print(f"[{index + 1}/{args.episodes}] {args.scenario} seed {episode.seed}: success={episode.success} "
              f"policy steps {episode.policy_steps}; successes {successes}/{index + 1}", file=sys.stderr, flush=True)

    seeds = range(args.seed, args.seed + args.episodes)
    result: EvaluationResult = evaluate(policy, args.scenario, seeds, record=args.record is not None,
                                        progress=progress)
    if args.record is not None:
        save_rollouts([result], args.record, args.split)
    print(f"| {args.task} | {args.scenario} | {len(result.episodes)} | {result.success_rate:.2f} | "
          f"{result.mean_policy_steps:.1f} | seeds {args.seed}-{args.seed + args.episodes - 1} |")
    return 0


def _plot(args: argparse.Namespace) -> int:
    from sim_bridge.multimodality import plot_multimodality  # noqa: PLC0415
    from fiper_ros.policy.policy import Policy  # noqa: PLC0415

    policy = Policy.load(args.model or f"models/{args.task}")
    out = args.out or f"docs/img/policy_multimodality_{args.task}.png"
    print(plot_multimodality(policy, args.seeds, out))
    return 0


def _fit(args: argparse.Namespace) -> int:
    from fiper_ros.policy.dataset import episode_files  # noqa: PLC0415
    from fiper_ros.policy.fit import open_loop_fit  # noqa: PLC0415
    from fiper_ros.policy.policy import Policy  # noqa: PLC0415

    policy = Policy.load(args.model or f"models/{args.task}")
    files = episode_files(args.demos)
    outside = [i for i in args.episodes if not 0 <= i < len(files)]
    if outside:
        raise UsageError(f"--episodes {outside}: {args.demos} has episodes 0..{len(files) - 1}")
    chosen = [files[i] for i in args.episodes]
    report = open_loop_fit(policy, chosen, args.batch, args.stride, args.seed)
    print(f"{args.task}: {report.states} states of {len(chosen)} demonstration episodes, B = {args.batch}")
    print("| action dim | error of the sample mean | sample spread (std) | expert magnitude | error / magnitude |")
    print("| ---: | ---: | ---: | ---: | ---: |")
    for d, (err, spread, mag) in enumerate(zip(report.error, report.spread, report.magnitude, strict=True)):
        print(f"| {d} | {err:.3f} | {spread:.3f} | {mag:.3f} | {err / max(mag, 1e-9):.2f} |")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point: a user error (:class:`~fiper_ros.errors.FiperError`) is one line ``fiper policy: ...``, exit
    status 2, as ``fiper`` prints it; any other exception keeps its traceback."""
    parser = argparse.ArgumentParser(prog="fiper_ros.commands.policy", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    parser.add_argument("--threads", type=int, default=1,
                        help="torch threads (1 is fastest on the shared 2-core machine, see docs/policies.md)")
    sub = parser.add_subparsers(dest="command", required=True)
    train = sub.add_parser("train", help="train a policy on demonstrations (resumes from the run folder)")
    train.add_argument("--task", choices=sorted(PRESETS), required=True)
    train.add_argument("--demos", required=True, help="folder of episode_*.npz files")
    train.add_argument("--out", required=True, help="model folder (policy.pt + policy.yaml)")
    train.add_argument("--epochs", type=int, default=None, help="override the preset's epochs")
    train.add_argument("--seed", type=int, default=0)
    train.add_argument("--max-episodes", type=int, default=None, help="use only the first N demo files")
    train.add_argument("--stop-after", type=int, default=None,
                       help="write the model after this many epochs of the schedule (rerun without it to go on)")
    train.add_argument("--run-dir", default=None, help="checkpoint folder (default runs/policy/<task>_seed<S>)")
    train.set_defaults(func=_train)
    evaluate = sub.add_parser("eval", help="closed-loop success rate in the simulation (optionally recorded)")
    evaluate.add_argument("--task", choices=sorted(PRESETS), required=True)
    evaluate.add_argument("--scenario", default="id")
    evaluate.add_argument("--episodes", type=int, default=50)
    evaluate.add_argument("--seed", type=int, default=1000, help="first episode seed (demos use 0..N-1)")
    evaluate.add_argument("--model", default=None, help="model folder (default models/<task>)")
    evaluate.add_argument("--record", default=None, help="save the rollouts as a core RolloutSet .npz")
    evaluate.add_argument("--split", choices=("test", "calibration"), default="test",
                          help="RolloutSet split of the recorded rollouts")
    evaluate.set_defaults(func=_eval)
    plot = sub.add_parser("plot", help="multimodality figure: sampled chunks at initial states (top view)")
    plot.add_argument("--task", choices=sorted(PRESETS), required=True)
    plot.add_argument("--model", default=None, help="model folder (default models/<task>)")
    plot.add_argument("--seeds", type=int, nargs="+", default=[1000, 1001, 1002])
    plot.add_argument("--out", default=None, help="PNG path (default docs/img/policy_multimodality_<task>.png)")
    plot.set_defaults(func=_plot)
    fit = sub.add_parser("fit", help="open-loop fit: sampled chunks against the expert's on demonstration states")
    fit.add_argument("--task", choices=sorted(PRESETS), required=True)
    fit.add_argument("--model", default=None, help="model folder (default models/<task>)")
    fit.add_argument("--demos", required=True, help="folder of episode_*.npz files")
    fit.add_argument("--episodes", type=int, nargs="+", default=[0, 50, 100, 150], help="indices of episode files")
    fit.add_argument("--stride", type=int, default=4, help="every stride-th state of an episode")
    fit.add_argument("--batch", type=int, default=16, help="chunks sampled per state")
    fit.add_argument("--seed", type=int, default=0, help="noise seed of every state")
    fit.set_defaults(func=_fit)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    torch.set_num_threads(args.threads)
    try:
        return args.func(args)
    except FiperError as error:
        return fail("policy", error)


if __name__ == "__main__":
    sys.exit(main())
