"""DDS isolation for everything the project starts: tests, benchmarks, demos.

Each run takes a ROS_DOMAIN_ID nobody else on this machine uses: an exclusive file lock per id, and no
live process whose environment names that id (a node left over from a killed run holds no lock, but
would still speak in its domain). Every child process gets ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, so
no DDS packet leaves loopback and parallel runs never see each other.
"""
from __future__ import annotations

import ctypes
import fcntl
import os
import random
import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO

from fiper_ros.platform.errors import PlatformError

LOCK_DIR = Path(os.environ.get("FIPER_DOMAIN_LOCK_DIR", "/tmp/fiper-ros-domains"))
#: Domain ids that are safe on Linux with the default RTPS port mapping.
DOMAIN_RANGE = range(1, 102)
#: A process started with this set to its parent's pid ends when that parent does (:func:`die_with_parent`):
#: ``fiper launch`` sets it for each node, the test fixtures for each launcher they start.
PARENT_PID_ENV = "FIPER_PARENT_PID"
#: How long :func:`wait_interruptible` waits for a process to stop ignoring SIGINT (then it is sent anyway).
INTERRUPTIBLE_WAIT_S = 2.0
#: A node process prints every thread's Python stack on this signal and runs on (``faulthandler``); ``fiper launch``
#: sends it to a node that did not stop within its grace period, before killing it.
STACKS_SIGNAL = signal.SIGUSR1


class DomainsExhausted(PlatformError):
    """Every ROS_DOMAIN_ID of :data:`DOMAIN_RANGE` is taken: by the shell, a live process or another run's lock."""


def domains_in_use(proc: Path = Path("/proc")) -> set[int]:
    """The ROS_DOMAIN_IDs in the environments of the other live processes (those this user may read)."""
    used: set[int] = set()
    me = str(os.getpid())
    for entry in proc.iterdir():
        if not entry.name.isdigit() or entry.name == me:
            continue
        try:
            environ = (entry / "environ").read_bytes()
        except OSError:  # gone meanwhile, or not ours to read
            continue
        for variable in environ.split(b"\0"):
            if variable.startswith(b"ROS_DOMAIN_ID="):
                value = variable[len(b"ROS_DOMAIN_ID="):]
                if value.isdigit():
                    used.add(int(value))
    return used


@contextmanager
def allocate_domain() -> Iterator[int]:
    """Hold an unused ROS_DOMAIN_ID (not the shell's own, none a live process uses) for the duration of
    the ``with`` block; :class:`DomainsExhausted` if none is free."""
    LOCK_DIR.mkdir(parents=True, exist_ok=True)
    own = os.environ.get("ROS_DOMAIN_ID", "")
    busy = domains_in_use()
    candidates = [d for d in DOMAIN_RANGE if str(d) != own and d not in busy]
    random.shuffle(candidates)
    for domain in candidates:
        handle: IO[str] = open(LOCK_DIR / f"{domain}.lock", "w")  # noqa: SIM115 - held while in use
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
    raise DomainsExhausted(f"no free ROS_DOMAIN_ID in {DOMAIN_RANGE.start}..{DOMAIN_RANGE.stop - 1}: each is the "
                           "shell's, used by a live process or held by another run (end those runs first)")


def local_env(domain: int, base: dict[str, str] | None = None) -> dict[str, str]:
    """An environment for a child process: ``base`` (default: this one) in ``domain``, loopback only."""
    env = dict(os.environ if base is None else base)
    env["ROS_DOMAIN_ID"] = str(domain)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.pop("ROS_STATIC_PEERS", None)
    env["PYTHONUNBUFFERED"] = "1"
    return env


_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def die_with(parent: int) -> None:
    """Ask Linux to send this process SIGTERM when ``parent`` (its parent) dies, so that a killed parent never
    leaves it running (speaking in its domain, or working for nobody); SIGTERM at once if ``parent`` is gone
    already. (Linux sends it when the parent's thread that started this process ends: start such processes
    from a thread that lives as long as they should.)"""
    if not sys.platform.startswith("linux"):
        return
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0) != 0:
        raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG) failed")
    if os.getppid() != parent:  # the parent died before the request was in place
        os.kill(os.getpid(), signal.SIGTERM)


def interruptible() -> None:
    """Take SIGINT as this process's stop request (Python's ``KeyboardInterrupt``) also when it started with SIGINT
    ignored, as it inherits from a parent started that way (a background job of a shell without job control, a
    test run in the background). The project's tools stop what they start with SIGINT: ``fiper launch`` under a
    demo, a replay or a test fixture would otherwise miss a Ctrl-C sent before it installs its own handler, go on
    starting the suite, and be killed only after its starter's timeout (measured: a refused replay took 25 s
    instead of 1 s). In the main thread only, where Python handles signals."""
    if threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def ignores_sigint(pid: int) -> bool:
    """Whether live process ``pid`` ignores SIGINT now (Linux: ``SigIgn`` of its ``/proc`` status; False for a process
    that is gone or a zombie, and where it cannot be read)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    fields = dict(line.split(":", 1) for line in status.splitlines() if ":" in line)
    if fields.get("State", "").strip().startswith("Z") or "SigIgn" not in fields:
        return False
    return bool(int(fields["SigIgn"], 16) >> (signal.SIGINT - 1) & 1)


def wait_interruptible(pid: int, wait_s: float = INTERRUPTIBLE_WAIT_S) -> None:
    """Wait, at most ``wait_s``, while process ``pid`` (one we started) still ignores SIGINT: inherited, and not yet
    restored by :func:`interruptible` or rclpy's handler in its first milliseconds. A SIGINT sent then is lost."""
    end = time.monotonic() + wait_s
    while ignores_sigint(pid) and time.monotonic() < end:
        time.sleep(0.005)


def interrupt_group(pid: int, wait_s: float = INTERRUPTIBLE_WAIT_S) -> None:
    """Ctrl-C the process group of ``pid``, a process we started in a session of its own, once it takes SIGINT
    (:func:`wait_interruptible`). ``ProcessLookupError`` when the group is gone."""
    wait_interruptible(pid, wait_s)
    os.killpg(pid, signal.SIGINT)


def die_with_parent() -> None:
    """:func:`die_with` the parent ``FIPER_PARENT_PID`` names, if it is set."""
    parent = os.environ.get(PARENT_PID_ENV)
    if parent:
        die_with(int(parent))
