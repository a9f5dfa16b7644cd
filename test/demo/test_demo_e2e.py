"""`fiper demo` end to end: sim bridge, policy node, RND-OE, ACE, fusion and supervisor as separate processes
over loopback DDS, on the shipped Sorting model and calibration; the live alarms equal the offline oracle's
on the very data the run recorded."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from helpers.demo_run import ROOT, run_demo

from fiper_ros.bagio.reader import BagReader
from fiper_ros.core.calibration import load_calibration
from fiper_ros.evaluation.offline import predict_bag


def test_demo_runs_the_suite_and_its_alarms_equal_the_offline_oracle(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    run, summary = run_demo(out)
    in_dist, ood = summary["rollouts"]
    assert (in_dist["scenario"], ood["scenario"]) == ("id", "box_pos")
    log = (out / "suite.log").read_text()
    why = "\n".join(line for line in log.splitlines() if "halting" in line or "ended:" in line) + run.stdout[-2000:]
    assert in_dist["outcome"] == "success" and in_dist["alarm_step"] is None, why
    assert ood["outcome"] == "failure" and ood["alarm_step"] is not None
    # what judged, said with the calibration's combine (the pair under one threshold is not FIPER's AND)
    assert summary["judged_by"] == "RND-OE and ACE (max)" and "judged by RND-OE and ACE (max)" in run.stdout
    assert in_dist["judged_by"] == ood["judged_by"] == "RND-OE and ACE (max)"  # from the fusion node's alarms
    # The supervisor halted the robot on the alarm: the bridge says why the rollout ended. The monitor scores
    # step t beside the policy computing step t + 1 (as on a robot), so the halt lands in step t + 1 or t + 2
    # (26 steps after an alarm at step 25); how far the policy gets meanwhile is a race that load can
    # shift, so the bound is 10 steps (4 s of robot time), still far below a missed halt (75 steps).
    assert f"halting the robot (rollout {ood['rollout_id']}): ALARM" in log
    assert f"rollout {ood['rollout_id']} ended: failure (halted)" in log
    assert ood["alarm_step"] + 1 <= ood["policy_steps"] <= ood["alarm_step"] + 10, "the supervisor halts the robot"
    assert "ALARM  step" in run.stdout and "why: RND-OE " in run.stdout  # the alarm's one line (#22)
    # the live view ran beside the suite (#22): its address and layout printed, the view node serving
    assert "fiper demo: live view ws://127.0.0.1:0 (any free port" in run.stdout and "fiper.layout.json" in run.stdout
    assert re.search(r"\[view_node\].*serving ws://127\.0\.0\.1:\d+ ", log)
    for name in ("rollout_id_1002.png", "rollout_box_pos_1000.png"):
        assert (out / name).read_bytes()[:4] == b"\x89PNG"

    with BagReader(out / "bag") as bag:
        topics = set(bag.topics)
    assert {"/fiper/observation_embedding", "/fiper/action_chunks", "/fiper/scores/rnd_oe", "/fiper/scores/ace",
            "/fiper/alarm", "/fiper/rollout_events", "/camera/wrist/image_raw", "/sim/action"} <= topics
    calibration = load_calibration(ROOT / "models/sorting/calibration")
    assert calibration.threshold("rnd_oe").kind == calibration.threshold("ace").kind == "cp_constant"
    # one conformal factor for both detectors: the promise is delta itself (docs/results.md, models/)
    assert calibration.settings.combine == "max" and calibration.auto["settings"]["promise"] == "delta"
    # At least 5 policy steps before the end: unhalted, this rollout fails at step 27, where the pair's AND alarmed
    # (ACE's exceedance), one step before the halt ended it (docs/results.md, issue #44).
    assert ood["alarm_step"] <= 27 - 5, ood["alarm_step"]
    offline = {r.rollout_id: r for r in predict_bag(out / "bag", calibration)}
    for live in (in_dist, ood):
        oracle = offline[live["rollout_id"]]
        assert len(oracle.steps) == live["policy_steps"]
        # the thresholds the suite published are the calibration's, step by step
        assert np.array_equal(np.float32(live["rnd_oe"]["threshold"]),
                              np.float32(calibration.threshold("rnd_oe").over(len(oracle.steps))))
        assert oracle.first_alarm == live["alarm_step"]
        assert [round(s.windowed[0], 3) for _, s in sorted(oracle.steps.items())] == \
            [round(v, 3) for v in live["rnd_oe"]["windowed"]]
