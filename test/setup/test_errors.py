"""The error model (docs/architecture.md, "Errors"): one root :class:`FiperError`, one error per package that
derives from it and is exported by the package, every custom exception of the tree a user error, and one catch
in ``fiper`` (:func:`fiper_ros.cli.main`): a user error in one line with exit status 2, anything else with its
traceback."""
from __future__ import annotations

import argparse
import ast
import importlib
import inspect
import pkgutil
import warnings
from collections.abc import Callable
from pathlib import Path

import pytest

import fiper_ros
import sim_bridge
from fiper_ros import cli
from fiper_ros.errors import FiperError, FiperWarning

ROOT = Path(__file__).resolve().parents[2]

#: package -> the error of its layer, which its ``__init__`` exports.
LAYER_ERRORS = {"core": "CoreError", "bagio": "BagError", "launcher": "LaunchError", "evaluation": "EvaluationError",
                "nodes": "NodeError", "client": "ClientError", "commands": "UsageError", "policy": "PolicyError",
                "platform": "PlatformError"}
#: Exception classes of the tree that are programming errors, not user errors (none today).
PROGRAMMING_ERRORS: frozenset[str] = frozenset()
#: A custom exception that keeps a builtin base beside FiperError, and why: a caller outside the project relies on it.
SECOND_BASES = {"fiper_ros.publishing.SuiteNotReady": RuntimeError}  # a policy author's code (publishing.py's API)


@pytest.mark.parametrize("package", LAYER_ERRORS)
def test_each_package_exports_the_error_of_its_layer(package: str) -> None:
    module = importlib.import_module(f"fiper_ros.{package}")
    error = getattr(module, LAYER_ERRORS[package])
    assert issubclass(error, FiperError) and error is not FiperError
    assert LAYER_ERRORS[package] in module.__all__


def _exception_classes() -> dict[str, type[BaseException]]:
    """``module.Class`` -> class of every exception class defined in a module of fiper_ros or sim_bridge."""
    found: dict[str, type[BaseException]] = {}
    for package in (fiper_ros, sim_bridge):
        for info in pkgutil.walk_packages(package.__path__, f"{package.__name__}."):
            module = importlib.import_module(info.name)
            for name, value in vars(module).items():
                if (inspect.isclass(value) and issubclass(value, BaseException) and value.__module__ == info.name
                        and not issubclass(value, Warning)):
                    found[f"{info.name}.{name}"] = value
    return found


def test_every_custom_exception_is_a_user_error() -> None:
    """Imported, not read: a class derives from FiperError through its bases, wherever they live."""
    classes = _exception_classes()
    assert len(classes) >= 30  # the walk sees the tree (the modules import)
    assert PROGRAMMING_ERRORS <= set(classes)
    strays = sorted(name for name, cls in classes.items()
                    if name not in PROGRAMMING_ERRORS and not issubclass(cls, FiperError))
    assert strays == []
    builtin = {name: [b for b in cls.__mro__[1:] if b.__module__ == "builtins" and b not in (Exception, BaseException,
                                                                                               object)]
               for name, cls in classes.items()}
    assert {name: bases for name, bases in builtin.items() if bases} == {n: [b] for n, b in SECOND_BASES.items()}


def test_fail_and_warn_live_in_the_errors_module_only() -> None:
    """The one-line printers are ``fiper_ros.errors``' (``fiper`` and the entry points outside it use them): no other
    module defines them (nor prints ``fiper COMMAND: warning``)."""
    sources = [*(ROOT / "fiper_ros" / "fiper_ros").rglob("*.py"), *(ROOT / "sim_bridge" / "sim_bridge").rglob("*.py")]
    defined = sorted(str(path.relative_to(ROOT)) for path in sources for node in ast.walk(ast.parse(path.read_text()))
                     if isinstance(node, ast.FunctionDef) and node.name in ("fail", "warn"))
    assert defined == ["fiper_ros/fiper_ros/errors.py", "fiper_ros/fiper_ros/errors.py"]
    assert sum("warning: " in path.read_text() and "fiper {" in path.read_text() for path in sources) == 1


Run = Callable[[argparse.Namespace], int]


@pytest.fixture()
def command(monkeypatch: pytest.MonkeyPatch) -> Callable[[Run], None]:
    """Install ``fiper boom``, whose ``run`` is the given function."""

    def install(run: Run) -> None:
        monkeypatch.setitem(cli.COMMANDS, "boom", ("test_errors", "a command of the test"))
        monkeypatch.setattr(cli, "_load", lambda name: (lambda parser: None, run, False))

    return install


def test_a_user_error_is_one_line_and_exit_2(command: Callable[[Run], None],
                                              capsys: pytest.CaptureFixture[str]) -> None:
    def run(args: argparse.Namespace) -> int:
        raise FiperError("calibration x:\n  missing   entry 'settings'")

    command(run)
    assert cli.main(["boom"]) == cli.EXIT_USAGE == 2
    assert capsys.readouterr().err == "fiper boom: calibration x: missing entry 'settings'\n"


@pytest.mark.parametrize("bug", [RuntimeError("a bug"), KeyError("a bug"), ValueError("a bug")])
def test_any_other_exception_keeps_its_traceback(bug: Exception, command: Callable[[Run], None]) -> None:
    def run(args: argparse.Namespace) -> int:
        raise bug

    command(run)
    with pytest.raises(type(bug)) as raised:
        cli.main(["boom"])
    assert raised.value is bug


def test_each_warning_is_one_line_and_the_command_goes_on(command: Callable[[Run], None],
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    def run(args: argparse.Namespace) -> int:
        for _ in range(2):
            warnings.warn("bag b:\n reading 3 chunks", FiperWarning, stacklevel=1)
        return 0

    command(run)
    assert cli.main(["boom"]) == 0
    assert capsys.readouterr().err == "fiper boom: warning: bag b: reading 3 chunks\n" * 2


def test_a_bug_while_loading_a_policy_shows_its_traceback(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """``fiper collect`` caught RuntimeError, KeyError, ValueError and OSError around the policy load and reported a
    bug as one line, exit 2; now only the user's errors are reported so."""
    from fiper_ros.commands import collect

    def broken(directory: object) -> None:
        raise RuntimeError("a bug in the policy code")

    monkeypatch.setattr(collect.Policy, "load", broken)
    with pytest.raises(RuntimeError, match="a bug in the policy code"):
        cli.main(["collect", "--task", "sorting", "--episodes", "1", "--out", str(tmp_path)])


def test_a_policy_folder_that_is_not_one_is_a_user_error(tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    """A missing or unreadable policy is the user's: one line naming the folder, exit 2."""
    folder = tmp_path / "model"
    folder.mkdir()
    assert cli.main(["collect", "--task", "sorting", "--episodes", "1", "--model", str(folder),
                     "--out", str(folder / "out")]) == 2
    assert capsys.readouterr().err == (f"fiper collect: policy folder {folder.resolve()} lacks policy.yaml and policy.pt: not a policy "
                   "model folder (train one first, docs/policies.md)\n")
    (folder / "policy.yaml").write_text("config: [")
    (folder / "policy.pt").write_bytes(b"")
    assert cli.main(["collect", "--task", "sorting", "--episodes", "1", "--model", str(folder),
                     "--out", str(folder / "out")]) == 2
    assert capsys.readouterr().err.startswith(f"fiper collect: {folder}: cannot load the policy (")


def test_a_policy_yaml_without_a_configuration_is_a_policy_error(tmp_path: Path) -> None:
    """``PolicyConfig.read`` (``fiper demo``'s check of its model, ``fiper security``'s shipped models) refused with
    a ValueError, which the demo relabelled a BagError; now the policy's own error, naming the file."""
    from fiper_ros.policy import PolicyError
    from fiper_ros.policy.config import PolicyConfig

    path = tmp_path / "policy.yaml"
    for text in ("config: [", "weights: {}", "config: {heads: 3}"):
        path.write_text(text)
        with pytest.raises(PolicyError, match=f"^{path}: not a policy configuration \\("):
            PolicyConfig.read(path)
