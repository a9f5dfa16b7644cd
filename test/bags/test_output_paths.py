"""An output path below a file is one line naming it, before any work (before: a FileExistsError traceback
from ``mkdir``, for ``fiper evaluate`` only after the whole run)."""
from __future__ import annotations

from pathlib import Path

import pytest

from fiper_ros.cli import main


@pytest.fixture
def a_file(tmp_path: Path) -> Path:
    path = tmp_path / "notes.txt"
    path.write_text("not a directory\n")
    return path


def _one_line(capsys: pytest.CaptureFixture[str], command: str, out: Path, blocker: Path) -> None:
    assert capsys.readouterr().err == f"fiper {command}: {out}: {blocker} is not a directory\n"


def test_calibrate_output_below_a_file(small_bag: Path, a_file: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = a_file / "calibration"
    assert main(["calibrate", str(small_bag), "-o", str(out)]) == 2
    _one_line(capsys, "calibrate", out, a_file)


def test_convert_output_below_a_file(tmp_path: Path, a_file: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Refused before the source is read: the source here is no .npz file at all."""
    (tmp_path / "run.npz").write_bytes(b"not a zip")
    out = a_file / "deeper" / "bags"
    assert main(["convert", "generic", str(tmp_path / "run.npz"), "-o", str(out)]) == 2
    _one_line(capsys, "convert", out, a_file)


def test_evaluate_output_below_a_file(a_file: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = a_file / "results"
    assert main(["evaluate", "--synthetic", "sorting", "--out", str(out), "--no-cache"]) == 2
    _one_line(capsys, "evaluate", out, a_file)
