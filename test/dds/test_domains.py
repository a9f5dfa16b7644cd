"""Each run's ROS domain is its own: not locked by another run, and used by no live process (a node of a
killed run holds no lock but still speaks in its domain)."""
from __future__ import annotations

import os
import subprocess

from fiper_ros.platform.dds import DOMAIN_RANGE, allocate_domain, domains_in_use


def test_a_domain_a_live_process_uses_is_never_allocated() -> None:
    taken = [d for d in DOMAIN_RANGE if str(d) != os.environ.get("ROS_DOMAIN_ID")][:len(DOMAIN_RANGE) - 3]
    sleepers = [subprocess.Popen(["sleep", "60"],
                                 env=os.environ | {"ROS_DOMAIN_ID": str(d)}) for d in taken]
    try:
        busy = domains_in_use()
        assert set(taken) <= busy
        for _ in range(5):
            with allocate_domain() as domain:
                assert domain not in taken
    finally:
        for sleeper in sleepers:
            sleeper.kill()
            sleeper.wait()
