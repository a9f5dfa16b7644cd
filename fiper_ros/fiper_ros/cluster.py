"""The platform of the parallel offline work: a Ray cluster, a local instance on loopback or an existing one.

:func:`connected` joins the cluster for the duration of a ``with`` block; :class:`TaskPool` runs one Ray task per
unit of work (an episode, a bag), fetches each result as soon as it is ready, runs again a task whose worker or
node was lost (at most :data:`MAX_LOST` times: a lost task never leaves a partial result, since every result
goes to the caller, which writes it) and turns a task that raised into one line naming its reason. ``ray`` is
imported inside the functions only: a command that does not ask for Ray never loads it (``test_layers.py``
names the modules that may import it). How to run on a real cluster: docs/scale.md.
"""
from __future__ import annotations

import logging
import os
from collections import Counter
from collections.abc import Callable, Hashable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from fiper_ros.errors import FiperError

#: ``--ray`` without an address: a new Ray instance on this machine, stopped at the end.
LOCAL = "local"
#: Environment of a local instance, set before ``ray`` is imported. Ray binds every server of a node to its
#: node address, which is 127.0.0.1 only while Ray's multi-node mode is off (the network rule: nothing of the
#: project listens off loopback); no usage reports leave the machine.
LOCAL_ENV = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0", "RAY_USAGE_STATS_ENABLED": "0"}
#: The address of every server of a local instance.
LOOPBACK = "127.0.0.1"
#: How often one task may lose its worker or node before the command fails.
MAX_LOST = 3

K = TypeVar("K", bound=Hashable)


class ClusterError(FiperError):
    """The cluster cannot be reached, or a task failed: the message is one line, for ``fiper COMMAND: ...``."""


@dataclass(frozen=True)
class Cluster:
    """The cluster joined by :func:`connected`.

    Attributes:
        address: The address given (:data:`LOCAL` for a local instance).
        cpus: CPUs of the cluster when joined (the number of tasks that run at once).
        nodes: Live nodes when joined.
    """

    address: str
    cpus: int
    nodes: int


def first_line(error: BaseException) -> str:
    """``error``'s message up to its first line break (a Ray error's traceback follows it)."""
    text = str(error).strip().splitlines()
    return text[0] if text else type(error).__name__


@contextmanager
def connected(address: str, cpus: int | None = None) -> Iterator[Cluster]:
    """Join the Ray cluster at ``address`` (``auto``, ``host:port``, ``ray://host:10001``) or, for :data:`LOCAL`,
    start an instance on this machine bound to 127.0.0.1 with ``cpus`` CPUs (default: all cores) and no
    dashboard; leave it (and stop a local instance) at the end of the block. Inside a block that joined already,
    the cluster joined is used as it is and left by that block.

    Raises:
        ClusterError: Ray cannot reach ``address`` (or a local instance does not start).
    """
    if address == LOCAL:
        os.environ.update(LOCAL_ENV)
    import ray  # noqa: PLC0415 - only commands that ask for Ray load it

    if ray.is_initialized():  # joined by an enclosing block (one command, one cluster): that block leaves it
        yield Cluster(address, cluster_cpus(), sum(node["Alive"] for node in ray.nodes()))
        return
    options: dict[str, Any] = {"logging_level": logging.ERROR, "log_to_driver": False}
    if address == LOCAL:
        options |= {"address": "local", "num_cpus": cpus, "include_dashboard": False}
    else:
        if cpus is not None:
            raise ClusterError(f"the CPUs of the cluster at {address} are its own: give no CPU count with an address")
        options["address"] = address
    try:
        ray.init(**options)
    except (ConnectionError, RuntimeError, ValueError, TimeoutError) as error:
        raise ClusterError(f"cannot join the Ray cluster at {address}: {first_line(error)}") from error
    node_address = ray.util.get_node_ip_address()
    if address == LOCAL and node_address != LOOPBACK:
        ray.shutdown()
        raise ClusterError(f"the local Ray instance took the address {node_address}, not {LOOPBACK}: ray was "
                           "imported before fiper_ros.cluster set its environment")
    try:
        resources = ray.cluster_resources()
        yield Cluster(address, int(resources.get("CPU", 0)), sum(node["Alive"] for node in ray.nodes()))
    finally:
        ray.shutdown()


def cluster_cpus() -> int:
    """CPUs of the joined cluster now (nodes may have joined or left)."""
    import ray  # noqa: PLC0415

    return int(ray.cluster_resources().get("CPU", 0))


class TaskPool(Generic[K]):
    """Ray tasks of one function, keyed by the caller.

    Each task takes one CPU. Results are fetched as soon as a task is ready (:meth:`result`, :meth:`completed`)
    and held until the caller takes them. A task whose worker process or node was lost (the process killed,
    the node gone, its result lost with the node) runs again, at most :data:`MAX_LOST` times; a task that
    raised fails the pool with :class:`ClusterError` naming ``describe(key)`` and the exception's message.

    Args:
        function: A module-level function (Ray's workers import it by name).
        describe: How a key is named in an error.
    """

    def __init__(self, function: Callable[..., Any], describe: Callable[[K], str]) -> None:
        import ray  # noqa: PLC0415

        self._ray = ray
        self._remote = ray.remote(num_cpus=1, max_retries=0)(function)
        self._describe = describe
        self._calls: dict[K, tuple[Any, ...]] = {}
        self._refs: dict[K, Any] = {}
        self._ready: dict[K, Any] = {}
        self._lost: Counter[K] = Counter()
        #: Tasks whose result was fetched.
        self.done = 0
        #: Task runs lost with their worker or node (each ran again).
        self.lost = 0

    def submit(self, key: K, *args: Any) -> None:
        """Start ``function(*args)`` as the task ``key`` (nothing if it is already started or ready)."""
        if key not in self._refs and key not in self._ready:
            self._calls[key] = args
            self._refs[key] = self._remote.remote(*args)

    def keys(self) -> set[K]:
        """The tasks started and not taken (running, queued or ready)."""
        return set(self._refs) | set(self._ready)

    def drop(self, key: K) -> None:
        """Cancel the task ``key`` (or forget its result)."""
        ref = self._refs.pop(key, None)
        if ref is not None:
            self._ray.cancel(ref)
        self._ready.pop(key, None)
        self._calls.pop(key, None)

    def close(self) -> None:
        """Forget every task not finished: they end with the driver's job when :func:`connected` leaves the cluster
        (a local instance stops, a cluster ends the job's tasks). Not ``ray.cancel(force=True)``: a task that
        completed while it was being cancelled made Ray 2.60's driver abort ("Tried to complete task that was not
        pending", task_manager.cc, exit 1) when a collect was interrupted (docs/scale.md)."""
        self._refs.clear()
        self._ready.clear()
        self._calls.clear()

    def result(self, key: K) -> Any:
        """The result of the started task ``key``, waiting for it (other results are fetched meanwhile)."""
        while key not in self._ready:
            if key not in self._refs:
                raise KeyError(key)
            self._fetch()
        self._calls.pop(key)
        return self._ready.pop(key)

    def completed(self) -> Iterator[tuple[K, Any]]:
        """``(key, result)`` of every started task, in the order they finish."""
        while self._refs or self._ready:
            while not self._ready:  # a lost task is run again: the fetch may bring nothing
                self._fetch()
            key = next(iter(self._ready))
            self._calls.pop(key)
            yield key, self._ready.pop(key)

    def status(self) -> str:
        """``N done, R running, Q queued, L lost`` (running: at most the cluster's CPUs)."""
        running = min(len(self._refs), cluster_cpus())
        queued = len(self._refs) - running
        return f"{self.done} done, {running} running, {queued} queued, {self.lost} lost"

    def _fetch(self) -> None:
        """Wait for a task to be ready, then fetch the results of every task that is."""
        by_ref = {ref: key for key, ref in self._refs.items()}
        ready, waiting = self._ray.wait(list(by_ref), num_returns=1)
        if waiting:
            more, _ = self._ray.wait(waiting, num_returns=len(waiting), timeout=0)
            ready = [*ready, *more]
        for ref in ready:
            self._take(by_ref[ref], ref)

    def _take(self, key: K, ref: Any) -> None:
        exceptions = self._ray.exceptions
        try:
            value = self._ray.get(ref)
        except exceptions.RayTaskError as error:  # the function raised: its reason, in one line
            cause = error.cause if isinstance(error.cause, Exception) else error
            raise ClusterError(f"{self._describe(key)}: {first_line(cause)}") from None
        except (exceptions.WorkerCrashedError, exceptions.NodeDiedError, exceptions.LocalRayletDiedError,
                exceptions.ObjectLostError, exceptions.OutOfMemoryError, exceptions.RaySystemError) as error:
            self.lost += 1
            self._lost[key] += 1
            if self._lost[key] > MAX_LOST:
                raise ClusterError(f"{self._describe(key)}: lost {self._lost[key]} times with its worker or node "
                                   f"(the last time: {first_line(error)})") from None
            self._refs[key] = self._remote.remote(*self._calls[key])
            return
        except exceptions.RayError as error:  # not schedulable, no environment, ...: the cluster's reason
            raise ClusterError(f"{self._describe(key)}: {first_line(error)}") from None
        del self._refs[key]
        self._ready[key] = value
        self.done += 1
