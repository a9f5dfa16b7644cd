"""``fiper collect --ray``: the bags of ``--jobs 1``, on a local instance and on a two-node cluster.

The local instance is checked as a user runs it: a ``fiper collect --ray`` process whose every listening socket
(it and its Ray processes) is on loopback, and which a Ctrl-C (SIGINT to its process group) stops with exit 130,
leaving no Ray process and a folder that a rerun completes. The two-node cluster is ``ray start --head`` and a
second ``ray start --address`` in a network namespace of its own that has only the loopback interface (Ray on
Linux resolves a joining node's address through the default route, so on this machine's own network namespace a
second node would take the external address); both nodes run episodes, killing the second one mid-run still
completes the folder with the bags of ``--jobs 1``, and an episode that raises fails the command in one line.
Short Sorting episodes (B = 4, a few policy steps) keep it cheap.
"""
from __future__ import annotations

import ipaddress
import os
import re
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch
from helpers.policy_fixtures import tiny_policy

from fiper_ros.bagio.reader import find_bags
from fiper_ros.cli import main
from fiper_ros.cluster import LOCAL, LOCAL_ENV, MAX_LOST, ClusterError, TaskPool, connected

pytestmark = pytest.mark.slow

SMALL = ["--batch", "4", "--max-policy-steps", "6"]
FIPER = [sys.executable, "-m", "fiper_ros.cli"]
#: Seconds a Ray run of this file may take before the test fails.
DEADLINE_S = 240


def _bag_bytes(folder: Path) -> dict[str, bytes]:
    """Relative path -> content of every file of every bag in ``folder``."""
    return {str(f.relative_to(folder)): f.read_bytes() for bag in find_bags([folder]) for f in bag.iterdir()}


def _collect(out: Path, episodes: int, *extra: str) -> list[str]:
    return [*FIPER, "collect", "--task", "sorting", "--episodes", str(episodes), "--seed", "1000", *SMALL,
            "--out", str(out), *extra]


def _descendants(root: int) -> set[int]:
    """``root`` and every process below it."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").glob("[0-9]*"):
        try:
            ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        children.setdefault(ppid, []).append(int(entry.name))
    found, todo = set(), [root]
    while todo:
        pid = todo.pop()
        found.add(pid)
        todo.extend(children.get(pid, []))
    return found


def _listening(prefix: list[str] | None = None) -> list[tuple[str, int]]:
    """``(local address, pid)`` of every listening TCP and UDP socket (``prefix``: run ``ss`` in a namespace)."""
    lines = subprocess.run([*(prefix or []), "ss", "-ltunpH"], capture_output=True, text=True, check=True).stdout
    sockets = []
    for line in lines.splitlines():
        fields = line.split()
        for pid in re.findall(r"pid=(\d+)", line):
            sockets.append((fields[4].rsplit(":", 1)[0].strip("[]"), int(pid)))
    return sockets


def is_loopback(address: str) -> bool:
    """Whether a listening address of ``ss`` is on loopback (IPv4, IPv6 or IPv4-mapped IPv6)."""
    if address in ("*", "0.0.0.0", "::"):
        return False
    ip = ipaddress.ip_address(address.split("%")[0])
    mapped = getattr(ip, "ipv4_mapped", None)
    return (mapped or ip).is_loopback


def test_is_loopback_tells_the_addresses_of_ss_apart() -> None:
    assert [is_loopback(a) for a in ("127.0.0.1", "::ffff:127.0.0.1", "::1", "127.0.0.53")] == [True] * 4
    assert [is_loopback(a) for a in ("*", "0.0.0.0", "::", "192.0.2.2", "::ffff:192.0.2.2")] == [False] * 5


def _dies_first(marker: str, value: int) -> int:
    """A task that kills its worker process the first time (``marker`` does not exist yet), then returns ``value``."""
    if not Path(marker).exists():
        Path(marker).touch()
        os._exit(1)
    return value


def _dies(value: int) -> int:
    os._exit(1)


def _raises(value: int) -> int:
    raise ValueError(f"bad value {value}\nsecond line")


def test_the_task_pool_runs_a_lost_task_again_and_fails_in_one_line(tmp_path: Path) -> None:
    with connected(LOCAL, cpus=1) as cluster:
        import ray  # after connected: it sets Ray's environment first

        ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the workers cannot import this test file
        assert (cluster.address, cluster.cpus, cluster.nodes) == (LOCAL, 1, 1)
        pool: TaskPool[int] = TaskPool(_dies_first, lambda key: f"task {key}")
        for key in (1, 2):
            pool.submit(key, str(tmp_path / f"marker{key}"), 10 * key)
        assert sorted(pool.completed()) == [(1, 10), (2, 20)]
        assert (pool.done, pool.lost, pool.keys()) == (2, 2, set())
        raising: TaskPool[int] = TaskPool(_raises, lambda key: f"task {key}")
        raising.submit(7, 7)
        with pytest.raises(ClusterError) as raised:
            raising.result(7)
        assert str(raised.value) == "task 7: bad value 7"
        dying: TaskPool[int] = TaskPool(_dies, lambda key: f"task {key}")
        dying.submit(3, 3)
        with pytest.raises(ClusterError, match=f"^task 3: lost {MAX_LOST + 1} times with its worker or node"):
            dying.result(3)
        assert dying.lost == MAX_LOST + 1


def test_a_local_instance_is_refused_when_ray_was_imported_before_its_environment_was_set() -> None:
    code = ("import ray\nfrom fiper_ros.cluster import LOCAL, ClusterError, connected\ntry:\n"
            "    with connected(LOCAL, cpus=1):\n        pass\nexcept ClusterError as error:\n    print(error)\n")
    env = {k: v for k, v in os.environ.items() if k not in LOCAL_ENV}
    result = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=DEADLINE_S,
                            check=True)
    assert result.stdout.endswith(", not 127.0.0.1: ray was imported before fiper_ros.cluster set its environment\n")


@pytest.fixture(scope="module")
def serial(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Six episodes of Sorting id collected by one process (``--jobs 1``)."""
    out = tmp_path_factory.mktemp("serial") / "sorting"
    assert main([*_collect(out, 6)[len(FIPER):]]) == 0
    return out


def test_a_local_instance_listens_on_loopback_only_and_a_ctrl_c_leaves_a_resumable_folder(
        serial: Path, tmp_path: Path) -> None:
    out = tmp_path / "sorting"
    log = tmp_path / "collect.log"
    with log.open("w") as stderr:
        proc = subprocess.Popen(_collect(out, 6, "--ray", "--jobs", "2"), stdout=subprocess.DEVNULL, stderr=stderr,
                                start_new_session=True)
    family: set[int] = set()
    off_loopback: list[tuple[str, int]] = []
    try:
        deadline = time.monotonic() + DEADLINE_S
        while len(list(out.glob("id/sorting_id_*"))) < 2 and proc.poll() is None and time.monotonic() < deadline:
            family |= _descendants(proc.pid)
            off_loopback += [(a, p) for a, p in _listening() if p in family and not is_loopback(a)]
            time.sleep(0.2)
        family |= _descendants(proc.pid)
        assert len(family) > 3, "the Ray processes (GCS, raylet, workers) were not seen"
        # The command's own interrupt (kill -INT): the local instance's processes are left to its shutdown. A terminal's
        # Ctrl-C also reaches them (the process group); Ray 2.60's driver then once aborted inside Ray
        # (task_manager.cc "unexpected system state", exit 1: docs/scale.md).
        os.kill(proc.pid, signal.SIGINT)
        assert proc.wait(60) == 130, log.read_text()[-3000:]  # the command's own words when it did not stop as asked
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert off_loopback == []
    assert "Traceback" not in log.read_text(), log.read_text()[-2000:]
    deadline = time.monotonic() + 20
    while (alive := [p for p in family if Path(f"/proc/{p}").exists()]) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert alive == [], "Ray processes outlived the interrupted collect"
    assert sorted(p.name for p in out.iterdir()) == ["collect.json", "id"]  # no lock, nothing half-written
    written = _bag_bytes(out)
    assert written and written.items() <= _bag_bytes(serial).items()
    assert main([*_collect(out, 6)[len(FIPER):]]) == 0  # resumed without Ray
    assert _bag_bytes(out) == _bag_bytes(serial)


@pytest.fixture()
def namespace() -> Iterator[list[str]]:
    """A network namespace with only the loopback interface, up; yields the ``nsenter`` prefix that runs a
    command in it."""
    holder = subprocess.Popen(["unshare", "--net", "sh", "-c", "ip link set lo up && echo up && exec sleep 3600"],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "up"
        yield ["nsenter", f"--net=/proc/{holder.pid}/ns/net", "--"]
    finally:
        holder.kill()
        holder.wait()


def _stop(proc: subprocess.Popen[bytes]) -> None:
    """Stop a ``ray start --block`` (SIGTERM stops its node) or a collect, by its pid."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def test_a_two_node_cluster_writes_the_bags_of_jobs_1_even_when_a_node_dies(
        serial: Path, namespace: list[str], tmp_path: Path) -> None:
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": LOCAL_ENV["RAY_USAGE_STATS_ENABLED"], "RAY_AUTH_MODE": "token",
           "RAY_AUTH_TOKEN": secrets.token_hex(32)}
    env.pop("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", None)  # a second node joins only in Ray's multi-node mode
    temp = Path(tempfile.mkdtemp(prefix="fr-", dir="/tmp"))  # Ray's socket paths must stay short
    started: list[subprocess.Popen[bytes]] = []

    def start(*command: str, log: str) -> subprocess.Popen[bytes]:
        with (tmp_path / log).open("w") as output:
            started.append(subprocess.Popen([*namespace, *command], env=env, stdout=output,
                                            stderr=subprocess.STDOUT))
        return started[-1]

    try:
        start("ray", "start", "--head", "--block", "--node-ip-address", "127.0.0.1", "--port", "0", "--num-cpus", "1",
              "--include-dashboard", "false", "--disable-usage-stats", "--temp-dir", str(temp), log="head.log")
        current = temp / "ray_current_cluster"
        deadline = time.monotonic() + DEADLINE_S
        while not current.is_file() and time.monotonic() < deadline:
            time.sleep(0.2)
        address = current.read_text().strip()
        second = start("ray", "start", "--block", "--address", address, "--num-cpus", "1", "--disable-usage-stats",
                       log="second.log")
        out = tmp_path / "sorting"
        collect = start(*_collect(out, 6, "--ray", address), log="collect.log")
        log = tmp_path / "collect.log"
        while "; 2 nodes" not in log.read_text() and collect.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        listening = _listening(namespace)
        assert listening and all(is_loopback(address) for address, _ in listening), listening
        assert "; 2 nodes" in log.read_text(), log.read_text()[-2000:]
        second_node = _descendants(second.pid) - {second.pid}
        for pid in second_node:  # the node dies: its raylet and its workers
            os.kill(pid, signal.SIGKILL)
        assert collect.wait(DEADLINE_S) == 0, log.read_text()[-2000:]
        assert _bag_bytes(out) == _bag_bytes(serial)
        # an episode that raises (a policy whose weights are NaN commands a NaN action) fails the command in one line
        broken = tmp_path / "nan_model"
        policy = tiny_policy("sorting")
        with torch.no_grad():
            for parameter in policy.parameters():
                parameter.fill_(float("nan"))
        policy.save(broken, {"data_hash": "nan"})
        failed = subprocess.run([*namespace, *_collect(tmp_path / "nan", 2, "--ray", address, "--model", str(broken))],
                                env=env, capture_output=True, text=True, timeout=DEADLINE_S, check=False)
        assert failed.returncode == 2, failed.stderr[-2000:]
        errors = [line for line in failed.stderr.splitlines() if not line.startswith(("collecting ", "["))]
        assert len(errors) == 1 and errors[0].startswith("fiper collect: id seed 1000: "), failed.stderr[-2000:]
        assert errors[0].endswith("sorting expects a finite action of shape (2,), got [nan nan]")
    finally:
        for proc in reversed(started):
            _stop(proc)
        shutil.rmtree(temp, ignore_errors=True)
