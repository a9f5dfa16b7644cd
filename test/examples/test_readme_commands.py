"""Every command printed in README.md works on this checkout (issue #21): each command of its ```bash blocks (and
each ```python block) has an entry in :data:`COVERAGE`, and ``make test`` runs it.

An entry runs the command as written (:class:`Run`), or one that runs until stopped (:class:`Serve`: started, it
prints what says it is up, what a user does beside it runs, then Ctrl-C; a bound such as ``--port 0`` may be
appended), in a scratch root that looks like the repository (links to env.sh, bin/, the packages, bags/, models/,
the venv and the install space: what the commands write lands in the scratch root), in the test's ROS domain. Or
it names the test of ``make test`` that runs the command (:class:`Elsewhere`, with text of that test that shows
it), or says why ``make test`` does not run it (:class:`Excluded`: long by design). A README command without an
entry fails :func:`test_every_readme_command_has_an_entry`, and so does an entry whose command left the README.
"""
from __future__ import annotations

import os
import re
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Union

import pytest

from fiper_ros.platform.dds import interrupt_group
from helpers.dds import ros_env

ROOT = Path(os.environ["FIPER_ROOT"])
README = ROOT / "README.md"
#: The README block that another test runs as written, with the path of that test.
WALKTHROUGH = re.compile(r"<!-- walkthrough: (\S+) runs the next bash block as written -->")
#: What the scratch root links to in the checkout: all the README's commands touch.
LINKS = ("env.sh", "bin", "fiper_ros", "sim_bridge", "bags", "models", ".venv", "install")
#: Seconds any one command may take (a loaded 2-core machine; evaluate takes ~35 s idle).
TIMEOUT_S = 400.0


@dataclass(frozen=True)
class Run:
    """Run as written (``extra`` appended) in the scratch root of the run ``group`` (empty: beside a :class:`Serve`
    that names it): exit 0, every text of ``expect`` printed and every path of ``files`` written."""

    group: str = ""
    expect: tuple[str, ...] = ()
    files: tuple[str, ...] = ()
    extra: str = ""


@dataclass(frozen=True)
class Serve:
    """A command that runs until stopped (``extra`` appended): once it printed ``ready``, ``feed`` (a shell command
    that must succeed) and the README commands of ``meanwhile`` run beside it, each to its end; then Ctrl-C: exit 0
    and every text of ``expect`` printed. ``group`` as for :class:`Run`."""

    ready: str
    group: str = ""
    expect: tuple[str, ...] = ()
    extra: str = ""
    feed: str = ""
    meanwhile: tuple[str, ...] = ()


@dataclass(frozen=True)
class Elsewhere:
    """Run by another test of ``make test``: the file ``test`` holds ``evidence`` (how it runs the command)."""

    test: str
    evidence: str
    why: str


@dataclass(frozen=True)
class Excluded:
    """Not run by ``make test``, for the reason given (long by design)."""

    why: str


Coverage = Union[Run, Serve, Elsewhere, Excluded]
#: The runs (:data:`RUNS`): the README's own-data commands, its replay and evaluation, the rest.
OWN, EVAL, MORE = "your-own-data", "replay-and-evaluate", "more-commands"

#: What the README's python blocks leave to the reader, by the block's first line: the lines run before the block
#: (a node, shapes of the example policy's model) and after it (until its callback or rollout did something).
PYTHON_PRELUDE = """\
import numpy as np
import rclpy
from fiper_ros.examples.minimal_policy import B, D, E, EXEC, H

rclpy.init()
node = rclpy.create_node("readme_example")
"""
PYTHON_HARNESS = {
    "from fiper_ros.publishing import FiperPublisher": (
        PYTHON_PRELUDE + "h = EXEC\nembedding = np.zeros(E, np.float32)\nchunks = np.zeros((B, H, D), np.float32)\n",
        'print("readme policy: one rollout sent")\n'),
    "from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy": (
        PYTHON_PRELUDE + "alarms = []\non_alarm = alarms.append\n",
        "while not alarms:\n    rclpy.spin_once(node, timeout_sec=0.1)\n"
        'print("readme supervisor: alarm state", alarms[0].state, alarms[0].reason)\n'),
}
PUBLISHER, SUPERVISOR = (f"python: {first}" for first in PYTHON_HARNESS)
#: The verdicts on bags/sorting_sim (bags/README.md's table), live and offline.
SORTING_SIM_VERDICTS = "all                     9        6  1.00 (6/6)            3  0.67 (2/3)"

#: Every README command (outside the walkthrough block, which its own test runs) and python block, in the order the
#: runs take them (a command named in a Serve's ``meanwhile`` runs beside that one).
COVERAGE: dict[str, Coverage] = {
    "make demo": Elsewhere("test/demo/test_demo_e2e.py", "fiper demo: live view ws://127.0.0.1:0",
                           "fiper demo end to end (make demo: the set-up, then it)"),
    "make test": Excluded("the whole suite, of which this test is part"),
    ". ./env.sh": Run(OWN),
    "fiper record -o runs/my_rollouts": Serve(
        "(Ctrl-C to stop)", OWN, expect=("runs/my_rollouts: ",),
        feed="python -m fiper_ros.examples.minimal_policy --rollouts 38 --rate 100 --task my_task "
             "--wait-for /fiper_record"),
    "fiper calibrate runs/my_rollouts -o my_calibration --threshold cp_band --window-obs 5 --window-act 5": Run(
        OWN, expect=("M = 38 successful rollouts fitted it", "guarantee: at most 0.05 of new successful rollouts alarmed"),
        files=("my_calibration/calibration.yaml",)),
    "fiper launch fiper_ros/launch/fiper.launch.yaml calibration_dir:=my_calibration --summary": Serve(
        "fusing rnd_oe, ace (calibration my_calibration)", OWN,
        meanwhile=(PUBLISHER, SUPERVISOR, "bin/fiper echo /fiper/alarm", "bin/fiper view"),
        # the README policy's step was judged (no "1 unknown": the calibration is of its task)
        expect=("my_task/id: 1 steps, first alarm ", "[summary] verdicts on 1 rollouts with a known outcome")),
    PUBLISHER: Run(expect=("readme policy: one rollout sent",)),
    SUPERVISOR: Run(expect=("readme supervisor: alarm state",)),
    "bin/fiper echo /fiper/alarm": Serve("reason: "),
    "bin/fiper view": Serve("serving ws://127.0.0.1:", extra="--port 0"),
    "fiper snapshot --before 10 --after 5": Serve("black box on", OWN,
                                                  expect=("0 snapshot(s) written to runs/snapshots",)),
    "bin/fiper replay bags/pretzel_synthetic --fast": Elsewhere(
        "test/bags/test_replay.py", '"pretzel_synthetic": ["--fast"]', "live replay of every sample set"),
    "bin/fiper replay bags/sorting_sim/test_rollouts --calibration bags/sorting_sim/calibration --offline": Run(
        EVAL, expect=(SORTING_SIM_VERDICTS,)),
    "bin/fiper convert sentinel|fiper SRC -o BAG": Elsewhere(
        "test/bags/test_converters.py", 'convert("fiper"', "a template for the published data sets (and sentinel)"),
    "bin/fiper convert generic LOGS -o BAG": Elsewhere(
        "test/bags/test_convert_generic.py", '"convert", "generic"', "a template for your own logs"),
    "bin/fiper evaluate --data sorting=bags/sorting_sim_calibration_rollouts,bags/sorting_sim/test_rollouts "
    "--out runs/eval": Run(
        EVAL, expect=("fiper evaluate: 1 task(s), 10 method(s), 1 seed(s)",),
        files=tuple(f"runs/eval/{name}" for name in ("results.md", "results.json", "scores_by_category.png",
                                                     "window_impact.png", "delta_impact.png", "example_rollouts.png"))),
    "bin/fiper replay bags/sorting_sim --view": Run(EVAL, expect=("serving ws://127.0.0.1:", SORTING_SIM_VERDICTS),
                                                    extra="--fast --view-port 0 --verbose"),
    "bin/fiper doctor": Run(MORE, expect=("ok    ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST",)),
    "bin/fiper launch sim_bridge/launch/bridge.launch.yaml": Elsewhere(
        "test/nodes/test_shipped_launch.py", '"bridge.launch.yaml"', "the bridge's launch file brought ACTIVE"),
    "bin/fiper launch fiper_ros/launch/demo.launch.yaml": Elsewhere(
        "test/nodes/test_shipped_launch.py", '"demo.launch.yaml"', "the demo's six nodes brought ACTIVE"),
    "bin/fiper launch fiper_ros/launch/fiper.launch.yaml --show-args": Run(
        MORE, expect=("Arguments (pass arguments as '<name>:=<value>'):", "'calibration_dir'")),
    "bin/fiper collect --task sorting --scenarios id camera_moved --episodes 50 --out data/my_set": Elsewhere(
        "test/bags/test_collect.py", '"--scenarios", "id", "camera_moved", "--episodes", "2"',
        "100 sim episodes take minutes: the same with 2 each"),
    "bin/fiper collect ... --ros --calibration models/sorting/calibration": Elsewhere(
        "test/bags/test_collect_ros.py", '"--ros", "--calibration", str(CALIBRATION)',
        "a template (...: as above) of collect through the live suite"),
    "make study": Excluded("the study: about 3 h 40 min by design (docs/results.md)"),
    "make bench-core bench-eval bench-nodes bench-policy": Excluded("benchmarks: minutes, for an idle machine"),
    "make bench-soak MINUTES=10": Excluded("a soak of 10 minutes by design"),
    "bin/fiper security --check fiper_ros/config/sros2_policy.xml": Elsewhere(
        "test/nodes/test_security_policy.py", 'main(["security", "--check", str(POLICY)])',
        "the check of the shipped policy, in-process"),
    "make mutants FILES=core/fusion.py": Excluded("mutation testing: minutes per file (docs/testing.md)"),
}
#: The runs, each in a scratch root of its own: the README commands they execute, in order.
RUNS = {group: [c for c, entry in COVERAGE.items() if isinstance(entry, (Run, Serve)) and entry.group == group]
        for group in (OWN, EVAL, MORE)}


@dataclass(frozen=True)
class Block:
    """A fenced code block of the README: its language, its text and the walkthrough marker before it (if any)."""

    language: str
    text: str
    marker: str | None


def blocks(text: str) -> list[Block]:
    """The README's fenced code blocks, in order."""
    return [Block(m.group(2), m.group(3), m.group(1)) for m in
            re.finditer(r"(<!-- walkthrough: .*? -->\n)?```(\w*)\n(.*?)```", text, re.S)]


def commands(script: str) -> Iterator[str]:
    """The commands of a bash block: continued lines joined, comments and blank lines dropped, spaces collapsed."""
    for line in script.replace("\\\n", " ").splitlines():
        command = " ".join(re.sub(r"(^|\s)#.*$", "", line).split())
        if command:
            yield command


def readme_entries() -> tuple[list[str], list[tuple[str, str]]]:
    """The README's commands and python blocks (as :data:`COVERAGE` keys), and the walkthrough blocks (test, text)."""
    entries: list[str] = []
    walkthroughs: list[tuple[str, str]] = []
    for block in blocks(README.read_text()):
        if block.marker is not None:
            walkthroughs.append((WALKTHROUGH.search(block.marker).group(1), block.text))  # type: ignore[union-attr]
        elif block.language == "bash":
            entries += [c for c in commands(block.text) if c not in entries]
        elif block.language == "python":
            entries.append(f"python: {block.text.splitlines()[0]}")
        else:
            raise AssertionError(f"README block of language {block.language!r}: give it an entry here")
    return entries, walkthroughs


def python_block(key: str) -> str:
    """The README's python block of ``key``, framed by its harness: a script."""
    first = key.removeprefix("python: ")
    (text,) = [b.text for b in blocks(README.read_text()) if b.language == "python" and b.text.startswith(first)]
    before, after = PYTHON_HARNESS[first]
    return before + text + after


def test_every_readme_command_has_an_entry() -> None:
    entries, walkthroughs = readme_entries()
    missing = [c for c in entries if c not in COVERAGE]
    assert not missing, f"README commands that no test runs: give each an entry in COVERAGE: {missing}"
    stale = [c for c in COVERAGE if c not in entries]
    assert not stale, f"COVERAGE entries for commands the README no longer has: {stale}"
    beside = [c for entry in COVERAGE.values() if isinstance(entry, Serve) for c in entry.meanwhile]
    alone = [c for c, entry in COVERAGE.items() if isinstance(entry, (Run, Serve)) and not entry.group]
    assert sorted(beside) == sorted(alone), "a Run or Serve without a group runs beside a Serve that names it, once"
    for command, entry in COVERAGE.items():
        if isinstance(entry, Elsewhere):
            assert entry.evidence in (ROOT / entry.test).read_text(), (command, entry)
    assert [test for test, _ in walkthroughs] == ["test/examples/test_walkthrough.py"]
    assert "runs the next bash block as written" in (ROOT / walkthroughs[0][0]).read_text()


def test_the_parser_reads_what_a_shell_runs() -> None:
    script = ". ./env.sh\n# a comment\nfiper a \\\n    --b 1   # why\n\nmake x   # or: y\n"
    assert list(commands(script)) == [". ./env.sh", "fiper a --b 1", "make x"]
    text = "x\n```bash\nmake a\n```\n<!-- walkthrough: t.py runs the next bash block as written -->\n```bash\nb\n```\n"
    assert blocks(text) == [Block("bash", "make a\n", None),
                            Block("bash", "b\n", "<!-- walkthrough: t.py runs the next bash block as written -->\n")]


class Scratch:
    """A scratch root that looks like the repository, and the README's commands run in it (in ``domain``)."""

    def __init__(self, root: Path, domain: int) -> None:
        self.root = root
        self.env = ros_env(domain)
        for name in LINKS:
            (root / name).symlink_to(ROOT / name)

    def start(self, command: str) -> tuple[subprocess.Popen[str], list[str], threading.Thread]:
        """``command`` (a README command, or ``python: ...``) started in bash after ``. ./env.sh``; its output
        lines, collected as they come by the thread returned."""
        if command.startswith("python: "):
            (self.root / "readme_block.py").write_text(python_block(command))
            command = "python readme_block.py"
        script = command if command == ". ./env.sh" else f". ./env.sh && exec {command}"
        proc = subprocess.Popen(["bash", "-c", script], cwd=self.root, env=self.env,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
        lines: list[str] = []
        reader = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)  # type: ignore[arg-type]
        reader.start()
        return proc, lines, reader

    def run(self, command: str) -> None:
        """Run the README command ``command`` as its :data:`COVERAGE` entry says, asserting what it promises."""
        entry = COVERAGE[command]
        assert isinstance(entry, (Run, Serve)), (command, entry)
        proc, lines, reader = self.start(f"{command} {entry.extra}".strip())
        try:
            if isinstance(entry, Serve):
                self._serve(command, entry, proc, lines)
            status = proc.wait(timeout=TIMEOUT_S)
        finally:
            if proc.poll() is None:  # what a failed assertion left running
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
            reader.join(timeout=30)
        output = "".join(lines)
        assert status == 0, (command, output[-4000:])
        for text in entry.expect:
            assert text in output, (command, text, output[-4000:])
        for name in getattr(entry, "files", ()):
            assert (self.root / name).is_file(), (command, name, output[-2000:])

    def _serve(self, command: str, entry: Serve, proc: subprocess.Popen[str], lines: list[str]) -> None:
        deadline = time.monotonic() + TIMEOUT_S
        while not any(entry.ready in line for line in list(lines)):
            assert proc.poll() is None and time.monotonic() < deadline, (command, "".join(lines)[-4000:])
            time.sleep(0.1)
        if entry.feed:
            fed = subprocess.run(["bash", "-c", f". ./env.sh && {entry.feed}"],
                                 cwd=self.root, env=self.env, capture_output=True, text=True, timeout=TIMEOUT_S)
            assert fed.returncode == 0, (entry.feed, fed.stdout[-3000:], fed.stderr[-3000:])
        for beside in entry.meanwhile:
            self.run(beside)
        assert proc.poll() is None, (command, "".join(lines)[-4000:])  # it was still serving
        interrupt_group(proc.pid)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(RUNS))
def test_the_readme_commands_run(name: str, tmp_path: Path, ros_domain: int) -> None:
    scratch = Scratch(tmp_path, ros_domain)
    for command in RUNS[name]:
        scratch.run(command)
