"""Cost of one policy step of each shipped policy on this machine.

Run: ``python -m fiper_ros.bench.policy_bench`` (or ``make bench-policy``). Per model in ``models/`` it
times, on the first observation of ID episode 1000: ``Policy.embed`` (the encoder's O_t^e) and
``Policy.sample`` (all B chunks through the model's sampler). One torch thread, as the policy node and
``fiper collect`` run by default. Prints p50/p99 in ms. The sim's own cost per control step:
``python -m sim_bridge.cli bench`` (docs/sim.md).
"""

from __future__ import annotations

import argparse
import sys
from collections import deque
from pathlib import Path

import torch
from sim_bridge.env import make_env
from sim_bridge.scenarios import TASK_NAMES

from fiper_ros.bench.core_bench import measure
from fiper_ros.policy.noise import sampling_generator
from fiper_ros.policy.policy import Policy

def run(models: Path, iterations: int, warmup: int) -> list[tuple[str, str, float, float]]:
    """``(model, measurement, p50 ms, p99 ms)`` for every shipped model."""
    rows: list[tuple[str, str, float, float]] = []
    for task in TASK_NAMES:
        folder = models / task
        if not (folder / "policy.yaml").is_file():
            continue
        policy = Policy.load(folder)
        config = policy.config
        generator = sampling_generator(1000)
        label = f"{task} ({config.head}, B = {config.sample_batch}, H = {config.horizon}, D = {config.action_dim})"
        with make_env(task, "id", 1000) as env:
            history = deque([env.reset()], maxlen=config.obs_horizon)
            embedding = policy.embed(history)
            rows.append((label, "embed", *measure(lambda _: policy.embed(history), iterations, warmup)))
            rows.append((label, "sample B chunks", *measure(lambda _: policy.sample(embedding, None, generator),
                                                            iterations, warmup)))
    return rows


def main(argv: list[str] | None = None) -> int:
    """Print the table; exit status 1 if no model was found."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", type=Path, default=Path("models"), help="folder of the shipped models")
    parser.add_argument("--iterations", type=int, default=30)
    parser.add_argument("--warmup", type=int, default=3)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    rows = run(args.models, args.iterations, args.warmup)
    if not rows:
        sys.stderr.write(f"no policy model in {args.models.resolve()}\n")
        return 1
    width = max(len(model) for model, *_ in rows)
    sys.stdout.write(f"{'model'.ljust(width)}  {'measurement':<17} p50 ms   p99 ms\n")
    for model, name, p50, p99 in rows:
        sys.stdout.write(f"{model.ljust(width)}  {name:<17} {p50:7.1f}  {p99:7.1f}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
