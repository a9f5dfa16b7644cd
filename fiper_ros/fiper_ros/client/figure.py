"""The demo's picture of one rollout: a panel per declared detector (windowed score, threshold), the alarm step,
the outcome; the title says which detectors judged (an observation-only calibration has no ACE panel)."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # after the backend choice
from matplotlib.figure import Figure

from fiper_ros.client.trace import RolloutTrace
from fiper_ros.core.detectors import ACE, RND_OE, judged_by

TITLES = {RND_OE: "RND-OE: windowed observation score (eq. 2)", ACE: "ACE: windowed action-chunk entropy (eq. 5)"}
#: Inches of figure height per panel, and for the title and the step axis.
PANEL_IN, FRAME_IN = 2.2, 0.8


def trace_figure(trace: RolloutTrace, task: str) -> Figure:
    """A panel per declared detector, score against threshold, alarm line; the outcome and the judging detectors
    in the title (close it with ``plt.close``)."""
    figure, axes = plt.subplots(len(trace.detectors), 1, figsize=(7.0, FRAME_IN + PANEL_IN * len(trace.detectors)),
                                sharex=True, squeeze=False)
    for axis, name in zip(axes[:, 0], trace.detectors, strict=True):
        steps, windowed, threshold = trace.scores[name].arrays()
        axis.plot(steps, windowed, marker=".", label="windowed score")
        axis.step(steps, threshold, where="mid", linestyle="--", color="tab:orange", label="threshold")
        if trace.alarm_step is not None:
            axis.axvline(trace.alarm_step, color="red", linewidth=1.2, label=f"alarm (step {trace.alarm_step})")
        axis.set_title(TITLES[name], fontsize=9)
        axis.legend(fontsize=7, loc="upper left")
    axes[-1, 0].set_xlabel("policy step")
    outcome = trace.outcome or "did not end"
    figure.suptitle(f"{task} / {trace.scenario} seed {trace.seed} ({trace.label}): {outcome}; {trace.verdict()}\n"
                    f"judged by {judged_by(trace.detectors, trace.combine)}", fontsize=9)
    figure.tight_layout()
    return figure


def plot_trace(trace: RolloutTrace, path: Path, task: str) -> Path:
    """Write :func:`trace_figure` to ``path`` (PNG)."""
    figure = trace_figure(trace, task)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path
