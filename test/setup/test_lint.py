"""The linter (ruff, pinned in requirements.lock, configured in ruff.toml): the repository is clean, and the
configuration does flag what it selects (docs/testing.md, "Lint")."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "ruff.toml"


def _ruff(*args: str) -> subprocess.CompletedProcess[str]:
    """``ruff check`` from the venv with the project's configuration."""
    return subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "--config", str(CONFIG), *args],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)


def test_the_repository_is_lint_clean() -> None:
    result = _ruff(".")
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.parametrize(("source", "rule"), [
    ("import os\n", "F401"),  # an unused import
    ("def f() -> None:\n    x = 1\n", "F841"),  # an unused variable
    ("def f() -> int:\n    return y\n", "F821"),  # an undefined name
    ("import os  # noqa: E402\n\nprint(os.sep)\n", "RUF100"),  # a stale marker
])
def test_a_file_breaking_a_selected_rule_fails(tmp_path: Path, source: str, rule: str) -> None:
    path = tmp_path / "bad.py"
    path.write_text(source)
    result = _ruff(str(path))
    assert result.returncode == 1 and f"{rule} " in result.stdout, result.stdout + result.stderr


def test_the_same_file_without_the_fault_passes(tmp_path: Path) -> None:
    path = tmp_path / "good.py"
    path.write_text("import os\n\nprint(os.sep)\n")
    result = _ruff(str(path))
    assert result.returncode == 0, result.stdout + result.stderr
