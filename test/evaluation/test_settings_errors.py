"""Evaluation settings refuse a bad value where it is found, as a :class:`SettingsError` (an
:class:`EvaluationError`), so ``fiper evaluate`` reports it in one line without converting anything on its way out
(docs/architecture.md, "Errors")."""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from fiper_ros.cli import main
from fiper_ros.evaluation import EvaluationError
from fiper_ros.evaluation.engine import EngineSettings
from fiper_ros.evaluation.errors import SettingsError
from fiper_ros.evaluation.methods import (Combination, MethodSettings, method_of, parse_combination, signal_methods,
                                          streams_of)
from fiper_ros.evaluation.sweep import SweepSettings


@pytest.mark.parametrize("make, message", [
    (lambda: EngineSettings(q_auc=2.0), "--q-auc must be in (0, 1], got 2"),
    (lambda: EngineSettings(seeds=()), "at least one seed is needed"),
    (lambda: EngineSettings(protocols=("best",)), "protocols must be among"),
    (lambda: SweepSettings(windows=(0, 1)), "windows must be integers >= 1, got (0, 1)"),
    (lambda: SweepSettings(pairs="fine-ish"), "pairs must be one of"),
    (lambda: SweepSettings(or_promise="twice"), "or_promise must be one of entry, delta, got 'twice'"),
    (lambda: EngineSettings(sweep=SweepSettings(or_promise="delta"), promise="entry"),
     "--or-promise delta sweeps every OR at delta / N"),
    (lambda: MethodSettings(split="halves"), "unknown split 'halves'"),
    (lambda: MethodSettings(profile="novel"), "unknown profile 'novel'"),
    (lambda: method_of("nope"), "unknown method 'nope'"),
    (lambda: streams_of(["rnd_oe", "external_Bad"]), "unknown detector 'external_Bad'"),
    (lambda: Combination("pair", ("rnd_oe", "rnd_oe")), "combination 'pair': distinct detectors needed"),
    (lambda: Combination("pair", ("rnd_oe", "sonar")), "unknown detector 'sonar'"),
    (lambda: parse_combination("pair"), "combination 'pair': expected NAME=DETECTOR+DETECTOR+..."),
    (lambda: parse_combination("fiper=rnd_oe+ace"), "combination 'fiper=rnd_oe+ace': 'fiper' is the name of a built-in"),
    (lambda: signal_methods(("speed", "Bad-Name")), "signal name 'Bad-Name' must match"),
])
def test_a_bad_setting_is_a_settings_error_at_its_source(make: Callable[[], object], message: str) -> None:
    """Before: a ValueError, which ``fiper evaluate`` turned into a UsageError on its way out (a bug in the
    evaluation raising ValueError was then reported as the user's)."""
    with pytest.raises(SettingsError) as refused:
        make()
    assert str(refused.value).startswith(message)
    assert isinstance(refused.value, EvaluationError) and not isinstance(refused.value, ValueError)


@pytest.mark.parametrize("argv, message", [
    (["--signals", "Bad-Name"], "signal name 'Bad-Name' must match [a-z][a-z0-9_]*"),
    (["--combo", "pair=rnd_oe+sonar"], "unknown detector 'sonar'"),
    (["--q-auc", "0"], "--q-auc must be in (0, 1], got 0"),
    (["--or-promise", "delta", "--auto-promise", "entry"], "--or-promise delta sweeps every OR at delta / N"),
])
def test_a_bad_evaluate_flag_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str],
                                         message: str) -> None:
    assert main(["evaluate", "--synthetic", "sorting", "--synthetic-test", "6", "--synthetic-scale", "0.2",
                 "--out", str(tmp_path / "out"), "--no-cache", "--no-plots", "--quiet", *argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"fiper evaluate: {message}") and err.count("\n") == 1, err
    assert not (tmp_path / "out").exists()
