"""Fast DDS shared-memory hygiene (fiper_ros.platform.shm) against real DDS processes on loopback: a SIGKILLed
node's segments and ports are removed, a running node's never, also with several cleaners at once and a
node starting meanwhile; the launcher reports what it removed at start-up."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from fiper_ros.platform.dds import interrupt_group
from fiper_ros.platform.shm import SHM_DIR, clean_stale, group_files, maps_inodes
from helpers.dds import ros_env, spawn_python, stop
from helpers.launch import node_entry, write_launch

#: Seconds a DDS node process gets to create its shared-memory files.
START_TIMEOUT_S = 60.0
LOCK = re.compile(r"_(el|sl)$")


def shm_files_of(pid: int) -> dict[str, int]:
    """Name -> inode of every file in /dev/shm that process ``pid`` maps or holds open (from /proc)."""
    files: dict[str, int] = {}
    for line in Path(f"/proc/{pid}/maps").read_text().splitlines():
        path = line.split(maxsplit=5)[-1]
        if path.startswith(f"{SHM_DIR}/") and not path.endswith("(deleted)"):
            files[Path(path).name] = int(line.split()[4])
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
            if target.startswith(f"{SHM_DIR}/"):
                files[Path(target).name] = os.stat(fd).st_ino
        except OSError:
            continue
    return {name: inode for name, inode in files.items() if name.startswith("fastrtps_")}


def owned_files(pid: int) -> dict[str, int]:
    """Name -> inode of the lock files ``pid`` holds open and of the segments / ports they guard."""
    files = shm_files_of(pid)
    locks = {name: inode for name, inode in files.items() if LOCK.search(name)}
    guarded = {LOCK.sub("", name) for name in locks}
    return locks | {name: inode for name, inode in files.items() if name in guarded}


def still_there(files: dict[str, int]) -> dict[str, int]:
    """Those of ``files`` that still exist as the same file (same inode)."""
    present = {}
    for name, inode in files.items():
        try:
            if os.stat(SHM_DIR / name).st_ino == inode:
                present[name] = inode
        except FileNotFoundError:
            continue
    return present


@contextmanager
def dds_node(domain: int) -> Iterator[subprocess.Popen[str]]:
    """A real DDS publisher process (every sample type at 10 Hz), once it holds its data segment's lock."""
    proc = spawn_python(["-m", "helpers.publish_samples"], domain)
    try:
        deadline = time.monotonic() + START_TIMEOUT_S
        while not any(LOCK.search(name) and "port" not in name for name in shm_files_of(proc.pid)):
            assert proc.poll() is None and time.monotonic() < deadline, f"no DDS segment:\n{stop(proc)}"
            time.sleep(0.1)
        yield proc
    finally:
        stop(proc)


def sigkill(proc: subprocess.Popen[str]) -> None:
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)


def cleaner_processes(count: int, seconds: float) -> list[subprocess.Popen[str]]:
    """``count`` processes that each clean again and again for ``seconds`` and print what they removed."""
    code = ("import json, sys, time\nfrom fiper_ros.platform.shm import clean_stale\n"
            "end = time.monotonic() + float(sys.argv[1])\nremoved = []\n"
            "while time.monotonic() < end:\n    removed += clean_stale().removed\nprint(json.dumps(removed))\n")
    command = [sys.executable, "-c", code, str(seconds)]
    return [subprocess.Popen(command, stdout=subprocess.PIPE, text=True) for _ in range(count)]


def test_group_files_pairs_segments_and_ports_with_their_lock_files() -> None:
    names = ["fastrtps_0123456789abcdef", "fastrtps_0123456789abcdef_el", "fastrtps_port7000",
             "fastrtps_port7000_el", "fastrtps_port7411_sl", "sem.fastrtps_port7000_mutex", "lttng-ust-wait-6",
             "fastrtps_port7000_el.bak", "fastrtps_0123", "fastrtps_0123456789ABCDEF", "xfastrtps_port1"]
    groups = group_files(names)
    assert sorted(groups) == ["0123456789abcdef", "port7000", "port7411"]
    segment, port, shared = groups["0123456789abcdef"], groups["port7000"], groups["port7411"]
    assert (segment.port, segment.data, segment.locks) == (None, ["fastrtps_0123456789abcdef"],
                                                           ["fastrtps_0123456789abcdef_el"])
    assert (port.port, port.data, port.locks, port.semaphore) == (7000, ["fastrtps_port7000"],
                                                                  ["fastrtps_port7000_el"], "/fastrtps_port7000_mutex")
    assert (shared.port, shared.data, shared.locks) == (7411, [], ["fastrtps_port7411_sl"])


def test_maps_inodes_reads_only_files_of_the_shm_device() -> None:
    maps = [b"7f00-7f01 rw-s 00000000 00:1b 2704                       /dev/shm/fastrtps_012fa136ad7279dc\n",
            b"7f01-7f02 rw-s 00000000 00:1c 99                         /dev/shm/fastrtps_port7000\n",
            b"7f02-7f03 r-xp 00000000 08:01 1234                       /usr/lib/libc.so.6\n",
            b"7f03-7f04 rw-p 00000000 00:00 0\n",
            b"7f04-7f05 rw-s 00000000 00:1b 2713                       /dev/shm/fastrtps_port7000 (deleted)\n"]
    assert list(maps_inodes(maps, b"00:1b", b"/dev/shm/")) == [2704, 2713]


def test_a_killed_nodes_files_go_and_a_running_nodes_stay(ros_domain: int) -> None:
    """The killed node shared the live node's domain, so the live node maps the dead one's ports and segment:
    those go too (as when Fast DDS resets a dead listener's port), the live node's own files stay."""
    with dds_node(ros_domain) as live:
        with dds_node(ros_domain) as victim:
            deadline = time.monotonic() + START_TIMEOUT_S
            while not (owned_files(victim.pid).keys() & shm_files_of(live.pid).keys()):  # they have met
                assert time.monotonic() < deadline, "the live node never mapped the victim's files"
                time.sleep(0.1)
            dead = owned_files(victim.pid)
            sigkill(victim)
        assert still_there(dead), "nothing was left behind: the test would prove nothing"
        live_files = owned_files(live.pid)
        result = clean_stale()
        deadline = time.monotonic() + START_TIMEOUT_S
        while still_there(dead) and result.busy and time.monotonic() < deadline:  # a port another node was
            time.sleep(0.5)  # opening is left for the next time (fiper_ros.platform.shm): the next cleaning takes it
            result = clean_stale()
        assert still_there(dead) == {}, result.summary()
        assert still_there(live_files) == live_files
        receiver = spawn_python(["-m", "helpers.receive_samples", "40"], ros_domain)
        out, _ = receiver.communicate(timeout=90)
        assert receiver.returncode == 0, out  # the live node still publishes to a new peer
        assert live.poll() is None


def test_cleaners_at_once_beside_a_starting_node_remove_each_file_once(ros_domain: int) -> None:
    dead: dict[str, int] = {}
    with dds_node(ros_domain) as live:
        for _ in range(2):
            with dds_node(ros_domain) as victim:
                dead |= owned_files(victim.pid)
                sigkill(victim)
        assert still_there(dead)
        cleaners = cleaner_processes(3, 6.0)
        with dds_node(ros_domain) as newcomer:  # starts while the cleaners run
            outputs = [json.loads(proc.communicate(timeout=60)[0]) for proc in cleaners]
            for files in (owned_files(newcomer.pid), owned_files(live.pid)):
                assert still_there(files) == files
            receiver = spawn_python(["-m", "helpers.receive_samples", "40"], ros_domain)
            out, _ = receiver.communicate(timeout=90)
            assert receiver.returncode == 0, out
    assert still_there(dead) == {}
    removed = [name for output in outputs for name in output]
    data_segments = [name for name in removed if "port" not in name]  # random names: removed at most once
    assert len(data_segments) == len(set(data_segments)), removed


def test_the_launcher_reports_and_removes_stale_files_before_starting_nodes(tmp_path: Path, ros_domain: int) -> None:
    with dds_node(ros_domain) as victim:
        dead = owned_files(victim.pid)
        sigkill(victim)
    config = write_launch(tmp_path / "launch.yaml", node_entry("supervisor_node"))
    launch = subprocess.Popen([sys.executable, "-m", "fiper_ros.cli", "launch", str(config)],
                              env=ros_env(ros_domain), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              start_new_session=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(line.rstrip() for line in launch.stdout or ()), daemon=True)
    reader.start()
    try:
        deadline = time.monotonic() + START_TIMEOUT_S
        while not any(line.startswith("[launch] started supervisor_node") for line in lines):
            assert launch.poll() is None and time.monotonic() < deadline, "\n".join(lines)
            time.sleep(0.1)
    finally:
        interrupt_group(launch.pid)
        launch.wait(timeout=60)
        reader.join(timeout=10)
    assert re.fullmatch(r"\[launch\] removed \d+ stale Fast DDS shared-memory files .*", lines[0]), lines
    assert lines[1].startswith("[launch] started supervisor_node"), lines
    assert still_there(dead) == {}
