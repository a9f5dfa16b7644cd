"""Running one node in its own process: init, spin, clean shutdown on SIGINT / SIGTERM.

After start-up every object that exists (rclpy, numpy, torch, the node) is moved out of the garbage
collector's reach (``gc.freeze``): a full collection then only walks what the callbacks allocate, so it
no longer stalls a callback for milliseconds (the tail of the node benchmark, docs/benchmarks.md).
A crash of the process prints every thread's Python stack (``faulthandler``), which the launcher shows.
A node started by ``fiper launch`` dies with it (``FIPER_PARENT_PID``: Linux's parent-death signal), so a
killed launcher never leaves a stale suite speaking on the suite's topics.
"""
from __future__ import annotations

import faulthandler
import gc
import os
import signal
import sys
from collections.abc import Callable
from typing import Any

import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.exceptions import NotInitializedException
from rclpy.executors import Executor, ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor

from fiper_ros.dds import die_with_parent

CALLBACK_DRAIN_S = 30.0
"""Longest wait at shutdown for callbacks still running (a policy step of a large batch takes seconds)."""


def spin_until_shutdown(executor: Executor) -> None:
    """Spin until Ctrl-C / SIGTERM shuts rclpy down, however rclpy reports the shutdown; return once the
    callbacks in flight have finished (``stop_executor``)."""
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RCLError:
        # rclpy's signal handler shuts the context down; if that lands while the executor builds its wait
        # set, rcl reports an invalid context instead of ExternalShutdownException.
        if rclpy.ok():
            raise
    finally:
        stop_executor(executor)


def stop_executor(executor: Executor) -> None:
    """Shut ``executor`` down and wait (at most ``CALLBACK_DRAIN_S``) for the callbacks still running in its
    threads, so that its nodes may be destroyed (a callback that outlives its node fails on a destroyed
    handle)."""
    executor.shutdown()
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


def _on_sigterm(*_: Any) -> None:
    """SIGTERM: shut rclpy down, once. Python runs a handler inside whatever the main thread waits on (a lock,
    a join), so a second SIGTERM (the launcher's stop, then the parent-death signal as the launcher exits)
    must not enter ``shut_down`` again while the first holds rclpy's context lock: that deadlocked a fusion
    node, which then outlived its test and the launcher, still in the domain."""
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    shut_down()


def run_node(factory: Callable[..., Any], args: list[str] | None = None, threads: int = 1) -> int:
    """Create the node from ``factory`` and spin it (in ``threads`` threads: callback groups of its own run
    beside the default group) until interrupted; returns the exit status."""
    faulthandler.enable()
    die_with_parent()
    rclpy.init(args=sys.argv if args is None else args)
    signal.signal(signal.SIGTERM, _on_sigterm)
    node = None
    try:
        node = factory()
        executor = SingleThreadedExecutor() if threads == 1 else MultiThreadedExecutor(num_threads=threads)
        executor.add_node(node)
        gc.collect()
        gc.freeze()
        spin_until_shutdown(executor)
    except KeyboardInterrupt:  # during start-up
        pass
    except (RCLError, NotInitializedException):
        # a signal shut the context down while the node was being built
        if rclpy.ok():
            raise
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)  # shutting down already: a SIGTERM now would re-enter it
        if node is not None:
            node.destroy_node()
        shut_down()
    return 0
