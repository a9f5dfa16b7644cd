"""A minimal policy that publishes what FIPER needs: ``python -m fiper_ros.examples.minimal_policy``.

A stand-in for your own policy (README, "Your policy, from the first line to TPR / TNR"): per policy step it
"encodes" an observation into an embedding of E = 32 values and "samples" B = 16 action chunks of H = 8
end-effector positions (D = 3), of which h = 4 would be executed. A successful rollout follows the task's
path; a failing one (scenario ``ood``) drifts away from it from a third of the way in: its embeddings leave
the path and its sampled chunks spread out, which is what RND-OE and ACE notice. Everything FIPER-specific is
the five calls of :class:`~fiper_ros.publishing.FiperPublisher`: create, ``wait_for_suite``, ``start``,
``step``, ``end`` (and ``flush`` before exiting).

Every number here is made up (numpy, seeded): it shows the publishing side, not a policy worth running.
"""
from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence

import numpy as np
import rclpy

from fiper_ros.publishing import FiperPublisher, SuiteNotReady

E, B, H, D, EXEC = 32, 16, 8, 3, 4
TASK = "example"
#: Seed of the task itself (its embedding path), the same in every run.
TASK_SEED = 7
#: What ``--wait-for`` calls the suite (the other names are nodes, e.g. ``/fiper_record``).
SUITE = "suite"


class StandInPolicy:
    """The made-up policy of one rollout: :meth:`act` gives step ``t``'s embedding and ``[B, H, D]`` chunks."""

    def __init__(self, seed: int, steps: int, fail_from: int | None) -> None:
        self.rng = np.random.default_rng(seed)
        self.steps = steps
        self.fail_from = fail_from
        self.basis = np.random.default_rng(TASK_SEED).normal(0.0, 0.5, (E, 4))
        drift = self.rng.normal(0.0, 1.0, E)
        self.drift = drift / np.linalg.norm(drift)

    def _path(self, s: np.ndarray) -> np.ndarray:
        """The end effector's path at progress ``s`` in [0, 1]: ``[len(s), 3]`` positions in metres."""
        return np.stack([0.4 + 0.2 * np.cos(np.pi * s), 0.2 * np.sin(np.pi * s), 0.3 - 0.1 * s], axis=-1)

    def act(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """Step ``t``: the observation embedding ``[E]`` and the B sampled chunks ``[B, H, D]``."""
        phase = t / self.steps
        latent = np.array([np.cos(np.pi * phase), np.sin(np.pi * phase), np.cos(2 * np.pi * phase),
                           np.sin(2 * np.pi * phase)])
        embedding = self.basis @ latent + self.rng.normal(0.0, 0.05, E)
        progress = (t * EXEC + np.arange(H)) / (self.steps * EXEC)
        chunks = self._path(progress)[None] + self.rng.normal(0.0, 0.003, (B, H, D))
        if self.fail_from is not None and t >= self.fail_from:
            off = t - self.fail_from + 1
            embedding = embedding + 0.5 * off * self.drift
            chunks = chunks + self.rng.normal(0.0, 0.05 * min(off, 5), (B, H, D))
        return embedding.astype(np.float32), chunks.astype(np.float32)


def failing_rollouts(rollouts: int, failures: int) -> set[int]:
    """Which of ``rollouts`` fail: ``failures`` of them, spread evenly."""
    return set(np.round(np.linspace(0, rollouts - 1, failures)).astype(int).tolist()) if failures else set()


def run(args: argparse.Namespace) -> int:
    """Publish ``args.rollouts`` rollouts once the suite (and what ``--wait-for`` names) has matched."""
    rclpy.init()
    node = rclpy.create_node("minimal_policy")
    fiper = FiperPublisher(node, action_space="ee_position", exec_steps=EXEC)
    seed = args.seed if args.seed is not None else time.time_ns() % 2**31
    try:
        nodes = [name for name in args.wait_for if name != SUITE]
        print(f"minimal_policy: waiting for {', '.join(args.wait_for)} (at most {args.wait:g} s) ...", flush=True)
        fiper.wait_for_suite(args.wait, also=nodes, suite=SUITE in args.wait_for)
        failing = failing_rollouts(args.rollouts, args.failures)
        print(f"minimal_policy: {args.rollouts} rollouts ({len(failing)} failing) of {args.steps} steps at "
              f"{args.rate:g} Hz, seed {seed}", flush=True)
        for index in range(args.rollouts):
            fails = index in failing
            policy = StandInPolicy(seed + index, args.steps, args.steps // 3 if fails else None)
            rollout_id = fiper.start(task=args.task, scenario="ood" if fails else "id", max_steps=args.steps)
            for t in range(args.steps):
                began = time.monotonic()
                embedding, chunks = policy.act(t)
                fiper.step(embedding, chunks)
                time.sleep(max(0.0, 1.0 / args.rate - (time.monotonic() - began)))
            fiper.end(success=not fails)
            print(f"minimal_policy: rollout {rollout_id}: {args.steps} steps, {'failure' if fails else 'success'}",
                  flush=True)
        if not fiper.flush(args.wait):
            print("minimal_policy: not every message was acknowledged before exiting", file=sys.stderr)
            return 1
        return 0
    except SuiteNotReady as error:
        print(f"minimal_policy: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m fiper_ros.examples.minimal_policy [--rollouts N] [--failures K] ...``."""
    parser = argparse.ArgumentParser(prog="python -m fiper_ros.examples.minimal_policy", description=__doc__.split(
        "\n")[0])
    parser.add_argument("--rollouts", type=int, default=10, help="rollouts to run (default 10)")
    parser.add_argument("--failures", type=int, default=0, help="how many of them fail (default 0)")
    parser.add_argument("--steps", type=int, default=20, help="policy steps per rollout (default 20)")
    parser.add_argument("--rate", type=float, default=20.0, help="policy steps per second (default 20)")
    parser.add_argument("--seed", type=int, help="seed of the first rollout (default: from the clock)")
    parser.add_argument("--task", default=TASK, help=f"the task its rollouts name (default {TASK})")
    parser.add_argument("--wait", type=float, default=60.0, help="seconds to wait for the readers (default 60)")
    parser.add_argument("--wait-for", nargs="+", default=[SUITE], metavar="WHO",
                        help=f"'{SUITE}' (the FIPER suite's nodes) and/or nodes that report their matches on "
                             "/diagnostics, e.g. /fiper_record (fiper record); default: suite")
    args = parser.parse_args(argv)
    if not 0 <= args.failures <= args.rollouts or args.steps < 1 or args.rate <= 0:
        parser.error("need 0 <= --failures <= --rollouts, --steps >= 1 and --rate > 0")
    return run(args)


if __name__ == "__main__":
    sys.exit(main())
