"""Running one node in its own process: init, spin, clean shutdown on SIGINT / SIGTERM.

After start-up every object that exists (rclpy, numpy, torch, the node) is moved out of the garbage
collector's reach (``gc.freeze``): a full collection then only walks what the callbacks allocate, so it
no longer stalls a callback for milliseconds (the tail of the node benchmark, docs/benchmarks.md).
A crash of the process prints every thread's Python stack (``faulthandler``), which the launcher shows; so does
:data:`~fiper_ros.platform.dds.STACKS_SIGNAL` (SIGUSR1), which the launcher sends a node that does not stop within its
grace period before it kills it, and so does a teardown that outlasts :data:`TEARDOWN_S`, which then ends the process.
The exit after the teardown (Python's finalization, then the C++ static destructors) is bounded by :data:`EXIT_S`:
SIGALRM, whose default action ends the process.
A node started by ``fiper launch`` dies with it (``FIPER_PARENT_PID``: Linux's parent-death signal), so a
killed launcher never leaves a stale suite speaking on the suite's topics.

The executor (docs/benchmarks.md "Nodes"): the scoring and fusion nodes spin rclpy's C++
``EventsExecutor`` by default, the other single-threaded nodes rclpy's Python ``SingleThreadedExecutor``;
``FIPER_EXECUTOR=events`` or ``single`` chooses for every single-threaded node process. The EventsExecutor is
spun in slices of :data:`EVENTS_SLICE_S` (``spin_once`` with a timeout), never by its untimed ``spin()``: in
this rclpy wheel (manylinux_2_28, built without ``pthread_cond_clockwait``) that waits on its event queue until
``steady_clock::time_point::max()``, which libstdc++ converts to an overflowed system-clock deadline, so the
wait never sleeps: the main thread busy-loops holding the queue's lock, the DDS threads that enqueue timer and
message events block on it, and no timer, message or service request is ever dispatched again (the "stopped
timers" of the first attempt). ``FIPER_PROFILE_DIR=DIR`` profiles the spinning (``cProfile``, the main thread's
CPU time) into ``DIR/<node name>.prof`` at shutdown (``make bench-nodes`` ``--profile``).
"""
from __future__ import annotations

import cProfile
import faulthandler
import gc
import os
import signal
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.context import Context
from rclpy.exceptions import NotInitializedException
from rclpy.executors import Executor, ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.experimental import EventsExecutor

from fiper_ros.data_paths import package_share
from fiper_ros.errors import FiperError, report
from fiper_ros.platform.dds import STACKS_SIGNAL, die_with_parent
from fiper_ros.platform.errors import PlatformError

CALLBACK_DRAIN_S = 30.0
"""Longest wait at shutdown for callbacks still running (a policy step of a large batch takes seconds)."""
TEARDOWN_S = 3.0
"""Longest teardown once the callbacks have finished (destroying the nodes, shutting rclpy down): past it the process
prints every thread's stack and exits with status 1 (``faulthandler``), its DDS entities not deleted. An upstream
rmw_fastrtps race can hang that teardown when a peer was killed a few seconds before (docs/nodes.md)."""
EXIT_S = 3
"""Longest exit of a node process after its teardown: Python's finalization, then the C++ static destructors, where
Fast DDS 2.14 can deadlock deleting a participant still left to its factory (a discovery thread waits for a lock
that the exiting thread holds while it busy-waits for that thread's callback to end; docs/nodes.md).
Past it SIGALRM ends the process (the signal's default action)."""
#: Environment variable that chooses the executor of every single-threaded node process: :data:`EXECUTOR_EVENTS` or
#: :data:`EXECUTOR_SINGLE`.
EXECUTOR_ENV = "FIPER_EXECUTOR"
EXECUTOR_EVENTS, EXECUTOR_SINGLE = "events", "single"
#: Longest single ``spin_once`` of an EventsExecutor (it returns at once on work or shutdown; see the module doc).
EVENTS_SLICE_S = 0.5
#: Fast DDS's variable naming its XML profiles file, and the files it reads from the working directory without it.
FASTDDS_PROFILES_ENV = "FASTRTPS_DEFAULT_PROFILES_FILE"
FASTDDS_DEFAULT_FILES = ("DEFAULT_FASTRTPS_PROFILES.xml", "DEFAULT_FASTDDS_PROFILES.xml")
#: The RMW implementations that read Fast DDS profiles (ROS 2's default is the first).
FASTDDS_RMWS = ("rmw_fastrtps_cpp", "rmw_fastrtps_dynamic_cpp")
#: The suite's Fast DDS profile in the package share: a participant announces itself every 0.5 s, not 3 s.
DISCOVERY_PROFILE = Path("config") / "fastdds_discovery.xml"
#: Environment variable naming a folder: each node process profiles its spinning into ``<node name>.prof`` there.
PROFILE_ENV = "FIPER_PROFILE_DIR"


def proc_stat(pid: int | str = "self") -> list[str]:
    """The fields of ``/proc/<pid>/stat`` after the command name (which may hold spaces and parentheses): index 0
    is the state, field 3 of proc(5); times are in clock ticks (``os.sysconf("SC_CLK_TCK")``)."""
    return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()


def process_age_s() -> float:
    """Seconds since this process was started (its exec, from ``/proc``: to the kernel's clock tick, 10 ms): what
    a node's ``ACTIVE`` log line reports, and ``make bench-nodes`` reads as the node's own start-up."""
    started_ticks = int(proc_stat()[19])  # starttime, field 22 of proc(5)
    uptime_s = float(Path("/proc/uptime").read_text().split()[0])
    return uptime_s - started_ticks / os.sysconf("SC_CLK_TCK")


def use_discovery_profile() -> Path | None:
    """Point Fast DDS at the suite's discovery profile (:data:`DISCOVERY_PROFILE`, docs/nodes.md "DDS discovery")
    for this process's participants and its children, before ``rclpy.init``. Returns the profile's path while it
    is in effect (set now, or by a parent), None where the user's own settings apply: another RMW,
    :data:`FASTDDS_PROFILES_ENV` naming another file, a default profiles file in the working directory, or no
    installed share."""
    share = package_share()
    ours = share / DISCOVERY_PROFILE if share is not None else None
    given = os.environ.get(FASTDDS_PROFILES_ENV)
    if given:
        return ours if ours is not None and Path(given) == ours else None
    if os.environ.get("RMW_IMPLEMENTATION", FASTDDS_RMWS[0]) not in FASTDDS_RMWS or ours is None or not ours.is_file():
        return None
    if any(Path(name).exists() for name in FASTDDS_DEFAULT_FILES):
        return None
    os.environ[FASTDDS_PROFILES_ENV] = str(ours)
    return ours


def discovery_note(profile: Path) -> str:
    """What a process that applies the discovery profile says (a node logs it, ``fiper launch --in-process``
    prints it)."""
    return f"DDS discovery: Fast DDS profile {profile} (set {FASTDDS_PROFILES_ENV} to use your own)"


def new_executor(threads: int = 1, default: str = EXECUTOR_SINGLE, context: Context | None = None) -> Any:
    """The executor of a node process (``threads`` > 1: a multi-threaded one); a single-threaded one is of the
    kind :data:`EXECUTOR_ENV` names, else ``default``; :class:`~fiper_ros.platform.errors.PlatformError` naming the
    variable and its values for another kind."""
    if threads > 1:
        return MultiThreadedExecutor(num_threads=threads, context=context)
    kind = os.environ.get(EXECUTOR_ENV) or default
    if kind == EXECUTOR_EVENTS:
        return EventsExecutor(context=context)
    if kind == EXECUTOR_SINGLE:
        return SingleThreadedExecutor(context=context)
    raise PlatformError(f"{EXECUTOR_ENV}={kind!r}: expected {EXECUTOR_EVENTS!r} or {EXECUTOR_SINGLE!r}")


def spin_until_shutdown(executor: Any) -> None:
    """Spin until Ctrl-C / SIGTERM shuts rclpy down, however rclpy reports the shutdown; return once the
    callbacks in flight have finished (``stop_executor``). An EventsExecutor spins in bounded slices."""
    try:
        if isinstance(executor, Executor):
            executor.spin()
        else:
            _termination.events_spinning = True
            try:
                while rclpy.ok() and not _termination.requested:
                    executor.spin_once(timeout_sec=EVENTS_SLICE_S)
            finally:
                _termination.events_spinning = False
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RCLError:
        # rclpy's signal handler shuts the context down; if that lands while the executor builds its wait
        # set, rcl reports an invalid context instead of ExternalShutdownException.
        if rclpy.ok():
            raise
    finally:
        stop_executor(executor)


def stop_executor(executor: Any) -> None:
    """Shut ``executor`` down and wait (at most ``CALLBACK_DRAIN_S``) for the callbacks still running in its
    threads, so that its nodes may be destroyed (a callback that outlives its node fails on a destroyed
    handle). An EventsExecutor and a SingleThreadedExecutor run their callbacks in the thread that spins them:
    none is in flight once that thread is here. Their work tracker is not waited on: a Ctrl-C whose
    KeyboardInterrupt lands inside the tracker's ``__enter__``, after its count went up, leaves it counting a
    callback that never runs, and the wait would then last the whole ``CALLBACK_DRAIN_S`` (a node that did not
    exit within 10 s of its SIGINT, once in CI)."""
    executor.shutdown()
    if not isinstance(executor, MultiThreadedExecutor):
        return
    # rclpy 7.1 (Jazzy) sets its shutdown flag before testing it, so Executor.shutdown() never waits for
    # the callbacks in flight; wait on the executor's own work tracker instead.
    executor._work_tracker.wait(CALLBACK_DRAIN_S)  # noqa: SLF001


def shut_down() -> None:
    """Shut the default context down unless that already happened, also while rclpy's signal handler
    thread does it (its shutdown can land between ``try_shutdown``'s check and its call)."""
    try:
        rclpy.try_shutdown()
    except RCLError:
        if rclpy.ok():
            raise


class _Termination:
    """What the SIGTERM handler found and asked: whether an EventsExecutor was spinning, whether to stop."""

    events_spinning = False
    requested = False


_termination = _Termination()


def _on_sigterm(*_: Any) -> None:
    """SIGTERM: stop, once. Python runs a handler inside whatever the main thread waits on (a lock, a join), so a
    second SIGTERM (the launcher's stop, then the parent-death signal as the launcher exits) must not enter
    ``shut_down`` again while the first holds rclpy's context lock: that deadlocked a fusion node, which then
    outlived its test and the launcher, still in the domain. While an EventsExecutor spins, the main thread runs
    Python only in a callback, so the handler runs at a callback's start: shutting the context down there failed
    that callback on the dead context (a FATAL "Exception in 'timers' callback" at every SIGTERM, a ``docker stop``
    or a launch's escalation). There the handler only asks the spin loop to end; :func:`run_node` shuts down after
    the callback."""
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _termination.requested = True
    if not _termination.events_spinning:
        shut_down()


def spin_profiled(executor: Any, label: str) -> None:
    """:func:`spin_until_shutdown`, profiled into :data:`PROFILE_ENV`'s folder as ``<label>.prof`` if that is set
    (the CPU time of this thread: waiting is not counted)."""
    folder = os.environ.get(PROFILE_ENV)
    if not folder:
        spin_until_shutdown(executor)
        return
    profile = cProfile.Profile(time.thread_time)
    profile.enable()
    try:
        spin_until_shutdown(executor)
    finally:
        profile.disable()
        profile.dump_stats(Path(folder) / f"{label}.prof")


def run_reported(label: str, run: Callable[..., int], *args: Any, **kwargs: Any) -> int:
    """The exit status of ``run(*args, **kwargs)`` (a node process's :func:`run_node`), a user error it raises (a
    :class:`~fiper_ros.errors.FiperError`: an environment the set-up refuses, a port taken, a node's command line)
    reported as ``LABEL: MESSAGE`` on one line, status :data:`~fiper_ros.errors.EXIT_USAGE`, as ``fiper`` reports
    one; any other exception keeps its traceback. The console scripts' ``main`` call their node through it."""
    try:
        return run(*args, **kwargs)
    except FiperError as error:
        return report(label, error)


def run_node(factory: Callable[..., Any], args: list[str] | None = None, threads: int = 1,
             executor: str = EXECUTOR_SINGLE) -> int:
    """Create the node from ``factory`` and spin it (in ``threads`` threads: callback groups of its own run
    beside the default group; one thread: on the ``executor`` kind unless :data:`EXECUTOR_ENV` says otherwise)
    until interrupted; returns the exit status."""
    return run_nodes([factory], args, threads, executor)


def run_nodes(factories: Sequence[Callable[..., Any]], args: list[str] | None = None, threads: int = 1,
              executor: str = EXECUTOR_SINGLE) -> int:
    """:func:`run_node` for several nodes in this one process, created in order from ``factories`` and spun by
    one executor (:mod:`fiper_ros.nodes.container`); the same ``--ros-args`` reach every one. Returns the exit
    status."""
    faulthandler.enable()
    faulthandler.register(STACKS_SIGNAL, all_threads=True)
    die_with_parent()
    profile = use_discovery_profile()
    rclpy.init(args=sys.argv if args is None else args)
    signal.signal(signal.SIGTERM, _on_sigterm)
    nodes: list[Any] = []
    try:
        for factory in factories:
            nodes.append(factory())
        if profile is not None:
            nodes[0].get_logger().info(discovery_note(profile))
        spinner = new_executor(threads, executor)
        for node in nodes:
            spinner.add_node(node)
        gc.collect()
        gc.freeze()
        spin_profiled(spinner, "+".join(node.get_name() for node in nodes))
    except KeyboardInterrupt:  # during start-up
        pass
    except (RCLError, NotInitializedException):
        # a signal shut the context down while a node was being built
        if rclpy.ok():
            raise
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)  # shutting down already: a SIGTERM now would re-enter it
        faulthandler.dump_traceback_later(TEARDOWN_S, exit=True)
        try:
            for node in reversed(nodes):
                node.destroy_node()
            shut_down()
            faulthandler.cancel_dump_traceback_later()
        finally:
            signal.alarm(EXIT_S)  # no handler: past EXIT_S the kernel ends the process, wherever its exit hangs
    return 0
