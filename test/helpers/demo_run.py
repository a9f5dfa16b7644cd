"""``fiper demo`` as a user runs it, in a child process (test/demo)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]


def run_demo(out: Path, *args: str) -> tuple[subprocess.CompletedProcess[str], dict[str, Any]]:
    """``fiper demo --out OUT ARGS`` from the repository root, its live view on any free port (tests run side by
    side): asserted to exit 0 with no problem in its summary; the finished process and ``summary.json``."""
    run = subprocess.run([sys.executable, "-m", "fiper_ros.cli", "demo", "--view-port", "0", *args, "--out", str(out)],
                         cwd=ROOT, env=os.environ | {"PYTHONUNBUFFERED": "1"}, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["problems"] == []
    return run, summary
