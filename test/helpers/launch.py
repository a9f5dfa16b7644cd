"""``fiper launch`` in a subprocess for the process-level tests: its output collected line by line; a launched
suite with the test's driver beside it (:class:`Rig`)."""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import rclpy
import yaml
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from std_srvs.srv import Trigger

from fiper_msgs.msg import FailureAlarm
from fiper_ros.core.rollout import Rollout
from fiper_ros.interface.topics import score_topic
from fiper_ros.nodes.graph_watch import NOT_NAMED, PUBLISHERS_KEY
from fiper_ros.platform.dds import PARENT_PID_ENV, interrupt_group
from fiper_ros.platform.process import TEARDOWN_S
from fiper_ros.runtime.wiring import MATCHED_PUBLISHERS
from helpers.dds import ros_env
from helpers.spin import spin_until
from helpers.suite import STEP_NS, PolicySideNode

POLICY_PERIOD_S = STEP_NS / 1e9
#: The score topics the fusion node reads, fully qualified.
SCORE_TOPICS = tuple(score_topic(detector) for detector in ("rnd_oe", "ace"))


class Launch:
    """``fiper launch CONFIG name:=value ...`` in its own process group and ROS domain (in ``cwd``, with ``env`` set
    beside the test's ROS environment)."""

    def __init__(self, config: Path, domain: int, arguments: dict[str, str] | None = None,
                 cwd: Path | None = None, env: dict[str, str] | None = None) -> None:
        named = [f"{name}:={value}" for name, value in (arguments or {}).items()]
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "fiper_ros.cli", "launch", str(config), *named, "--grace", "5"],
            cwd=cwd, env=ros_env(domain) | {PARENT_PID_ENV: str(os.getpid())} | (env or {}), stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True, start_new_session=True)
        self.lines: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip())

    def pids_of(self, name: str) -> list[int]:
        """Every pid the launcher started ``name`` with (respawns add one each), in order."""
        pattern = re.compile(rf"\[launch\] started {name} \(pid (\d+)\)")
        return [int(m.group(1)) for line in list(self.lines) if (m := pattern.match(line))]

    def pid_of(self, name: str) -> int:
        """The pid of the latest start of ``name``."""
        pids = self.pids_of(name)
        if not pids:
            raise AssertionError(f"{name} not started:\n" + "\n".join(self.lines))
        return pids[-1]

    def wait_for(self, condition: Callable[[], bool], timeout: float = 120.0) -> bool:
        """Poll until ``condition()`` or ``timeout`` seconds (or until the launch exited); whether it held."""
        deadline = time.monotonic() + timeout
        while not condition():
            if time.monotonic() > deadline or self.proc.poll() is not None:
                return condition()
            time.sleep(0.05)
        return True

    def interrupt(self) -> int:
        """Ctrl-C the launch (unless it has exited already); its exit status."""
        if self.proc.poll() is not None:
            return self.proc.returncode
        interrupt_group(self.proc.pid)
        return self.proc.wait(timeout=30)

    def exit_statuses(self) -> dict[str, int]:
        """Each node's exit status, from the launcher's last line (``[launch] name: exit N, ...``)."""
        final = next((line for line in reversed(self.lines) if re.fullmatch(r"\[launch\] (\S+: exit -?\d+(, )?)+", line)),
                     None)
        if final is None:
            raise AssertionError("no exit statuses:\n" + "\n".join(self.lines[-10:]))
        return {m.group(1): int(m.group(2)) for m in re.finditer(r"(\S+): exit (-?\d+)", final)}

    def stopped(self, name: str) -> bool:
        """Whether Ctrl-C stopped node process ``name`` within its teardown bound: cleanly (status 0), or, where the
        upstream DDS teardown race after a killed peer hung its teardown (docs/nodes.md), by its own watchdog after
        ``TEARDOWN_S`` with its stacks printed (status 1), or, where its exit hung after the teardown, by SIGALRM
        past ``EXIT_S`` (both said as a warning, so the run shows it)."""
        status = self.exit_statuses()[name]
        if status == -signal.SIGALRM:  # its exit hung after the teardown (the same race at exit): EXIT_S ended it
            warnings.warn(f"{name}'s exit hung after its teardown and SIGALRM ended it past EXIT_S", stacklevel=2)
            return True
        if status == 1 and f"[{name}] Timeout (0:00:{TEARDOWN_S:02.0f})!" in self.lines:
            warnings.warn(f"{name}'s teardown hung and its watchdog ended it:\n" + "\n".join(
                line for line in self.lines if line.startswith(f"[{name}]"))[-3000:], stacklevel=2)
            return True
        return status == 0

    def kill(self) -> None:
        """SIGKILL the whole launch (a test's clean-up after a failure)."""
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(timeout=30)


@dataclass
class Rig:
    """A launched suite (with the example supervisor), the test's driver and its halt service."""

    launch: Launch
    context: Context
    driver: PolicySideNode
    executor: SingleThreadedExecutor
    halts: list[float] = field(default_factory=list)
    """When the supervisor called ``/test/halt`` (monotonic seconds)."""

    def spin_until(self, condition: Callable[[], bool], timeout: float = 30.0) -> bool:
        return spin_until(self.executor, condition, timeout, step=0.01)

    def pace(self, seconds: float, condition: Callable[[], bool] = lambda: False) -> bool:
        """Spin for ``seconds`` of a policy period (returning early once ``condition`` holds)."""
        return self.spin_until(condition, timeout=seconds)

    def start(self, rollout_id: int) -> None:
        self.driver.start(rollout_id)
        self.pace(0.2)  # the nodes take the START before the first step (the policy resets the sim first)

    def step(self, rollout_id: int, rollout: Rollout, step: int) -> None:
        self.driver.step(rollout_id, step, rollout.embeddings[step], rollout.actions[step], rollout.exec_steps)

    def run_paced(self, rollout_id: int, rollout: Rollout, steps: range) -> dict[int, FailureAlarm]:
        """Publish ``steps`` at 10 Hz, each after the previous one's verdict arrived."""
        for step in steps:
            began = time.monotonic()
            self.step(rollout_id, rollout, step)
            assert self.spin_until(lambda s=step: s in self.driver.alarms_of(rollout_id)), \
                (rollout_id, step, "\n".join(self.launch.lines[-30:]))
            self.pace(max(0.0, POLICY_PERIOD_S - (time.monotonic() - began)))
        return self.driver.alarms_of(rollout_id)

    def steps_until(self, noticed: Callable[[], bool], rollout_id: int, rollout: Rollout, first: int) -> int:
        """Go on publishing at 10 Hz from step ``first`` until ``noticed()``; the steps published meanwhile."""
        for published, step in enumerate(range(first, rollout.length)):
            if noticed():
                return published
            began = time.monotonic()
            self.step(rollout_id, rollout, step)
            if self.pace(max(0.0, POLICY_PERIOD_S - (time.monotonic() - began)), noticed):
                return published + 1
        raise AssertionError(f"not noticed within {rollout.length - first} steps:\n"
                             + "\n".join(self.launch.lines[-40:]))

    def wait_healthy(self, name: str) -> None:
        """Wait until ``name`` reports ACTIVE again, the fusion node attributes every score stream to the suite
        (a respawned node's publishers are named in its graph: a rollout started before is doubted, rightly) and
        the driver's topics are wired to the whole suite. Attributed: a fusion report received after that ACTIVE
        has matched every publisher of the score topics the driver's graph shows (a respawned node's too: its
        scores may reach the fusion node before the graph names it, about a second with the suite's discovery
        profile) and names them all."""
        key, fusion = f"fiper: /fiper/{name}", "fiper: /fiper/fusion_node"
        self.driver.diagnostics.pop(key, None)
        self.driver.diagnostics.pop(fusion, None)
        assert self.spin_until(lambda: self.driver.diagnostics.get(key, {}).get("lifecycle_state") == "active",
                               timeout=60), "\n".join(self.launch.lines[-40:])
        self.driver.diagnostics.pop(fusion, None)

        def attributed() -> bool:
            values = self.driver.diagnostics.get(fusion, {})
            matched = all(int(values.get(f"{MATCHED_PUBLISHERS}{topic}", "0")) >= self.driver.count_publishers(topic)
                          for topic in SCORE_TOPICS)
            named = not any(NOT_NAMED in value for k, value in values.items() if k.startswith(PUBLISHERS_KEY))
            return values.get("scores_in_doubt") == "no" and matched and named

        assert self.spin_until(attributed, timeout=60), (self.driver.diagnostics.get(fusion),
                                                         "\n".join(self.launch.lines[-40:]))
        assert self.spin_until(lambda: self.driver.embeddings.get_subscription_count() >= 1
                               and self.driver.batches.get_subscription_count() >= 1
                               and self.driver.events.get_subscription_count() >= 4)

    def close(self) -> None:
        """Stop the driver and SIGKILL the launch (what a test leaves behind)."""
        self.executor.shutdown()
        self.driver.destroy_node()
        rclpy.try_shutdown(context=self.context)
        self.launch.kill()


def node_entry(name: str, parameters: dict[str, object] | None = None, *, package: str = "fiper_ros",
               namespace: str = "/fiper", **attributes: object) -> dict[str, object]:
    """One ``node`` tag of a launch YAML: ``package``'s executable ``name``, named so, with ``parameters`` (by name)
    and other attributes (``respawn``, ``respawn_delay``, ``on_exit``, ...)."""
    params = [{"name": key, "value": value} for key, value in (parameters or {}).items()]
    return {"node": {"pkg": package, "exec": name, "name": name, "namespace": namespace, "output": "screen",
                     **({"param": params} if params else {}), **attributes}}


def write_launch(path: Path, *entries: dict[str, object]) -> Path:
    """Write the launch YAML of ``entries`` (tags) to ``path``."""
    path.write_text(yaml.safe_dump({"launch": list(entries)}, sort_keys=False))
    return path


def suite_config(path: Path, calibration_dir: Path, *, respawn: bool = False,
                 scoring: dict[str, object] | None = None, fusion: dict[str, object] | None = None) -> Path:
    """Write a launch YAML to ``path``: the scoring nodes on ``calibration_dir`` (and ``scoring`` parameters), the
    fusion node (and ``fusion`` parameters; ``respawn`` with a delay of 0.5 s for all three) and the example
    supervisor calling ``/test/halt``."""
    parameters = {"calibration_dir": str(calibration_dir), **(scoring or {})}
    respawning = {"respawn": str(respawn).lower(), "respawn_delay": 0.5}
    return write_launch(
        path,
        node_entry("rnd_oe_node", parameters, **respawning),
        node_entry("ace_node", parameters, **respawning),
        node_entry("fusion_node", fusion, **respawning),
        node_entry("supervisor_node", {"halt_service": "/test/halt", "deadline_s": 2.0}))


def open_rig(config: Path, domain: int) -> Rig:
    """Launch ``config`` in ``domain`` and make the test's driver, with the ``/test/halt`` service, beside it."""
    launch = Launch(config, domain)
    context = Context()
    rclpy.init(context=context, domain_id=domain)
    executor = SingleThreadedExecutor(context=context)
    rig = Rig(launch, context, PolicySideNode(context), executor)

    def on_halt(request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        del request
        rig.halts.append(time.monotonic())
        response.success = True
        return response

    rig.driver.create_service(Trigger, "/test/halt", on_halt)
    executor.add_node(rig.driver)
    return rig
