"""``fiper calibrate``: fits on the successful rollouts of bags, writes the directory, refuses clearly, warns of a
window longer than every calibration rollout and closes with a summary of what it fitted."""
from __future__ import annotations

from pathlib import Path

import pytest

from fiper_ros.bagio.rollout_bags import read_rollouts
from fiper_ros.cli import main
from fiper_ros.commands.calibrate import RND_PRESETS
from fiper_ros.core.calibration import CalibrationSettings, calibrate, load_calibration
from fiper_ros.core.rnd_oe import RNDConfig

# Three successes cannot be split (a conformal quantile at delta 0.3 needs 3 alone): these tests check the
# command's mechanics on the paper's same-data calibration, asked for explicitly.
SETTINGS = ["--window-obs", "3", "--window-act", "3", "--threshold", "cp_constant", "--delta", "0.3",
            "--max-epochs", "4", "--seed", "3", "--same-data"]


def test_calibrate_uses_the_successes_and_prints_what_it_used(
        tmp_path: Path, small_bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "calibration"
    assert main(["calibrate", str(small_bag), "-o", str(out), "--min-rollouts", "3", *SETTINGS]) == 0
    printed = capsys.readouterr()
    calibration = load_calibration(out)
    assert calibration.num_rollouts == 3  # the failed rollout is not used
    assert "calibrating on 3 successful rollouts (60 steps) of 4" in printed.out
    assert f"hash {calibration.content_hash}" in printed.out
    assert "RND-OE epoch 4/4" in printed.err  # progress of the training
    rnd = RNDConfig.from_dict(RND_PRESETS["small"]().to_dict() | {"max_epochs": 4})
    settings = CalibrationSettings(window=3, threshold="cp_constant", delta=0.3, rnd=rnd, seed=3,
                                   min_rollouts=3, split="same")
    assert calibrate(read_rollouts(small_bag), settings).content_hash == calibration.content_hash


def test_a_window_longer_than_every_rollout_is_warned_and_the_summary_closes_the_output(
        tmp_path: Path, small_bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "calibration"
    assert main(["calibrate", str(small_bag), "-o", str(out), "--min-rollouts", "3", *SETTINGS,
                 "--window-act", "21"]) == 0
    printed = capsys.readouterr()
    warning = ("warning: the window of ACE (21) is longer than every calibration rollout (the longest has 20 steps): "
               "its windowed score sums the whole rollout so far at every step, as any window of 20 or more would; a "
               "shorter window reacts sooner")
    assert printed.err.count(warning) == 1 and f"fiper calibrate: {warning}" in printed.err  # before the training
    closing = printed.out[printed.out.index(f"calibration {out} written"):].splitlines()
    hash_ = load_calibration(out).content_hash
    assert closing[:3] == [f"calibration {out} written (hash {hash_}):",
                           "  M = 3 successful rollouts fitted it (60 steps, 20 to 20 per rollout)",
                           "  judged by RND-OE and ACE"]
    assert closing[3:5] == ["  windows: RND-OE 3 (window), ACE 21 (window) policy steps",
                            "  split: same: 3 successes fitted the models, 3 the thresholds"]
    assert [line.split(",")[0].split(":")[0] for line in closing[5:]] == [
        "  threshold RND-OE", "  threshold ACE", "  false alarms on held-out successes", "  guarantee",
        "  warning", "  warning"]  # the second: same-data calibration, not covered by Proposition 1
    assert closing[-1] == f"  {warning}"
    assert main(["calibrate", str(small_bag), "-o", str(tmp_path / "fits"), "--min-rollouts", "3", *SETTINGS,
                 "--window-act", "20"]) == 0
    assert "warning" not in capsys.readouterr().err  # a window of the longest rollout's length: no word


def test_calibrate_refuses_too_few_successes(tmp_path: Path, small_bag: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "calibration"
    assert main(["calibrate", str(small_bag), "-o", str(out), *SETTINGS]) == 2  # default --min-rollouts 4
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert err.startswith("fiper calibrate: too few successful rollouts to calibrate: 3 of 4 in")
    assert "need at least 4" in err
    assert not out.exists() and not list(tmp_path.iterdir())


def test_calibrate_refuses_an_existing_directory(tmp_path: Path, small_bag: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "calibration").mkdir()
    assert main(["calibrate", str(small_bag), "-o", str(tmp_path / "calibration"), "--min-rollouts", "3",
                 *SETTINGS]) == 2
    assert "exists already" in capsys.readouterr().err


@pytest.mark.parametrize("option, message", [
    (["--delta", "0"], "delta must be in (0, 1), got 0.0"),
    (["--delta", "1.5"], "delta must be in (0, 1), got 1.5"),
    (["--alpha", "0"], "cell size factor alpha must be in (0, 1), got 0.0"),
    (["--alpha", "-1"], "cell size factor alpha must be in (0, 1), got -1.0"),
    (["--seed", "-1"], "seed must be >= 0, got -1"),
    (["--max-epochs", "-3"], "RND-OE needs at least one training epoch, got max_epochs -3"),
])
def test_bad_settings_are_one_line_before_training(small_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                   option: list[str], message: str) -> None:
    """Before: a traceback after RND-OE's training (delta, alpha), from numpy (seed), or, for --max-epochs -3,
    a calibration written with an untrained RND-OE."""
    assert main(["calibrate", str(small_bag), "-o", str(tmp_path / "cal"), "--min-rollouts", "2", *option]) == 2
    assert capsys.readouterr().err == f"fiper calibrate: {message}\n"
    assert not (tmp_path / "cal").exists()
