"""``fiper launch`` in a subprocess for the process-level tests: its output collected line by line."""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

from helpers.dds import ros_env


class Launch:
    """``fiper launch CONFIG`` in its own process group and ROS domain."""

    def __init__(self, config: Path, domain: int) -> None:
        self.proc = subprocess.Popen(  # noqa: S603
            [sys.executable, "-m", "fiper_ros.cli", "launch", str(config), "--grace", "5"],
            env=ros_env(domain), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
        self.lines: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip())

    def pids_of(self, name: str) -> list[int]:
        """Every pid the launcher started ``name`` with (respawns add one each), in order."""
        pattern = re.compile(rf"\[launch\] started {name} \(pid (\d+)\)")
        return [int(m.group(1)) for line in list(self.lines) if (m := pattern.match(line))]

    def pid_of(self, name: str) -> int:
        """The pid of the latest start of ``name``."""
        pids = self.pids_of(name)
        if not pids:
            raise AssertionError(f"{name} not started:\n" + "\n".join(self.lines))
        return pids[-1]

    def interrupt(self) -> int:
        """Ctrl-C the launch; its exit status."""
        os.killpg(self.proc.pid, signal.SIGINT)
        return self.proc.wait(timeout=30)

    def kill(self) -> None:
        """SIGKILL the whole launch (a test's clean-up after a failure)."""
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(timeout=30)
