"""DDS isolation for tests: every test that touches DDS gets its own ROS_DOMAIN_ID, on loopback only.

Domain ids are taken with an exclusive file lock, so parallel test runs on one machine never share
a domain. The environment of every child process carries ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST.
"""
from __future__ import annotations

import fcntl
import os
import random
import subprocess
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import IO

LOCK_DIR = Path(os.environ.get("FIPER_DOMAIN_LOCK_DIR", "/tmp/fiper-ros-domains"))
#: Domain ids that are safe on Linux with the default RTPS port mapping.
DOMAIN_RANGE = range(1, 102)


@contextmanager
def allocate_domain() -> Iterator[int]:
    """Hold an unused ROS_DOMAIN_ID for the duration of the ``with`` block."""
    LOCK_DIR.mkdir(parents=True, exist_ok=True)
    reserved = {int(os.environ["ROS_DOMAIN_ID"])} if os.environ.get("ROS_DOMAIN_ID", "").isdigit() else set()
    candidates = [d for d in DOMAIN_RANGE if d not in reserved]
    random.shuffle(candidates)
    for domain in candidates:
        handle: IO[str] = open(LOCK_DIR / f"{domain}.lock", "w")
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.close()
            continue
        try:
            yield domain
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)
            handle.close()
        return
    raise RuntimeError(f"no free ROS_DOMAIN_ID in {DOMAIN_RANGE}")


def ros_env(domain: int) -> dict[str, str]:
    """The environment for a child process of a test: this one, in ``domain``, on loopback only."""
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(domain)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.pop("ROS_STATIC_PEERS", None)
    env["PYTHONUNBUFFERED"] = "1"
    test_dir = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = test_dir + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def spawn_python(args: Sequence[str], domain: int, **kwargs: object) -> subprocess.Popen[str]:
    """Start ``python ARGS`` in its own process group, in ``domain``, text mode, output piped."""
    return subprocess.Popen(  # noqa: S603 - test helper runs our own scripts
        [sys.executable, *args],
        env=ros_env(domain),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
        **kwargs,  # type: ignore[arg-type]
    )


def stop(proc: subprocess.Popen[str], timeout: float = 10.0) -> str:
    """Interrupt ``proc`` (SIGINT, then SIGKILL after ``timeout``) and return its output."""
    if proc.poll() is None:
        proc.send_signal(2)
        try:
            out, _ = proc.communicate(timeout=timeout)
            return out or ""
        except subprocess.TimeoutExpired:
            proc.kill()
    out, _ = proc.communicate()
    return out or ""
