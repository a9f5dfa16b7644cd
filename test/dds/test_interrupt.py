"""A fiper command takes SIGINT as its stop request also when it inherited SIGINT ignored (a background job of a
shell without job control, a test run in the background): the project's tools stop what they start with SIGINT.
Seen: every refused live replay and demo of a test run started in the background took 20 s instead of 1 s, its
launcher missing the Ctrl-C sent before it had installed its handler and being killed after the timeout."""
from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from fiper_ros.client.suite_process import SuiteProcess, installed_launch
from fiper_ros.platform.dds import ignores_sigint, interrupt_group, interruptible

SORTING_CALIBRATION = Path(__file__).resolve().parents[2] / "models" / "sorting" / "calibration"

#: Run in a child started with SIGINT ignored: the disposition after ``fiper --version``.
AFTER_THE_CLI = """
import signal
from fiper_ros.cli import main
try:
    main(["--version"])
except SystemExit:
    pass
print(signal.getsignal(signal.SIGINT) is signal.default_int_handler)
"""


#: A child that takes SIGINT only after 0.3 s (as a process takes a while to restore an inherited ignored SIGINT).
LATE_HANDLER = """
import signal, time
time.sleep(0.3)
signal.signal(signal.SIGINT, signal.default_int_handler)
time.sleep(30)
"""


def _ignoring_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def test_the_cli_restores_an_inherited_ignored_sigint_first() -> None:
    """Fails on the cli before ``interruptible``: the child's SIGINT stayed ignored."""
    done = subprocess.run([sys.executable, "-c", AFTER_THE_CLI], preexec_fn=_ignoring_sigint,
                          capture_output=True, text=True, check=True, timeout=60)
    assert done.stdout.splitlines()[-1] == "True", done.stdout


def test_interruptible_restores_only_an_ignored_sigint_and_only_in_the_main_thread() -> None:
    before = signal.getsignal(signal.SIGINT)
    try:
        handler = lambda *_: None  # noqa: E731 - a handler of the process's own stays
        signal.signal(signal.SIGINT, handler)
        interruptible()
        assert signal.getsignal(signal.SIGINT) is handler
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        thread = threading.Thread(target=interruptible)  # signal.signal would raise there: nothing is done
        thread.start()
        thread.join()
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
        interruptible()
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGINT, before)


def test_interrupt_group_waits_until_the_process_takes_sigint() -> None:
    """Fails on a plain killpg: the SIGINT sent while the child still ignores it is lost, and it sleeps 30 s."""
    child = subprocess.Popen([sys.executable, "-c", LATE_HANDLER], preexec_fn=_ignoring_sigint,  # noqa: PLW1509
                             start_new_session=True, stderr=subprocess.PIPE, text=True)
    try:
        assert ignores_sigint(child.pid)
        began = time.monotonic()
        interrupt_group(child.pid)
        _, err = child.communicate(timeout=10)
        assert child.returncode != 0 and "KeyboardInterrupt" in err, err
        assert time.monotonic() - began < 5
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()


def test_a_process_that_is_gone_or_a_zombie_ignores_nothing() -> None:
    child = subprocess.Popen([sys.executable, "-c", "pass"], preexec_fn=_ignoring_sigint)  # noqa: PLW1509
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and not Path(f"/proc/{child.pid}/status").read_text().count("State:\tZ"):
        time.sleep(0.01)  # exited, not reaped yet: a zombie
    assert not ignores_sigint(child.pid)
    child.wait()
    assert not ignores_sigint(child.pid)


def test_a_suite_started_by_a_process_that_ignores_sigint_stops_at_once(ros_domain: int) -> None:
    """The symptom: a refused replay stops the suite it has just started. Fails on the old code: the launcher missed
    the Ctrl-C and was killed after SuiteProcess.stop's 20 s."""
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)  # the launcher inherits an ignored SIGINT
    try:
        suite = SuiteProcess(installed_launch(), ros_domain, echo=False,
                             arguments={"calibration_dir": str(SORTING_CALIBRATION)})
    finally:
        signal.signal(signal.SIGINT, before)
    began = time.monotonic()
    suite.stop()
    took = time.monotonic() - began
    assert took < 10, (took, suite.output())
