"""`fiper demo` with the second shipped Sorting calibration, ``models/sorting/calibration_cp_constant`` (CP
constant: one threshold per detector for the whole rollout, the paper's AND), through the whole live suite; the live
alarms equal the offline oracle's on the data the run recorded. The default calibration (the pair's ``max`` under
one conformal threshold) is ``test_demo_e2e``'s."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from helpers.demo_run import ROOT, run_demo

from fiper_ros.core.calibration import load_calibration
from fiper_ros.evaluation.offline import predict_bag

CP_CONSTANT = ROOT / "models" / "sorting" / "calibration_cp_constant"


def test_demo_with_the_cp_constant_calibration_alarms_as_the_offline_oracle(tmp_path: Path) -> None:
    calibration = load_calibration(CP_CONSTANT)
    assert calibration.threshold("rnd_oe").kind == calibration.threshold("ace").kind == "cp_constant"
    out = tmp_path / "demo"
    run, summary = run_demo(out, "--calibration", str(CP_CONSTANT))
    assert Path(summary["calibration"]) == CP_CONSTANT
    log = (out / "suite.log").read_text()
    why = "\n".join(line for line in log.splitlines() if "halting" in line or "ended:" in line) + run.stdout[-2000:]
    offline = {r.rollout_id: r for r in predict_bag(out / "bag", calibration)}
    for live in summary["rollouts"]:
        oracle = offline[live["rollout_id"]]
        assert oracle.first_alarm == live["alarm_step"], (live["label"], why)
        steps = sorted(oracle.steps)
        assert len(steps) == live["policy_steps"]
        assert np.array_equal(np.float32([oracle.steps[t].windowed[0] for t in steps]),
                              np.float32(live["rnd_oe"]["windowed"]))
        assert set(np.float32(live["rnd_oe"]["threshold"])) == {np.float32(calibration.threshold("rnd_oe").over(1)[0])}
    in_dist, ood = summary["rollouts"]
    assert in_dist["alarm_step"] is None and ood["alarm_step"] is not None, why
