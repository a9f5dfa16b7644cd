"""Test-side DDS helpers: child processes in a test's own domain (see fiper_ros.platform.dds), shared memory of dead
processes removed (fiper_ros.platform.shm)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

from fiper_ros.platform.dds import STACKS_SIGNAL, allocate_domain, local_env, wait_interruptible
from fiper_ros.platform.shm import clean_stale

__all__ = ["allocate_domain", "clean_stale", "ros_env", "run_python", "spawn_python", "stop"]


def ros_env(domain: int) -> dict[str, str]:
    """The environment for a child process of a test: in ``domain``, loopback only, test helpers importable."""
    env = local_env(domain)
    test_dir = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = test_dir + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def spawn_python(args: Sequence[str], domain: int, **kwargs: object) -> subprocess.Popen[str]:
    """Start ``python ARGS`` in its own process group, in ``domain``, text mode, output piped."""
    return subprocess.Popen(  # test helper runs our own scripts
        [sys.executable, *args],
        env=ros_env(domain),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
        **kwargs,  # type: ignore[arg-type]
    )


#: How long a process that did not stop after SIGINT gets to print its threads' stacks before SIGKILL.
STACKS_WAIT_S = 2.0


def stop(proc: subprocess.Popen[str], timeout: float = 10.0) -> str:
    """Interrupt ``proc`` (SIGINT, then SIGKILL after ``timeout``) and return its output; one that does not stop is
    first asked for its threads' stacks (:data:`STACKS_SIGNAL`, which the node processes answer), so the output
    shows where it hung."""
    if proc.poll() is None:
        wait_interruptible(proc.pid)  # a SIGINT before the helper takes it would be lost
        proc.send_signal(signal.SIGINT)
        try:
            out, _ = proc.communicate(timeout=timeout)
            return out or ""
        except subprocess.TimeoutExpired:
            proc.send_signal(STACKS_SIGNAL)
            try:
                out, _ = proc.communicate(timeout=STACKS_WAIT_S)
                return out or ""
            except subprocess.TimeoutExpired:
                proc.kill()
    out, _ = proc.communicate()
    return out or ""


def run_python(args: Sequence[str], domain: int, timeout: float) -> subprocess.CompletedProcess[str]:
    """Run ``python ARGS`` to its end in ``domain``; on ``timeout`` kill its whole process group (the suite
    a ``fiper replay`` started too) and raise ``AssertionError`` with what it printed so far."""
    proc = spawn_python(args, domain)
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, 9)
        out, _ = proc.communicate()
        raise AssertionError(f"python {' '.join(args)} did not finish in {timeout:g} s:\n{(out or '')[-4000:]}") from None
    return subprocess.CompletedProcess(proc.args, proc.returncode, out or "", "")
