"""The options ``fiper calibrate`` and ``fiper evaluate`` share (:mod:`fiper_ros.commands.options`): one parser of
integer lists, one set of ``--auto-*`` options and one builder of their :class:`AutoSettings`, and the action
channel option, a flag refused as a :class:`UsageError` naming the flag."""
from __future__ import annotations

import argparse
from pathlib import Path

import pytest
from hypothesis import given, strategies as st

from fiper_ros.cli import main
from fiper_ros.commands import calibrate, evaluate, options
from fiper_ros.commands.errors import UsageError
from fiper_ros.core.auto import AutoError, AutoSettings


@pytest.mark.parametrize("text, expected", [
    ("1-3,5", (1, 2, 3, 5)), ("5,1,3,3", (1, 3, 5)), ("0-4", (0, 1, 2, 3, 4)), ("7", (7,)), ("-1", (-1,)),
    ("-3-1", (-3, -2, -1, 0, 1)), (" 2 , 1-2 ,", (1, 2)), ("4-4", (4,)),
])
def test_int_list_by_hand(text: str, expected: tuple[int, ...]) -> None:
    assert options.int_list(text) == expected


@pytest.mark.parametrize("text, message", [
    ("", "no integers in ''"), (",", "no integers in ','"), ("3-1", "range '3-1': expected LOW-HIGH with LOW <= HIGH"),
    (f"1-{options.MAX_INTS + 1}", f"at most {options.MAX_INTS} integers"),
    (f"0-{options.MAX_INTS - 1},{options.MAX_INTS}", f"names more than {options.MAX_INTS} integers"),
])
def test_int_list_refuses_in_one_line(text: str, message: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match=message.replace("(", r"\(")):
        options.int_list(text)


@given(st.lists(st.integers(0, 10_000), min_size=1, max_size=20))
def test_int_list_of_a_comma_list_is_sorted_and_distinct(values: list[int]) -> None:
    assert options.int_list(",".join(map(str, values))) == tuple(sorted(set(values)))


@given(st.integers(-50, 50), st.integers(0, 50))
def test_int_list_of_a_range_is_the_range(low: int, size: int) -> None:
    assert options.int_list(f"{low}-{low + size}") == tuple(range(low, low + size + 1))


def _parsed(command: str, *argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    {"calibrate": calibrate, "evaluate": evaluate}[command].add_arguments(parser)
    required = {"calibrate": ["-o", "cal"], "evaluate": ["--out", "out"]}[command]
    return parser.parse_args([*required, *argv])


@pytest.mark.parametrize("command", ["calibrate", "evaluate"])
def test_both_commands_read_auto_windows_alike(command: str) -> None:
    """``fiper calibrate --auto-windows`` refused a range and kept the order and repeats it was given; now both
    commands give AutoSettings the sorted distinct windows of either form."""
    args = _parsed(command, "--auto", "--auto-windows", "10,1-3,3", "--auto-budget", "50", "--step-limit", "80")
    assert args.auto_windows == (1, 2, 3, 10)
    assert options.auto_from(args) == AutoSettings(windows=(1, 2, 3, 10), budget=50, step_limit=80)


def test_only_calibrate_sets_the_folds_and_no_auto_is_none() -> None:
    assert options.auto_from(_parsed("calibrate", "--auto", "--auto-folds", "3")) == AutoSettings(folds=3)
    with pytest.raises(SystemExit):
        _parsed("evaluate", "--auto", "--auto-folds", "3")
    assert options.auto_from(_parsed("calibrate", "--auto-windows", "1-3")) is None
    assert options.auto_from(_parsed("evaluate")) is None
    assert _parsed("evaluate").auto_windows == _parsed("calibrate").auto_windows == AutoSettings().windows


def test_a_bad_auto_setting_is_the_settings_own_error() -> None:
    """Refused by AutoSettings (an AutoError, a CoreError), not relabelled on its way out of the command."""
    with pytest.raises(AutoError, match=r"^auto budget must be >= 1, got 0$"):
        options.auto_from(_parsed("calibrate", "--auto", "--auto-budget", "0"))


def test_a_bad_auto_setting_is_one_line_before_any_bag_is_read(tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--auto", "--step-limit", "1", "-o", str(tmp_path / "cal")]
    assert main(["calibrate", str(tmp_path / "no-bag"), *argv]) == 2
    assert capsys.readouterr().err == "fiper calibrate: step limit must be >= 2, got 1\n"


@pytest.mark.parametrize("text, expected", [("0:3", (0, 3)), ("2:7", (2, 7)), ("all", "all"), ("auto", "auto")])
def test_channels_by_hand(text: str, expected: tuple[int, int] | str) -> None:
    assert options.parse_channels(text) == expected


@pytest.mark.parametrize("text, message", [
    ("3", "--action-dims must be START:STOP, 'all' or 'auto', got '3'"),
    ("a:b", "--action-dims must be START:STOP, 'all' or 'auto', got 'a:b'"),
    ("3:3", "--action-dims 3:3: need 0 <= START < STOP"),
    ("-1:2", "--action-dims -1:2: need 0 <= START < STOP"),
])
def test_a_bad_channel_option_is_a_usage_error_naming_its_flag(text: str, message: str) -> None:
    """Before: a BagError (the converters' input files), and ``--channels`` for calibrate's ``--action-dims`` too."""
    with pytest.raises(UsageError) as refused:
        options.parse_channels(text, "--action-dims")
    assert str(refused.value) == message


def test_calibrate_refuses_bad_action_dims_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for dims, message in (("3", "--action-dims must be START:STOP, 'all' or 'auto', got '3'"),
                          ("all", "--action-dims must be START:STOP, got 'all'")):
        assert main(["calibrate", str(tmp_path / "no-bag"), "-o", str(tmp_path / "cal"), "--action-dims", dims]) == 2
        assert capsys.readouterr().err == f"fiper calibrate: {message}\n"


@pytest.mark.parametrize(("parse", "value", "message"), [
    (calibrate._combine, "kth:0", "combine 'kth:0': kth:K needs an integer K >= 1 (e.g. kth:2)"),
    (evaluate.combine_list, "max,xor", "unknown combine 'xor'; expected one of and, or, max, kth:K"),
])
def test_a_combine_option_refuses_as_argparse_expects(parse: object, value: str, message: str) -> None:
    """argparse prints a usage error only for a ValueError, TypeError or ArgumentTypeError of a ``type=``: the core's
    ChoiceError (no ValueError) goes to argparse in its own words."""
    with pytest.raises(argparse.ArgumentTypeError) as raised:
        parse(value)  # type: ignore[operator]
    assert str(raised.value) == message


def test_fiper_calibrate_with_a_bad_combine_prints_its_usage(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as raised:
        main(["calibrate", "--combine", "max:2", "bag"])
    assert raised.value.code == 2
    assert capsys.readouterr().err.endswith(
        "fiper calibrate: error: argument --combine: combine 'max:2': only kth takes a count (kth:K)\n")
