#!/usr/bin/env python3
"""Resident memory of the sim bridge's session over many rollouts, without DDS (docs/benchmarks.md, the soak).

    python tools/bridge_memory.py images|noimages ROLLOUTS      (after `source env.sh`)

Sorting rollouts, in-distribution and ``box_pos`` in turn (seeds 3000, 3001, ...), 40 control steps each with
zero actions and an observation (both cameras rendered with ``images``) at every control step, as the bridge
node runs them; VmRSS every 25 rollouts.
"""
from __future__ import annotations

import os
import sys
import time

import numpy as np

from sim_bridge.bridge_session import BridgeSession

from fiper_ros.bench import memory_mb

CONTROL_STEPS = 40


def main(argv: list[str]) -> int:
    """Run the rollouts and print the memory."""
    if len(argv) != 2 or argv[0] not in ("images", "noimages") or not argv[1].isdigit():
        print(__doc__, file=sys.stderr)
        return 2
    mode, rollouts = argv[0], int(argv[1])
    session = BridgeSession(images=mode == "images")
    started = time.monotonic()
    for i in range(rollouts):
        rollout, _ = session.start("sorting", "id" if i % 2 == 0 else "box_pos", 3000 + i)
        assert session.env is not None
        for _ in range(CONTROL_STEPS):
            session.accept(rollout.rollout_id, rollout.policy_step, "ee_position", 1, session.env.action_dim,
                           np.zeros(session.env.action_dim, np.float32), 0)
            ended = session.execute_one()
            session.observation()
            if ended is not None:
                break
        if i % 25 == 0 or i == rollouts - 1:
            print(f"{mode} rollout {i}: RSS {memory_mb(os.getpid()):.1f} MB ({time.monotonic() - started:.0f} s)",
                  flush=True)
    session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
