"""The demo's picture of one rollout: both windowed scores, both thresholds, the alarm step, the outcome."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402 - after the backend choice

from fiper_ros.client.trace import ACE, RND_OE, RolloutTrace  # noqa: E402

TITLES = {RND_OE: "RND-OE: windowed observation score (eq. 2)", ACE: "ACE: windowed action-chunk entropy (eq. 5)"}


def plot_trace(trace: RolloutTrace, path: Path, task: str) -> Path:
    """Write ``path`` (PNG): two panels, scores against thresholds, alarm line, outcome in the title."""
    figure, axes = plt.subplots(2, 1, figsize=(7.0, 5.2), sharex=True)
    for axis, name in zip(axes, (RND_OE, ACE), strict=True):
        steps, windowed, threshold = trace.scores[name].arrays()
        axis.plot(steps, windowed, marker=".", label="windowed score")
        axis.step(steps, threshold, where="mid", linestyle="--", color="tab:orange", label="threshold")
        if trace.alarm_step is not None:
            axis.axvline(trace.alarm_step, color="red", linewidth=1.2, label=f"alarm (step {trace.alarm_step})")
        axis.set_title(TITLES[name], fontsize=9)
        axis.legend(fontsize=7, loc="upper left")
    axes[1].set_xlabel("policy step")
    outcome = trace.outcome or "did not end"
    figure.suptitle(f"{task} / {trace.scenario} seed {trace.seed} ({trace.label}): {outcome}; {trace.verdict()}",
                    fontsize=9)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path
