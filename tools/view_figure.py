"""docs/img/view_panels.png: what each panel of the live view's layout shows, drawn with matplotlib (not a Foxglove
screenshot: there is no display here) from real data (docs/view.md).

    python tools/view_figure.py [--out docs/img/view_panels.png]      (after `source env.sh`)

The data: the harmful-OOD Sorting rollout recorded in the sim (``bags/sorting_sim/test_rollouts/box_pos``, first
bag), scored with the set's calibration by the core (``predict_rollout``, what the scoring nodes compute) and fused
step by step by the fusion node's own state machine (``AlarmFuser``): the windowed scores, thresholds, states and
reasons the suite publishes for it. The cameras: the sim's renders of the Sorting scene (docs/img/sim_sorting_*.png).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from fiper_ros.bagio.rollout_bags import read_rollouts
from fiper_ros.core.calibration import load_calibration
from fiper_ros.core.detectors import ACE, RND_OE
from fiper_ros.core.monitor import predict_rollout
from fiper_ros.interface.messages import AlarmStateName
from fiper_ros.interface.topics import score_topic
from fiper_ros.runtime.alarm import AlarmFuser, DetectorScore
from fiper_ros.view.layout import STATE_COLOURS

ROOT = Path(__file__).resolve().parents[1]
SET = ROOT / "bags" / "sorting_sim"
BAG = sorted((SET / "test_rollouts" / "box_pos").iterdir())[0]


def fused(rollout_id: int, prediction: object, combine: str) -> list[tuple[str, str]]:
    """(state, reason) of every step, as the fusion node says them."""
    fuser = AlarmFuser(combine, detectors=tuple(prediction.detectors))  # type: ignore[attr-defined]
    fuser.start(rollout_id, 0)
    out = []
    for t in range(len(prediction.alarms)):  # type: ignore[attr-defined]
        for name, trace in prediction.detectors.items():  # type: ignore[attr-defined]
            eta, gamma = float(np.float32(trace.windowed[t])), float(np.float32(trace.thresholds[t]))
            state = fuser.add(DetectorScore(name, rollout_id, t, eta, gamma, t, True, bool(trace.exceeded[t])), t)
        out.append((state.state, state.reason))
    return out


def draw(out: Path) -> Path:
    calibration = load_calibration(SET / "calibration")
    rollout = read_rollouts(BAG)[0]
    prediction = predict_rollout(rollout, calibration)
    states = fused(1, prediction, calibration.settings.combine)
    steps = np.arange(rollout.length)
    figure = plt.figure(figsize=(13, 8.5))
    grid = figure.add_gridspec(5, 2, width_ratios=(3, 2), height_ratios=(3, 3, 1.2, 1, 0.01), hspace=0.85)
    for row, (label, side, detector) in enumerate((("RND-OE", "obs", RND_OE), ("ACE", "act", ACE))):
        axes = figure.add_subplot(grid[row, 0])
        trace = prediction.detectors[detector]
        axes.plot(steps, trace.windowed, color="#1f77b4", lw=1.5, label=f"{label} windowed score (eta_{side})")
        axes.step(steps, trace.thresholds, where="post", color="#d62728", ls="--", label=f"threshold (gamma_{side})")
        axes.set_title(f"Plot: {label}: windowed score and threshold  ({score_topic(detector)})", fontsize=9,
                       loc="left")
        axes.legend(fontsize=8, loc="upper left")
        axes.set_xlim(0, rollout.length - 1)
    transitions = figure.add_subplot(grid[2, 0])
    for t, (state, _) in enumerate(states):
        transitions.barh(0, 1, left=t - 0.5, color=STATE_COLOURS[state], height=0.6)
    first = next(t for t, (state, _) in enumerate(states) if state == AlarmStateName.ALARM)
    transitions.text(first / 2, 0, "OK", ha="center", va="center", color="white", fontsize=9)
    transitions.text((first + rollout.length) / 2, 0, "ALARM", ha="center", va="center", color="white", fontsize=9)
    transitions.set_yticks([0], ["alarm"])
    transitions.set_xlim(-0.5, rollout.length - 0.5)
    transitions.set_xlabel("policy step (Foxglove: time)", fontsize=8)
    transitions.set_title("State Transitions: alarm state  (/fiper/alarm.state: OK / ALARM / UNKNOWN)", fontsize=9,
                          loc="left")
    reason = figure.add_subplot(grid[3, 0])
    reason.axis("off")
    reason.set_title("Markdown: why, the alarm's reason  (/fiper/alarm.reason)", fontsize=9, loc="left")
    reason.text(0, 0.55, f"step {first}: {states[first][1]}\nstep {rollout.length - 1}: {states[-1][1]}",
                fontsize=8.5, family="monospace", va="center", wrap=True)
    for row, camera in enumerate(("wrist", "third")):
        axes = figure.add_subplot(grid[row, 1])
        axes.imshow(plt.imread(ROOT / "docs" / "img" / f"sim_sorting_{camera}.png"))
        axes.axis("off")
        axes.set_title(f"Image: {camera} camera  (/camera/{camera}/image_raw; the sim's Sorting scene)", fontsize=9,
                       loc="left")
    note = figure.add_subplot(grid[2:4, 1])
    note.axis("off")
    note.text(0, 1, "Diagnostics (a tab): one row per node from /diagnostics,\n"
              "its level, message and values (not drawn: a bag of the\n"
              "policy's side has no diagnostics).\n\n"
              f"Data: {BAG.relative_to(ROOT)}\n(harmful OOD, recorded in the sim), scored with\n"
              f"{(SET / 'calibration').relative_to(ROOT)}; {calibration.settings.combine.upper()} fusion.",
              fontsize=8.5, va="top")
    figure.suptitle("What each panel of fiper.layout.json shows: drawn with matplotlib from real data, "
                    "NOT a Foxglove screenshot", fontsize=11, fontweight="bold")
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out, dpi=90, bbox_inches="tight")
    plt.close(figure)
    return out


def main() -> int:
    """Write the figure."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "img" / "view_panels.png")
    print(f"written: {draw(parser.parse_args().out)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
