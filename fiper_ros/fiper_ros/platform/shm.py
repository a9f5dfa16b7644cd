"""Fast DDS shared-memory hygiene: remove the ``/dev/shm`` files of dead processes, never a live one's.

What Fast DDS 2.14 (rmw_fastrtps 8.4, the pip wheels) keeps in ``/dev/shm``, under its SHM domain name
``fastrtps``:

- ``fastrtps_<16 hex>``: a participant's data segment (a random name); ``fastrtps_<16 hex>_el`` its lock
  file, ``flock``-ed exclusively by the creating process from before the segment exists until it is gone.
- ``fastrtps_port<N>``: port N, the ring of buffer descriptors a reader listens on; ``..._el`` / ``..._sl``
  the lock file its exclusive / shared listener holds ``flock``-ed while it lives.
- ``sem.fastrtps_port<N>_mutex``: the POSIX named semaphore Fast DDS holds while it opens, resets or
  creates port N.

A clean exit removes most of a process's files; a killed one leaves them all, and a port often outlives a
clean exit too (a killed peer's reference count keeps it). Fast DDS resets a dead port when it opens that
port again, but never reuses a data segment's name, so those pile up (docs/benchmarks.md: 950 stale
files halved the node benchmark's sustained rate).

A group (a data segment or a port, with its lock files) is in use, and kept, when

1. it has lock files and one of them is ``flock``-ed or held open by a live process (Fast DDS's own
   zombie test, that of ``fastdds shm clean``; a process holds the file open from just before it locks it).
   Peers that still map a group whose owner died keep their mappings, as when Fast DDS resets a dead
   port itself;
2. it has none (a port whose listener left cleanly while a killed writer's reference kept it; Fast DDS
   reuses such a port as it is) and a live process maps it or holds it open (``/proc/<pid>/maps``, ``fd``).

Everything else of this user is removed. A port is judged and removed while holding its semaphore
(``sem_trywait``: a port being opened is left for the next time; held at most :data:`PORT_HOLD_S`), so
no Fast DDS process opens it in between; a data segment's random name is not opened again once its
owner is dead. Lock files go last, while locked by the cleaner and only if their path still names the
locked file, so several cleaners at once remove each file at most once. The semaphores stay: they are
the ports' lock (32 bytes each, reused by Fast DDS). Processes of other users are not read: they cannot
open these files for writing (mode 0644). A pass takes milliseconds, or some tens of them when a
lock-less group makes it read every process's maps (docs/nodes.md, "Shared memory of dead processes").
"""
from __future__ import annotations

import ctypes
import errno
import fcntl
import os
import re
import stat
import time
from collections.abc import Iterable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path

SHM_DIR = Path("/dev/shm")
#: Fast DDS's default shared-memory domain name (the prefix of every file it creates).
DOMAIN = "fastrtps"
_NAME = re.compile(rf"^{DOMAIN}_(?P<group>[0-9a-f]{{16}}|port(?P<port>\d+))(?P<lock>_el|_sl)?$")
#: Semaphore permissions and initial value as Fast DDS (Boost.Interprocess ``named_mutex``) creates them.
_SEM_MODE, _SEM_UNLOCKED = 0o644, 1
#: Seconds the cleaner may hold port semaphores: Fast DDS waits 2 s for one, then takes it as abandoned.
PORT_HOLD_S = 1.0


@dataclass
class Group:
    """The files of one data segment or one port (names in the shm directory)."""

    port: int | None
    """The port's number; ``None`` for a data segment."""
    data: list[str] = field(default_factory=list)
    locks: list[str] = field(default_factory=list)

    @property
    def semaphore(self) -> str:
        """The ``sem_open`` name of a port's semaphore."""
        return f"/{DOMAIN}_port{self.port}_mutex"


@dataclass(frozen=True)
class CleanResult:
    """What one :func:`clean_stale` pass did."""

    removed: tuple[str, ...]
    """Names of the files this pass removed."""
    freed_bytes: int
    kept: int
    """Groups in use (or changing while looked at)."""
    busy: int
    """Ports left alone because a process was opening them."""

    def summary(self) -> str:
        """One log line."""
        return (f"removed {len(self.removed)} stale Fast DDS shared-memory files ({self.freed_bytes / 1e6:.1f} MB) "
                f"from {SHM_DIR}; kept {self.kept} in use" + (f", {self.busy} being opened" if self.busy else ""))


def group_files(names: Iterable[str]) -> dict[str, Group]:
    """The Fast DDS data segments and ports among ``names`` (semaphores and other files left out)."""
    groups: dict[str, Group] = {}
    for name in names:
        match = _NAME.match(name)
        if match is None:
            continue
        port = match.group("port")
        group = groups.setdefault(match.group("group"), Group(int(port) if port else None))
        (group.locks if match.group("lock") else group.data).append(name)
    return groups


def maps_inodes(maps: Iterable[bytes], device: bytes, prefix: bytes) -> Iterator[int]:
    """Inodes of the files under ``prefix`` on ``device`` (``maj:min`` in hex) in the lines of a
    ``/proc/<pid>/maps``."""
    for line in maps:
        if prefix in line:
            fields = line.split(maxsplit=5)
            if len(fields) == 6 and fields[3] == device and fields[5].startswith(prefix):
                yield int(fields[4])


@dataclass(frozen=True)
class Usage:
    """Inodes of the files in :data:`SHM_DIR` that live processes of this user hold open or map."""

    opened: set[int]
    mapped: set[int]
    """Mapped or open; empty unless asked for (reading every process's maps is the slow part)."""


def used_inodes(with_maps: bool) -> Usage:
    """What live processes hold open (``/proc/<pid>/fd``) and, ``with_maps``, map (``/proc/<pid>/maps``)."""
    dev = os.stat(SHM_DIR).st_dev
    device, prefix, uid = f"{os.major(dev):02x}:{os.minor(dev):02x}".encode(), f"{SHM_DIR}/", os.getuid()
    mapped: set[int] = set()
    opened: set[int] = set()
    for proc in os.scandir("/proc"):
        if not proc.name.isdigit():
            continue
        try:
            if uid != 0 and proc.stat().st_uid != uid:
                continue
            if with_maps:
                with open(Path(proc.path, "maps"), "rb") as maps:
                    mapped.update(maps_inodes(maps, device, prefix.encode()))
            fds = list(os.scandir(Path(proc.path, "fd")))
        except OSError:  # exited meanwhile
            continue
        for fd in fds:
            try:
                if os.readlink(fd.path).startswith(prefix) and (st := os.stat(fd.path)).st_dev == dev:
                    opened.add(st.st_ino)
            except OSError:
                continue
    return Usage(opened, mapped | opened if with_maps else set())


class _Semaphores:
    """Fast DDS's port semaphores, taken without waiting (libc ``sem_open`` / ``sem_trywait`` via ctypes)."""

    def __init__(self) -> None:
        libc = ctypes.CDLL(None, use_errno=True)
        self._open = libc.sem_open
        self._open.restype = ctypes.c_void_p
        self._open.argtypes = [ctypes.c_char_p, ctypes.c_int, ctypes.c_uint, ctypes.c_uint]
        self._trywait, self._post, self._close = libc.sem_trywait, libc.sem_post, libc.sem_close
        for function in (self._trywait, self._post, self._close):
            function.argtypes = [ctypes.c_void_p]

    @contextmanager
    def hold(self, name: str) -> Iterator[bool]:
        """Hold semaphore ``name`` (created as Fast DDS would if missing) for the block; ``False``: it is taken."""
        sem = self._open(name.encode(), os.O_CREAT, _SEM_MODE, _SEM_UNLOCKED)
        if not sem:
            yield False
            return
        try:
            if self._trywait(sem) != 0:
                yield False
                return
            try:
                yield True
            finally:
                self._post(sem)
        finally:
            self._close(sem)


def _lock(path: Path) -> int | None:
    """A descriptor holding ``path``'s ``flock`` (exclusive) if nobody else holds it and the path still names
    the locked file; ``None`` otherwise."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        if os.stat(path, follow_symlinks=False).st_ino == os.fstat(fd).st_ino:
            return fd
    except OSError as error:
        if error.errno not in (errno.EWOULDBLOCK, errno.ENOENT):
            raise
    os.close(fd)
    return None


def _own_files(names: Iterable[str]) -> dict[str, os.stat_result]:
    """The regular files of this user among ``names``."""
    out = {}
    for name in names:
        try:
            st = os.stat(SHM_DIR / name, follow_symlinks=False)
        except OSError:
            continue
        if stat.S_ISREG(st.st_mode) and st.st_uid == os.getuid():
            out[name] = st
    return out


def _remove_group(group: Group, files: dict[str, os.stat_result], usage: Usage) -> list[str] | None:
    """Remove ``group`` if it is stale (see the module docstring); the removed names, ``None`` if in use."""
    locks = [name for name in group.locks if name in files]
    if locks and any(files[name].st_ino in usage.opened for name in locks):
        return None
    if not locks and any(files[name].st_ino in usage.mapped for name in group.data if name in files):
        return None
    with ExitStack() as held:
        for name in locks:
            fd = _lock(SHM_DIR / name)
            if fd is None:
                return None
            held.callback(os.close, fd)
        removed = []
        for name in [*group.data, *locks]:  # lock files last: they are what says the group is alive
            try:
                if os.stat(SHM_DIR / name, follow_symlinks=False).st_ino == files[name].st_ino:
                    os.unlink(SHM_DIR / name)
                    removed.append(name)
            except (OSError, KeyError):
                continue
        return removed


def clean_stale() -> CleanResult:
    """Remove every Fast DDS data segment and port of this user that no live process owns (module docstring)."""
    try:
        names = os.listdir(SHM_DIR)
    except FileNotFoundError:
        return CleanResult((), 0, 0, 0)
    groups = group_files(names)
    files = _own_files([name for group in groups.values() for name in (*group.data, *group.locks)])
    mine = [group for group in groups.values() if any(n in files for n in (*group.data, *group.locks))]
    if not mine:
        return CleanResult((), 0, 0, 0)
    semaphores = _Semaphores()
    outcomes: list[list[str] | None] = []
    busy = 0
    with ExitStack() as stack:
        held_since = time.monotonic()
        ports = []
        for group in (g for g in mine if g.port is not None):
            if stack.enter_context(semaphores.hold(group.semaphore)):
                ports.append(group)
            else:
                busy += 1
        # after taking the semaphores: no port is opened from here on
        usage = used_inodes(with_maps=any(not any(n in files for n in group.locks) for group in mine))
        for group in ports:
            if time.monotonic() - held_since > PORT_HOLD_S:
                busy += 1
            else:
                outcomes.append(_remove_group(group, files, usage))
    outcomes += [_remove_group(group, files, usage) for group in mine if group.port is None]
    removed = tuple(name for outcome in outcomes if outcome is not None for name in outcome)
    freed = sum(files[name].st_blocks * 512 for name in removed)
    return CleanResult(removed, freed, sum(outcome is None for outcome in outcomes), busy)
