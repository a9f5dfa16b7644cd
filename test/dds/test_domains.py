"""Each run's ROS domain is its own: not locked by another run, and used by no live process (a node of a
killed run holds no lock but still speaks in its domain)."""
from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path

import pytest

from fiper_ros.errors import FiperError
from fiper_ros.platform import dds
from fiper_ros.platform.dds import DOMAIN_RANGE, DomainsExhausted, allocate_domain, domains_in_use


def _environment_set(pid: int) -> bool:
    """Whether ``/proc/PID/environ`` shows the process's environment yet: ``Popen`` returns once the exec closed its
    error pipe, before the kernel has laid out the new program's environment, and meanwhile the file reads empty
    (a fresh-clone run under load found the last of 98 sleepers' domain missing)."""
    try:
        return b"ROS_DOMAIN_ID=" in (Path("/proc") / str(pid) / "environ").read_bytes()
    except OSError:
        return False


def test_a_domain_a_live_process_uses_is_never_allocated() -> None:
    taken = [d for d in DOMAIN_RANGE if str(d) != os.environ.get("ROS_DOMAIN_ID")][:len(DOMAIN_RANGE) - 3]
    sleepers = [subprocess.Popen(["sleep", "60"],
                                 env=os.environ | {"ROS_DOMAIN_ID": str(d)}) for d in taken]
    try:
        deadline = time.monotonic() + 30.0
        while not all(_environment_set(s.pid) for s in sleepers) and time.monotonic() < deadline:
            time.sleep(0.01)
        busy = domains_in_use()
        assert set(taken) <= busy
        for _ in range(5):
            with allocate_domain() as domain:
                assert domain not in taken
    finally:
        for sleeper in sleepers:
            sleeper.kill()
            sleeper.wait()


def test_no_free_domain_is_a_user_error(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every domain taken (here: reported in use) is the user's to fix, one line (before: a RuntimeError, shown by
    ``fiper demo`` / ``replay`` as a traceback)."""
    monkeypatch.setattr(dds, "domains_in_use", lambda: set(DOMAIN_RANGE))
    with pytest.raises(DomainsExhausted, match=r"^no free ROS_DOMAIN_ID in 1\.\.101: each is the shell's") as refused, \
            allocate_domain():
        pass
    assert isinstance(refused.value, FiperError) and not isinstance(refused.value, RuntimeError)
