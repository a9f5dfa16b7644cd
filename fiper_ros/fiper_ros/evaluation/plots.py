"""PNG figures of an evaluation (matplotlib, Agg backend).

- ``scores_by_category.png`` (paper Fig. 3): per-step score divided by its CP band threshold
  (``w = 1``, the middle delta), averaged per rollout; bars: mean per category over tasks, error bars
  the 25/75 % quantiles.
- ``window_impact.png`` (App. C, window size): TWA, Acc, DT, TPR, TNR against ``w`` per threshold
  type, averaged over tasks, seeds and deltas (FIPER: ``w_O = w_A = w``, AND).
- ``delta_impact.png`` (App. C, quantiles): the metrics against ``1 - delta`` at ``w = 15`` (or the
  nearest swept window).
- ``example_rollouts.png``: FIPER's selected configuration on one test rollout per category of the
  first task: both windowed scores, both thresholds and the alarm step (computed through the core
  single-configuration functions).

Every figure names at its foot the data it was drawn from (tasks, calibration successes, test rollouts), so a
figure of a small or synthetic set says so.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # the backend must be chosen first
import numpy as np

from fiper_ros.core.combine_mode import CombineMode
from fiper_ros.core.fusion import alarms_over_rollout
from fiper_ros.core.thresholds import Threshold, fit_threshold
from fiper_ros.core.window import aggregate
from fiper_ros.evaluation.cache import StreamScores
from fiper_ros.evaluation.data import CATEGORIES
from fiper_ros.evaluation.engine import EvaluationResult
from fiper_ros.evaluation.methods import METHODS
from fiper_ros.evaluation.protocol import METRICS, nanmean
from fiper_ros.evaluation.report import KIND_LABELS, LABELS, config_text, data_text, middle_delta
from fiper_ros.evaluation.sweep import FIPER, Group

IMPACT_WINDOW = 15


def _save(figure: plt.Figure, path: Path, result: EvaluationResult, dpi: int) -> None:
    """Write ``figure`` to ``path`` labelled at its foot with the data it was drawn from (:func:`data_text`)."""
    figure.text(0.005, 0.005, f"data: {data_text(result)}", fontsize=7, color="dimgray", ha="left", va="bottom")
    figure.tight_layout(rect=(0.0, 0.03, 1.0, 1.0))
    figure.savefig(path, dpi=dpi)
    plt.close(figure)


def _middle_delta(result: EvaluationResult) -> float:
    return middle_delta(result.settings.sweep.deltas)


def _fit(stream: StreamScores, window: int | None, kind: str, result: EvaluationResult) -> Threshold:
    """The core threshold of one single configuration (the sweep's rules and split, first seed)."""
    settings = result.settings.calibration_settings(result.settings.seeds[0]).threshold_settings()
    mode = "cumulative" if window is None else "window"
    curves = [aggregate(c, mode, window or 1) for c in stream.conformal]
    shape = None if stream.fit is None else [aggregate(c, mode, window or 1) for c in stream.fit]
    return fit_threshold(curves, replace(settings, kind=kind, delta=_middle_delta(result)), shape)


def scores_by_category(result: EvaluationResult, path: Path) -> None:
    """Paper Fig. 3 from the first seed's scores."""
    streams = [s for s in ("pca_kmeans", "logpzo", "rnd_oe", "rnd_a", "stac", "ace")
               if all(s in result.streams[t] for t in result.tasks)]
    ratios: dict[str, dict[str, list[float]]] = {s: {c: [] for c in CATEGORIES} for s in streams}
    for dataset in result.datasets:
        for stream in streams:
            scores = result.streams[dataset.task][stream]
            threshold = _fit(scores, 1, "cp_band", result)
            for category, test in zip(dataset.categories, scores.test):
                ratio = test / np.maximum(threshold.over(test.shape[0]), 1e-12)
                ratios[stream][category].append(float(np.mean(ratio)))
    figure, axis = plt.subplots(figsize=(10, 3.5))
    width = 0.8 / len(CATEGORIES)
    colors = ("#0e7fc8", "#7fbfe6", "#d62728", "#f09a9b")
    for c, category in enumerate(CATEGORIES):
        means, low, high = [], [], []
        for stream in streams:
            values = np.array(ratios[stream][category]) if ratios[stream][category] else np.array([np.nan])
            mean = float(nanmean(values, axis=0))
            means.append(mean)
            low.append(max(mean - float(np.nanquantile(values, 0.25)), 0.0))
            high.append(max(float(np.nanquantile(values, 0.75)) - mean, 0.0))
        x = np.arange(len(streams)) + (c - (len(CATEGORIES) - 1) / 2) * width
        axis.bar(x, means, width, yerr=[low, high], color=colors[c], label=category, capsize=2)
    axis.set_xticks(np.arange(len(streams)), [METHODS[s].label for s in streams])
    axis.set_ylabel("score / CP band threshold")
    axis.axhline(1.0, color="black", linewidth=0.8, linestyle="--")
    axis.legend(ncol=4, fontsize=8)
    axis.set_title("Per-step scores by rollout category (w = 1, mean over tasks; bars: 25/75 %)")
    _save(figure, path, result, dpi=110)


def _series(result: EvaluationResult, method: str, kind: str, labels: list[str]) -> np.ndarray:
    """``[len(labels), deltas, 5]`` metrics averaged over tasks and seeds for one method and kind."""
    index = {g: i for i, g in enumerate(result.groups)}
    metrics = result.metrics["all"]
    rows = []
    for label in labels:
        group = Group(method, f"{label}/{label}", kind, CombineMode.AND.value) if method == FIPER else Group(method, label, kind)
        rows.append(nanmean(metrics[:, :, index[group]], axis=(0, 1)) if group in index else
                    np.full((metrics.shape[3], len(METRICS)), np.nan))
    return np.stack(rows)


def _swept(result: EvaluationResult) -> list[str]:
    """The methods with a window and threshold grid (not the elapsed-time baseline's single configuration)."""
    catalogue = result.settings.catalogue()
    return [m for m in result.settings.methods if catalogue[m].fixed is None]


def window_impact(result: EvaluationResult, path: Path) -> None:
    """Metrics against the window size, one column per threshold type."""
    kinds = result.settings.sweep.kinds
    windows = sorted(set(result.settings.sweep.windows))
    figure, axes = plt.subplots(len(METRICS), len(kinds), figsize=(4 * len(kinds), 2.2 * len(METRICS)),
                                squeeze=False, sharex=True)
    catalogue = result.settings.catalogue()
    for k, kind in enumerate(kinds):
        for method in _swept(result):
            values = nanmean(_series(result, method, kind, [str(w) for w in windows]), axis=1)
            for m, metric in enumerate(METRICS):
                axes[m, k].plot(windows, values[:, m], label=catalogue[method].label, linewidth=1.2)
        axes[0, k].set_title(KIND_LABELS[kind])
        axes[-1, k].set_xlabel("window w")
    for m, metric in enumerate(METRICS):
        axes[m, 0].set_ylabel(LABELS[metric])
    axes[0, -1].legend(fontsize=7)
    figure.suptitle("Impact of the window size (mean over tasks, seeds and deltas)")
    _save(figure, path, result, dpi=100)


def delta_impact(result: EvaluationResult, path: Path) -> None:
    """Metrics against ``1 - delta`` at the window nearest to 15."""
    kinds = result.settings.sweep.kinds
    windows = sorted(set(result.settings.sweep.windows))
    window = min(windows, key=lambda w: abs(w - IMPACT_WINDOW))
    levels = [1.0 - d for d in result.settings.sweep.deltas]
    figure, axes = plt.subplots(len(METRICS), len(kinds), figsize=(4 * len(kinds), 2.2 * len(METRICS)),
                                squeeze=False, sharex=True)
    catalogue = result.settings.catalogue()
    for k, kind in enumerate(kinds):
        for method in _swept(result):
            values = _series(result, method, kind, [str(window)])[0]
            for m in range(len(METRICS)):
                axes[m, k].plot(levels, values[:, m], marker=".", label=catalogue[method].label, linewidth=1.2)
        axes[0, k].set_title(KIND_LABELS[kind])
        axes[-1, k].set_xlabel("1 - delta")
    for m, metric in enumerate(METRICS):
        axes[m, 0].set_ylabel(LABELS[metric])
    axes[0, -1].legend(fontsize=7)
    figure.suptitle(f"Impact of the quantile 1 - delta (w = {window}, mean over tasks and seeds)")
    _save(figure, path, result, dpi=100)


def example_rollouts(result: EvaluationResult, path: Path, group: Group) -> None:
    """FIPER's scores, thresholds and alarm on one test rollout per category of the first task."""
    dataset = result.datasets[0]
    streams = result.streams[dataset.task]
    w_obs, w_act = group.windows()
    threshold_obs = _fit(streams["rnd_oe"], w_obs, group.kind, result)
    threshold_act = _fit(streams["ace"], w_act, group.kind, result)
    picks = [(c, dataset.categories.index(c)) for c in CATEGORIES if c in dataset.categories]
    figure, axes = plt.subplots(2, len(picks), figsize=(3.6 * len(picks), 5), squeeze=False)
    for column, (category, index) in enumerate(picks):
        eta_obs = aggregate(streams["rnd_oe"].test[index], group.aggregation, w_obs or 1)
        eta_act = aggregate(streams["ace"].test[index], group.aggregation, w_act or 1)
        gamma_obs, gamma_act = threshold_obs.over(eta_obs.shape[0]), threshold_act.over(eta_act.shape[0])
        _, first = alarms_over_rollout(eta_obs, gamma_obs, eta_act, gamma_act, group.combine)
        for row, (eta, gamma, name) in enumerate(((eta_obs, gamma_obs, "RND-OE"), (eta_act, gamma_act, "ACE"))):
            axis = axes[row, column]
            axis.plot(eta, label=f"windowed {name}")
            axis.plot(gamma, linestyle="--", label="threshold")
            if first is not None:
                axis.axvline(first, color="red", linewidth=1.0, label="alarm")
            axis.set_ylabel(name)
            axis.legend(fontsize=7)
        axes[0, column].set_title(f"{category}: {dataset.test[index].rollout_id}", fontsize=8)
        axes[1, column].set_xlabel("policy step")
    figure.suptitle(f"FIPER on {dataset.task} ({config_text(group)}, delta = {_middle_delta(result)})")
    _save(figure, path, result, dpi=100)


def write_figures(result: EvaluationResult, directory: Path) -> list[str]:
    """All figures that the run's methods allow; returns their file names."""
    directory.mkdir(parents=True, exist_ok=True)
    written = ["scores_by_category.png", "window_impact.png", "delta_impact.png"]
    scores_by_category(result, directory / written[0])
    window_impact(result, directory / written[1])
    delta_impact(result, directory / written[2])
    chosen = next(iter(result.protocols.values())).selected.get(FIPER)
    if chosen is not None:
        example_rollouts(result, directory / "example_rollouts.png", chosen.group)
        written.append("example_rollouts.png")
    return written
