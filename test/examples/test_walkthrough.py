"""The README's walkthrough "Your policy, from the first line to TPR / TNR" (issue #25's acceptance) runs as written:
the bash block after its marker, verbatim, in a scratch root that looks like the repository (links to its env.sh,
bin/, fiper_ros/, venv and install: the outputs land in the scratch root's runs/, not the checkout's), in the
test's own ROS domain. Every command succeeds; calibrate closes with its summary; the live suite's verdicts
(``fiper launch --summary``) are those of the offline replay of the recording, table and all."""
from __future__ import annotations

import os
import re
import signal
import subprocess
import threading
from pathlib import Path

import pytest
from helpers.dds import ros_env

ROOT = Path(os.environ["FIPER_ROOT"])
MARKER = "<!-- walkthrough: test/examples/test_walkthrough.py runs the next bash block as written -->"
#: What the scratch root links to in the checkout: all the block touches.
LINKS = ("env.sh", "bin", "fiper_ros", ".venv", "install")
TIMEOUT_S = 600


def walkthrough() -> str:
    """The bash block after the README's marker."""
    text = (ROOT / "README.md").read_text()
    block = re.search(r"```bash\n(.*?)```", text[text.index(MARKER):], re.S)
    assert block is not None, "no bash block after the walkthrough marker"
    return block.group(1)


@pytest.mark.slow
def test_the_readme_walkthrough_runs_as_written(tmp_path: Path, ros_domain: int) -> None:
    for name in LINKS:
        (tmp_path / name).symlink_to(ROOT / name)
    script = walkthrough()
    assert script.startswith(". ./env.sh\n") and "fiper launch" in script and "--summary" in script
    proc = subprocess.Popen(["bash", "-e", "-c", script], cwd=tmp_path, env=ros_env(ros_domain),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)  # type: ignore[arg-type]
    reader.start()
    try:
        proc.wait(timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        raise AssertionError(f"the walkthrough did not finish in {TIMEOUT_S} s:\n{''.join(lines)[-6000:]}") from None
    finally:  # what a failed step left running in the background (bash -e stopped at it)
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        reader.join(timeout=30)
    output = "".join(lines)
    assert proc.returncode == 0, output[-6000:]
    assert "M = 20 successful rollouts fitted it (400 steps, 20 to 20 per rollout)" in output, output[-6000:]
    assert "guarantee: at most 0.1 of new successful rollouts alarmed" in output
    # the policy's own lines share the pipe (another process): a rollout's line is found wherever it starts
    rollouts = re.findall(r"\[summary\] (rollout \d+ .*?: (?:detected|missed|no false alarm|false alarm) \(\w+ \w+\))",
                          output)
    live = [line.removeprefix("[summary] ") for line in output.splitlines() if line.startswith("[summary] ")]
    table = live[next(i for i, line in enumerate(live) if line.startswith("verdicts on ")):]
    offline = output[output.index("10 rollouts, 200 steps in"):].splitlines()[1:]
    assert table == offline, (table, offline)  # the live suite judged as the oracle does, from the recording
    assert table[0].startswith("verdicts on 10 rollouts with a known outcome")
    (everything,) = [line for line in table if line.startswith("all ")]
    assert everything.split()[1:3] == ["10", "5"]  # rollouts, failures
    assert len(rollouts) == 10 and all("20 steps" in line for line in rollouts), \
        (rollouts, [line for line in output.splitlines() if "[summary]" in line])
    assert sorted(line for line in output.splitlines() if re.match(r"rollout \d+ example/", line)) == sorted(rollouts)
    assert (tmp_path / "runs" / "first_hour" / "calibration" / "calibration.yaml").is_file()  # in the scratch root
