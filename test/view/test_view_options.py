"""How the commands that start a suite add the live view (issue #22): ``--view`` / ``--no-view`` and ``--view-port``
become the launch arguments of ``fiper.launch.yaml`` (``view``, ``view_port``), a taken port is named in one line
before anything starts, and the address and the layout are printed."""
from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from helpers.dds import ros_env

from fiper_ros.cli import main
from fiper_ros.client.suite_process import installed_launch, replay_config
from fiper_ros.commands import options
from fiper_ros.commands.errors import UsageError
from fiper_ros.commands.view import ros_arguments
from fiper_ros.core.detectors import DETECTORS
from fiper_ros.launcher.config import load_launch

ROOT = Path(os.environ["FIPER_ROOT"])
FIPER = ROOT / "fiper_ros" / "launch" / "fiper.launch.yaml"


@pytest.fixture
def taken_port() -> Iterator[int]:
    """A port another server listens on, on 127.0.0.1."""
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        yield holder.getsockname()[1]


def parsed(argv: list[str], on_by_default: bool = False) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    options.add_view_arguments(parser, on_by_default)
    return parser.parse_args(argv)


def test_the_view_options_become_launch_arguments_and_a_taken_port_a_one_line_error(taken_port: int) -> None:
    assert options.view_arguments(parsed([])) == {}
    assert options.view_arguments(parsed(["--view", "--view-port", "0"])) == {"view": "true", "view_port": "0"}
    on = parsed([], on_by_default=True)  # fiper demo: on unless --no-view, on Foxglove's default port
    assert (on.view, on.view_port) == (True, 8765)
    assert options.view_arguments(parsed(["--no-view"], on_by_default=True)) == {}
    with pytest.raises(UsageError) as taken:
        options.view_arguments(parsed(["--view", "--view-port", str(taken_port)]))
    assert str(taken.value) == f"live view: port {taken_port} on 127.0.0.1 is taken (another live view, or a " \
                               "Foxglove bridge?): give another --view-port"
    with pytest.raises(UsageError, match="--view-port must be in 0..65535, got 70000"):
        options.view_arguments(parsed(["--view", "--view-port", "70000"]))


def test_the_banner_names_the_address_and_the_installed_layout() -> None:
    banner = options.view_banner(8765)
    assert banner.startswith("live view ws://127.0.0.1:8765 (in Foxglove: Open connection > Foxglove WebSocket); "
                             "layout ")
    assert Path(banner.rsplit("layout ", 1)[1]).is_file()
    assert "any free port: view_node logs it" in options.view_banner(0)


def test_the_suite_launch_file_adds_the_view_node_only_when_asked(tmp_path: Path) -> None:
    assert "view_node" not in [spec.name for spec in load_launch(FIPER).nodes]
    nodes = {spec.name: spec for spec in load_launch(FIPER, {"view": "true", "view_port": "0"}).nodes}
    view = nodes["view_node"]
    assert (view.namespace, view.module, view.required, view.respawn) == ("/fiper", "fiper_ros.nodes.view_node",
                                                                         False, False)
    assert (view.parameters["host"], view.parameters["port"]) == ("127.0.0.1", 0)
    config = replay_config(installed_launch(), tmp_path, DETECTORS, tmp_path / "suite.yaml", None,
                           {"view": "true", "view_port": "0"})
    assert "view_node" in [spec.name for spec in load_launch(config).nodes]


def test_commands_refuse_a_view_they_cannot_serve_in_one_line(taken_port: int,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["launch", str(FIPER), "--view", "--view-port", str(taken_port)]) == 2
    assert capsys.readouterr().err == f"fiper launch: live view: port {taken_port} on 127.0.0.1 is taken (another " \
                                      "live view, or a Foxglove bridge?): give another --view-port\n"
    policy = ROOT / "fiper_ros" / "launch" / "policy.launch.yaml"
    assert main(["launch", str(policy), "--view", "--view-port", "0"]) == 2
    assert "unknown launch arguments view, view_port" in capsys.readouterr().err
    assert main(["replay", str(ROOT / "bags" / "pushchair_synthetic"), "--offline", "--view"]) == 2
    assert capsys.readouterr().err == "fiper replay: --view goes with the suite replay launches: beside a running " \
                                      "suite, run fiper view\n"


def test_the_view_serves_the_detectors_asked_and_names_one_no_suite_scores_in_one_line(ros_domain: int) -> None:
    argv = ros_arguments(argparse.Namespace(namespace="/fiper", host="127.0.0.1", port=0, backlog=8,
                                            detectors="rnd_oe,signal_x"))
    assert argv[-2:] == ["-p", "detectors:=[rnd_oe,signal_x]"]
    run = subprocess.run([sys.executable, "-m", "fiper_ros.cli", "view", "--port", "0", "--detectors", "rnd_oe,bogus"],
                         env=ros_env(ros_domain), capture_output=True, text=True, timeout=120)
    assert run.returncode == 2, run.stderr
    assert run.stderr.strip().splitlines()[-1] == (
        "fiper view: parameter detectors: 'bogus' is not a detector a suite scores (rnd_oe, ace, logpzo, pca_kmeans, "
        "progress, consistency, elapsed or signal_<name>)")
