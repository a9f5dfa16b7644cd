"""``make bench-scale``: the cost of collecting episodes as Ray tasks (docs/scale.md).

The same seeded episodes (``run_episode``: the policy and MuJoCo, the rollout recorded, no bag) run three ways:
in this process one after the other (each episode's own time), on a local Ray instance with one CPU and with two
(:class:`sim_bridge.ray_runner.RayRunner`, the runner of ``fiper collect --ray``, after one warm-up episode per
worker: a worker's first task imports torch and MuJoCo and loads the policy). Reported: time per episode, Ray's
overhead per episode (on one worker, the wall per episode less the episode's own time measured on the worker in
the same run, so that the load of other work cancels; target <= 5 % of it), the
speed-up of two workers over one (target >= 1.8x), the start-up, and the wall time the model of docs/scale.md
predicts for one and two workers next to the measured one. Each Ray configuration runs in a fresh process (a
process joins one Ray instance at a time).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import torch

SCENARIO = "id"
#: Seeds of the warm-up episodes (one per worker), apart from the measured ones.
WARMUP_SEED = 9000


def _own_times(task: str, seeds: list[int], batch: int | None) -> list[float]:
    """Seconds of each episode run in this process."""
    from sim_bridge.closed_loop import run_episode  # noqa: PLC0415

    from fiper_ros.commands.collect import default_model  # noqa: PLC0415
    from fiper_ros.policy.policy import Policy  # noqa: PLC0415

    policy = Policy.load(default_model(task))
    run_episode(policy, SCENARIO, WARMUP_SEED, batch=batch)
    times = []
    for seed in seeds:
        started = time.perf_counter()
        run_episode(policy, SCENARIO, seed, batch=batch)
        times.append(time.perf_counter() - started)
    return times


def _ray_times(task: str, seeds: list[int], batch: int | None, cpus: int) -> dict[str, float]:
    """Start-up (joining and warming the workers) and wall time of ``seeds`` on a local instance of ``cpus``."""
    from sim_bridge.ray_runner import RayRunner  # noqa: PLC0415

    from fiper_ros.bagio.collect_index import IN_PROCESS, CollectSetup  # noqa: PLC0415
    from fiper_ros.cluster import LOCAL, connected  # noqa: PLC0415
    from fiper_ros.commands.collect import default_model  # noqa: PLC0415
    from fiper_ros.policy.policy import Policy  # noqa: PLC0415

    model = default_model(task)
    policy = Policy.load(model)
    setup = CollectSetup(task, "bench", "test", batch or policy.config.sample_batch, None, IN_PROCESS)
    started = time.perf_counter()
    with connected(LOCAL, cpus) as cluster:
        runner = RayRunner(policy, setup, model)
        try:
            warmup = list(range(WARMUP_SEED, WARMUP_SEED + cluster.cpus))
            runner.ahead(SCENARIO, warmup)
            for seed in warmup:
                runner.result(SCENARIO, seed)
            ready = time.perf_counter()
            runner.episode_seconds.clear()
            for index, seed in enumerate(seeds):
                runner.ahead(SCENARIO, seeds[index:])
                runner.result(SCENARIO, seed)
            done = time.perf_counter()
        finally:
            runner.close()
    return {"startup_s": ready - started, "wall_s": done - ready, "own_s": sum(runner.episode_seconds)}


def main() -> None:
    """Run the benchmark and print its table."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--task", default="sorting", help="sim task (default sorting, the cheapest)")
    parser.add_argument("--episodes", type=int, default=8, help="measured episodes per configuration")
    parser.add_argument("--batch", type=int, default=None, help="B (default: the model's)")
    parser.add_argument("--ray-cpus", type=int, default=None, help=argparse.SUPPRESS)  # one configuration, JSON out
    args = parser.parse_args()
    torch.set_num_threads(1)
    seeds = list(range(1000, 1000 + args.episodes))
    if args.ray_cpus is not None:
        print(json.dumps(_ray_times(args.task, seeds, args.batch, args.ray_cpus)))
        return
    own = _own_times(args.task, seeds, args.batch)
    ray = {}
    for cpus in (1, 2):
        command = [sys.executable, "-m", "fiper_ros.bench.scale_bench", "--task", args.task, "--episodes",
                   str(args.episodes), "--ray-cpus", str(cpus), *(["--batch", str(args.batch)] if args.batch else [])]
        ray[cpus] = json.loads(subprocess.run(command, check=True, capture_output=True, text=True).stdout)  # noqa: S603
    episode = sum(own) / len(own)
    per_episode = {cpus: ray[cpus]["wall_s"] / args.episodes for cpus in ray}
    # on one worker, at the same time: the wall per episode less the episodes' own time on the worker
    overhead = per_episode[1] - ray[1]["own_s"] / args.episodes
    in_ray = ray[1]["own_s"] / args.episodes
    print(f"# make bench-scale: {args.task} {SCENARIO}, {args.episodes} episodes, B = {args.batch or 'the model'}'s; "
          f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    print(f"time per episode (in-process, own time)    {episode:.3f} s (min {min(own):.3f}, max {max(own):.3f})")
    print(f"time per episode on the Ray worker (own)   {in_ray:.3f} s")
    print(f"wall per episode, Ray 1 worker             {per_episode[1]:.3f} s")
    print(f"Ray overhead per episode                   {overhead * 1e3:+.1f} ms = {100 * overhead / in_ray:+.2f} % of "
          f"the episode (target <= 5 %)")
    print(f"wall per episode, Ray 2 workers            {per_episode[2]:.3f} s")
    print(f"speed-up 2 workers / 1 worker              {per_episode[1] / per_episode[2]:.2f}x (target >= 1.8x)")
    for cpus in (1, 2):
        predicted = args.episodes * (episode + overhead) / cpus
        print(f"start-up, {cpus} worker(s) (join + warm-up)     {ray[cpus]['startup_s']:.1f} s; model "
              f"E (t + o) / N = {predicted:.1f} s, measured {ray[cpus]['wall_s']:.1f} s "
              f"({100 * (ray[cpus]['wall_s'] / predicted - 1):+.1f} %)")


if __name__ == "__main__":
    main()
