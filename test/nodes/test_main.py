"""The process shell of every node (`fiper_ros.platform.process`): shutdown while a callback runs."""
from __future__ import annotations

import signal
import textwrap
import threading
import time

import pytest

import rclpy
from rclpy.context import Context
from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor

from fiper_ros.platform import process
from fiper_ros.platform.process import EXIT_S, spin_until_shutdown, stop_executor
from helpers.dds import spawn_python


def test_spin_until_shutdown_returns_only_after_the_callbacks_in_flight(ros_domain: int) -> None:
    context = Context()
    rclpy.init(context=context, domain_id=ros_domain)
    node = rclpy.create_node("slow_callback", context=context)
    executor = MultiThreadedExecutor(num_threads=2, context=context)
    running, started = threading.Event(), threading.Event()

    def slow() -> None:  # a policy step that takes a while
        running.set()
        started.set()
        time.sleep(0.5)
        running.clear()

    node.create_timer(0.01, slow)
    executor.add_node(node)
    spinner = threading.Thread(target=spin_until_shutdown, args=(executor,))
    spinner.start()
    try:
        assert started.wait(10)
        context.try_shutdown()  # what SIGTERM does in a node process
        spinner.join(10)
        assert not spinner.is_alive()
        assert not running.is_set()  # the node may be destroyed now
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_a_single_threaded_executor_is_not_held_by_a_work_count_a_ctrl_c_left(ros_domain: int,
                                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """A SIGINT whose KeyboardInterrupt lands in rclpy's ``_WorkTracker.__enter__`` after its count went up leaves
    it counting a callback that never runs (simulated here by entering the tracker); with the count waited on, the
    process outlived its SIGINT by the whole drain timeout (once in CI). A single-threaded executor's callbacks
    run in the thread that stops it: stopping it returns at once."""
    monkeypatch.setattr(process, "CALLBACK_DRAIN_S", 300.0)
    context = Context()
    rclpy.init(context=context, domain_id=ros_domain)
    executor = SingleThreadedExecutor(context=context)
    try:
        executor._work_tracker.__enter__()  # the count a Ctrl-C left up
        stopper = threading.Thread(target=stop_executor, args=(executor,), daemon=True)
        stopper.start()
        stopper.join(30)
        assert not stopper.is_alive()
    finally:
        executor._work_tracker.__exit__(None, None, None)
        rclpy.try_shutdown(context=context)


#: A factory body's first lines: a node class that says when it is destroyed.
PROBE = textwrap.dedent("""\
    class Probe(rclpy.node.Node):
        def destroy_node(self):
            print("destroy_node called", flush=True)
            super().destroy_node()
    """)


def _run_node_process(factory_body: str, domain: int, interrupt_after: str | None = None,
                      executor: str = "single", stop: signal.Signals = signal.SIGINT) -> tuple[int, str]:
    """Run ``run_node`` on ``factory()`` (given by its body) in a child process; send ``stop`` once the child
    printed ``interrupt_after``; return its exit status and output."""
    script = ("import faulthandler, sys, rclpy\nfrom fiper_ros.platform.process import run_node\n"
              f"def factory():\n{textwrap.indent(factory_body, '    ')}\n"
              f"sys.exit(run_node(factory, [], executor={executor!r}))\n")
    child = spawn_python(["-c", script], domain)
    lines = []
    if interrupt_after is not None:
        for line in child.stdout:
            lines.append(line)
            if interrupt_after in line:
                child.send_signal(stop)
                break
    out, _ = child.communicate(timeout=60)
    return child.returncode, "".join(lines) + out


#: The end of a child's factory body: its node prints "spinning" every 50 ms; the factory returns it.
SPINNING = 'node.create_timer(0.05, lambda: print("spinning", flush=True))\nreturn node'


def _hang(said: str) -> str:
    """Child code that prints ``said`` and then never returns, whatever signal comes (a hung teardown or exit)."""
    return textwrap.dedent(f"""\
        print({said!r}, flush=True)
        while True:
            try:
                time.sleep(60)
            except KeyboardInterrupt:
                pass""")


def test_a_stopped_node_process_destroys_its_node_and_exits_0(ros_domain: int) -> None:
    # destroying the node deletes its DDS entities and their shared-memory segments (docs/nodes.md)
    body = PROBE + 'node = Probe("probe")\n' + SPINNING
    status, out = _run_node_process("import rclpy.node\n" + body, ros_domain, interrupt_after="spinning")
    assert status == 0, out
    assert "destroy_node called" in out


def test_a_node_process_whose_teardown_hangs_prints_its_stacks_and_exits_1(ros_domain: int) -> None:
    """CI of cb728d1: after the test killed ACE, Ctrl-C left the RND-OE process running until the launcher killed it
    5 s later (the upstream DDS teardown race after a peer died, docs/nodes.md). Past TEARDOWN_S the process now
    says where it hangs and ends itself."""
    body = ("import time, rclpy.node\nclass Hanging(rclpy.node.Node):\n    def destroy_node(self):\n"
            + textwrap.indent(_hang("destroy_node called"), " " * 8) + '\nnode = Hanging("probe")\n' + SPINNING)
    began = time.monotonic()
    status, out = _run_node_process(body, ros_domain, interrupt_after="spinning")
    assert status == 1, out
    assert "destroy_node called" in out and "Timeout (0:00:03)!" in out and "in destroy_node" in out, out
    assert time.monotonic() - began < 60


def test_a_node_process_whose_exit_hangs_after_its_teardown_is_ended_within_exit_s(ros_domain: int) -> None:
    """2026-12-03, a test run of the whole suite: after test_faults' respawn test an RND-OE process had finished its
    teardown and hung in its exit. Among the C++ static destructors, Fast DDS's participant factory busy-waited for a
    discovery callback that waited for a lock the exiting thread held. Orphaned, SIGTERM already ignored, the
    process spun 85% of a core for 30 minutes. An exit that hangs (here in an atexit handler) now ends past
    EXIT_S."""
    body = ("import atexit, time, rclpy.node\ndef hang():\n" + textwrap.indent(_hang("exit hangs"), " " * 4)
            + '\natexit.register(hang)\nnode = rclpy.node.Node("probe")\n' + SPINNING)
    began = time.monotonic()
    status, out = _run_node_process(body, ros_domain, interrupt_after="spinning")
    took = time.monotonic() - began
    assert status == -signal.SIGALRM, out
    assert "exit hangs" in out, out
    assert EXIT_S <= took < 30, took


def test_a_signal_while_the_node_is_built_ends_the_process_quietly(ros_domain: int) -> None:
    # rclpy's SIGINT handler shuts the context down; landing between or inside the constructor's rcl calls,
    # that fails the next one
    for shut_down_before in ("node", "publisher"):
        body = textwrap.dedent(f"""\
            from std_msgs.msg import String
            if "{shut_down_before}" == "node":
                rclpy.get_default_context().shutdown()
            node = rclpy.create_node("late")
            rclpy.get_default_context().try_shutdown()
            node.create_publisher(String, "late", 1)
            return node""")
        status, out = _run_node_process(body, ros_domain)
        assert status == 0, (shut_down_before, out)
        assert "Traceback" not in out, (shut_down_before, out)


def test_a_crashing_node_process_prints_its_python_stack(ros_domain: int) -> None:
    status, out = _run_node_process("faulthandler._sigsegv()", ros_domain)
    assert status == -signal.SIGSEGV
    assert "Fatal Python error: Segmentation fault" in out and "in factory" in out


def test_sigterm_shuts_down_once_and_ignores_the_next(ros_domain: int) -> None:
    """A leaked fusion node's stack (gdb, 2026-12-01): the main thread waited on a lock inside the shutdown and
    a second SIGTERM (the launcher's stop, then the parent-death signal) ran the handler's ``shut_down`` again
    inside that wait, for ever. The handler now shuts down once and ignores further SIGTERMs (the old
    handler, a lambda, stayed installed)."""
    import os

    from fiper_ros.platform import process

    previous = signal.getsignal(signal.SIGTERM)
    rclpy.init(domain_id=ros_domain)
    try:
        signal.signal(signal.SIGTERM, process._on_sigterm)
        os.kill(os.getpid(), signal.SIGTERM)
        deadline = time.monotonic() + 10
        while rclpy.ok() and time.monotonic() < deadline:  # the handler runs between bytecodes of this thread
            time.sleep(0.01)
        assert not rclpy.ok()
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN
        os.kill(os.getpid(), signal.SIGTERM)  # ignored: this process goes on
        time.sleep(0.05)
    finally:
        signal.signal(signal.SIGTERM, previous)
        rclpy.try_shutdown()


def test_a_node_process_on_the_events_executor_keeps_firing_its_timers(ros_domain: int,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue #24: rclpy's EventsExecutor.spin() busy-waits in this wheel and never dispatches a timer after the
    first events (docs/benchmarks.md); run_node spins it in bounded slices, so the timer fires again and again
    and SIGINT ends the process."""
    monkeypatch.delenv("FIPER_EXECUTOR", raising=False)
    body = textwrap.dedent("""\
        faulthandler.dump_traceback_later(30, exit=True)  # a wedged spin ends the child: the test fails, not hangs
        node = rclpy.create_node("ticker")
        ticks = iter(range(1000))
        node.create_timer(0.02, lambda: print(f"tick {next(ticks)}", flush=True))
        return node""")
    status, out = _run_node_process("import rclpy\n" + body, ros_domain, interrupt_after="tick 5", executor="events")
    assert status == 0, out
    assert "tick 5" in out


def test_sigterm_stops_a_node_on_the_events_executor_without_failing_a_callback(
        ros_domain: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """The SIGTERM handler runs at the start of a callback while an EventsExecutor spins; shutting the context
    down there failed that callback (a FATAL "Exception in 'timers' callback: ... context is invalid" at every
    SIGTERM). Now the spin loop ends after the callback, and the node is destroyed and the process exits 0."""
    monkeypatch.delenv("FIPER_EXECUTOR", raising=False)
    body = PROBE + textwrap.dedent("""\
        from std_msgs.msg import String
        node = Probe("talker")
        publisher = node.create_publisher(String, "chatter", 10)
        ticks = iter(range(100000))
        def tick():
            publisher.publish(String(data="tick"))
            print(f"tick {next(ticks)}", flush=True)
        node.create_timer(0.005, tick)
        return node""")
    status, out = _run_node_process("import rclpy.node\n" + body, ros_domain, interrupt_after="tick 20",
                                    executor="events", stop=signal.SIGTERM)
    assert status == 0, out
    assert "Exception in" not in out and "FATAL" not in out, out
    assert "destroy_node called" in out
