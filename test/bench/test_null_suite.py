"""The platform's floor of ``make bench-nodes`` measures the suite's path: the benchmark's driver, unchanged, is
answered through the three stand-ins over real DDS (same names, topics, QoS and executor), and the fusion stand-in
answers a step only once both of its scores have come."""
from __future__ import annotations

import subprocess
import sys
import time

from fiper_ros.bench import null_suite
from fiper_ros.bench.nodes_bench import SHAPES, PolicyStepDriver, _start, _stop
from fiper_ros.interface.conversions import action_batch_cdr, embedding_cdr


def test_the_stand_ins_answer_every_step_once_both_scores_came(ros_domain: int) -> None:
    shape = SHAPES[0]
    driver = PolicyStepDriver(shape, ros_domain)
    procs = [_start([sys.executable, "-m", null_suite.__name__, role], ros_domain) for role in null_suite.ROLES]
    try:
        driver.wait_wired("the stand-ins")
        latencies, missing, _ = driver.run(1, 20, 50.0)
        assert missing == 0 and len(latencies) == 20
        assert set(driver.received) == {(1, step) for step in range(20)}

        # one score of a step (the embedding's): no alarm; the second (the batch's): the alarm
        stamp = 10**9
        driver.emb_pub.publish(embedding_cdr(2, 0, stamp, driver.embedding))
        driver.spin_for(0.5)
        assert (2, 0) not in driver.received
        driver.act_pub.publish(action_batch_cdr(2, 0, stamp, driver.actions, shape.exec_steps, "ee_position"))
        end = time.monotonic() + 10
        while (2, 0) not in driver.received and time.monotonic() < end:
            driver.executor.spin_once(timeout_sec=0.05)
        assert (2, 0) in driver.received
    finally:
        driver.close()
        for proc in procs:
            _stop(proc)
    assert [proc.returncode for proc in procs] == [0, 0, 0]


def test_a_role_that_is_not_one_is_a_usage_error() -> None:
    done = subprocess.run([sys.executable, "-m", null_suite.__name__, "policy"], capture_output=True, text=True,
                          timeout=60, check=False)
    assert done.returncode == 2 and "usage: python -m fiper_ros.bench.null_suite {rnd_oe,ace,fusion}" in done.stderr
