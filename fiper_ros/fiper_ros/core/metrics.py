"""Evaluation metrics, Sec. 5 and App. B.4.

Failed rollouts are positives, successful ones negatives. ``Acc = (TPR + TNR) / 2`` (balanced).
The detection time of a true positive is ``DT_i = t_i / T`` (the paper, ``dt_mode="paper"``) or
``t_i / (T_max - 1)`` (the authors' code, ``dt_mode="reference"``; ``T_max`` is the longest rollout
over calibration and test there), ``t_i`` being the index of the first alarm. ``DT`` is the mean over
true positives only, and the balanced timestep-wise accuracy is
``TWA = 1/2 [sum_TP (1 - DT_i) / #P + #TN / #N]``.

Edge cases (``metrics_rule="paper"``): without positives, TPR, DT and the positive half of TWA are undefined
(NaN), and so are Acc and TWA; without negatives likewise for TNR, Acc and TWA. DT is NaN without true
positives. The two halves of TWA are also returned (``twa_pos``, ``twa_neg``) so a one-class evaluation keeps
its defined half.

``metrics_rule="reference"`` computes the metrics as the authors' code does: TPR (TNR) is 0 without positives
(negatives), so Acc is their half-sum; DT is 1.0 without true positives and otherwise ``np.mean`` of the
detection times; TWA is accumulated rollout by rollout in the given order (``(1 - DT_i) / #P`` for a true
positive, ``1 / #N`` for a true negative) and halved, an empty class adding nothing; ``twa_pos`` and
``twa_neg`` are the halves with 0 for an empty class. Every one of these is then rounded to 6 decimals as
``round`` rounds a numpy float (``np.round``: scaled by ``1e6``, ``rint``, scaled back) and cast to float32.

Early detection, threshold-free (the measure of the failure-prediction literature beside TWA): a rollout's
statistic is the maximum of its (windowed) score over its steps (:func:`rollout_peaks`), or over its first
``ceil(q T_max)`` steps only (:func:`early_cut`; ``T_max`` the longest rollout of its task in the test set, a
rollout shorter than the cut-off counting all its steps), and :func:`auroc` is the area under the ROC curve of
that statistic with failures as positives: the Mann-Whitney probability that a failure's statistic exceeds a
success's, ties counting 1/2. No threshold enters it, so it says nothing about the false-alarm promise. It is
undefined (NaN) when a class is empty.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

DT_MODES = ("paper", "reference")
#: Empty classes and rounding: NaN and unrounded (paper) or the authors' code's values (module docstring).
METRIC_RULES = ("paper", "reference")
#: Decimals the authors' code rounds its metrics to.
AUTHORS_DECIMALS = 6


def _detection_time(step: int, t_max: int, dt_mode: str) -> float:
    if t_max < 1:
        raise ValueError(f"t_max must be >= 1, got {t_max}")
    if not 0 <= step < t_max:
        raise ValueError(f"alarm step {step} outside [0, t_max={t_max})")
    if dt_mode == "paper":
        return step / t_max
    return step / (t_max - 1) if t_max > 1 else 0.0


def _ratio(numerator: float, denominator: int) -> float:
    return numerator / denominator if denominator else math.nan


def authors_rounding(value: float) -> float:
    """``value`` as the authors' code reports it: rounded to :data:`AUTHORS_DECIMALS` decimals as numpy rounds
    (``round`` of a numpy float; 3.5e-6 -> 4e-6 where Python's ``round`` of a float gives 3e-6), then float32."""
    return float(np.float32(np.round(np.float64(value), AUTHORS_DECIMALS)))


def _authors_metrics(detection_times: list[float], outcomes: list[str], n_pos: int, n_neg: int, tp: int,
                     tn: int) -> dict[str, float]:
    """TPR, TNR, Acc, DT and TWA (and its halves) by the authors' code's rules (module docstring); ``outcomes``
    is each rollout's ``"tp"``, ``"fn"``, ``"tn"`` or ``"fp"`` in order."""
    tpr = tp / n_pos if n_pos else 0.0
    tnr = tn / n_neg if n_neg else 0.0
    twa = twa_pos = twa_neg = 0.0
    times = iter(detection_times)
    for outcome in outcomes:
        if outcome == "tp":
            term = (1.0 - next(times)) / n_pos
            twa, twa_pos = twa + term, twa_pos + term
        elif outcome == "tn":
            term = 1.0 / n_neg
            twa, twa_neg = twa + term, twa_neg + term
    values = {"tpr": tpr, "tnr": tnr, "acc": (tpr + tnr) / 2.0,
              "dt": float(np.mean(detection_times)) if detection_times else 1.0,
              "twa": twa * 0.5, "twa_pos": twa_pos, "twa_neg": twa_neg}
    return {name: authors_rounding(value) for name, value in values.items()}


def evaluate(
    alarm_steps: Sequence[int | None],
    failed: Sequence[bool],
    t_max: int | Sequence[int],
    dt_mode: str = "paper",
    metrics_rule: str = "paper",
) -> dict[str, Any]:
    """TPR, TNR, Acc, DT and balanced TWA of one failure predictor over a set of rollouts.

    Args:
        alarm_steps: Per rollout, the policy step of the first alarm or ``None``.
        failed: Per rollout, whether it failed (a positive).
        t_max: ``T`` of the DT formula, one value or one per rollout.
        dt_mode: ``"paper"`` (``t / T``) or ``"reference"`` (``t / (T - 1)``).
        metrics_rule: ``"paper"`` (NaN for an empty class) or ``"reference"`` (the authors' values for empty
            classes, their TWA sum and their rounding; module docstring).

    Returns:
        ``tpr, tnr, acc, dt, twa, twa_pos, twa_neg`` and the counts ``tp, fn, tn, fp, n_pos, n_neg``.
    """
    if dt_mode not in DT_MODES:
        raise ValueError(f"unknown dt_mode {dt_mode!r}; expected one of {DT_MODES}")
    if metrics_rule not in METRIC_RULES:
        raise ValueError(f"unknown metrics_rule {metrics_rule!r}; expected one of {METRIC_RULES}")
    if len(alarm_steps) != len(failed):
        raise ValueError(f"{len(alarm_steps)} alarm steps but {len(failed)} outcomes")
    horizons = [int(t_max)] * len(failed) if isinstance(t_max, int) else [int(t) for t in t_max]
    if len(horizons) != len(failed):
        raise ValueError(f"{len(horizons)} t_max values but {len(failed)} outcomes")
    detection_times: list[float] = []
    outcomes: list[str] = []
    for step, is_failure, horizon in zip(alarm_steps, failed, horizons):
        if is_failure:
            outcomes.append("fn" if step is None else "tp")
            if step is not None:
                detection_times.append(_detection_time(int(step), horizon, dt_mode))
        else:
            outcomes.append("tn" if step is None else "fp")
    tp, fn, tn, fp = (outcomes.count(outcome) for outcome in ("tp", "fn", "tn", "fp"))
    n_pos, n_neg = tp + fn, tn + fp
    if metrics_rule == "reference":
        values = _authors_metrics(detection_times, outcomes, n_pos, n_neg, tp, tn)
    else:
        tpr, tnr = _ratio(tp, n_pos), _ratio(tn, n_neg)
        twa_pos = _ratio(sum(1.0 - dt for dt in detection_times), n_pos)
        values = {"tpr": tpr, "tnr": tnr, "acc": (tpr + tnr) / 2.0,
                  "dt": sum(detection_times) / tp if tp else math.nan,
                  "twa": (twa_pos + tnr) / 2.0, "twa_pos": twa_pos, "twa_neg": tnr}
    return {
        **values,
        "tp": tp,
        "fn": fn,
        "tn": tn,
        "fp": fp,
        "n_pos": n_pos,
        "n_neg": n_neg,
        "dt_mode": dt_mode,
    }


def early_cut(t_max: int, q: float) -> int:
    """The q-AUC cut-off ``ceil(q T_max)``: how many first steps of every rollout the early statistic sees."""
    if not 0.0 < q <= 1.0:
        raise ValueError(f"q must be in (0, 1], got {q}")
    if t_max < 1:
        raise ValueError(f"t_max must be >= 1, got {t_max}")
    return math.ceil(q * t_max)


def rollout_peaks(curves: np.ndarray, lengths: Sequence[int] | np.ndarray, cut: int | None = None) -> np.ndarray:
    """Each rollout's maximum over its first ``min(cut, T_i)`` steps (``cut=None``: all its ``T_i`` steps).

    Args:
        curves: ``[..., N, T]`` per-step values, rollout ``i`` defined at steps ``0..T_i-1`` (anything after).
        lengths: ``T_i`` per rollout, ``1 <= T_i <= T``.
        cut: The steps seen (:func:`early_cut`), ``>= 1``.

    Returns:
        ``[..., N]``; ``ValueError`` when a value seen is not finite (a non-finite score is never a statistic).
    """
    values = np.asarray(curves, dtype=np.float64)
    steps = np.asarray(lengths, dtype=np.int64)
    if steps.shape != values.shape[-2:-1] or (steps.size and (steps.min() < 1 or steps.max() > values.shape[-1])):
        raise ValueError(f"lengths {steps.tolist()} do not fit curves of shape {values.shape}")
    if cut is not None:
        if cut < 1:
            raise ValueError(f"cut must be >= 1, got {cut}")
        steps = np.minimum(steps, cut)
    seen = np.arange(values.shape[-1])[None, :] < steps[:, None]  # [N, T]
    if not np.isfinite(values[..., seen]).all():
        raise ValueError("a rollout's score is not finite: it has no peak")
    return np.where(seen, values, -np.inf).max(axis=-1)


def auroc(statistics: np.ndarray, failed: Sequence[bool] | np.ndarray) -> np.ndarray:
    """AUROC of ``statistics [..., N]`` (higher: more likely a failure) against ``failed [N]``: per leading index,
    ``(#{(i, j): s_i > s_j} + #{(i, j): s_i = s_j} / 2) / (P N)`` over failures ``i`` and successes ``j``
    (Mann-Whitney, ties 1/2); NaN when there is no failure or no success. ``ValueError`` on a non-finite value."""
    values = np.asarray(statistics, dtype=np.float64)
    labels = np.asarray(failed, dtype=bool)
    if labels.ndim != 1 or values.shape[-1:] != labels.shape:
        raise ValueError(f"statistics of shape {values.shape} do not match {labels.shape[0]} outcomes")
    if not np.isfinite(values).all():
        raise ValueError("a statistic is not finite: no AUROC")
    positives, negatives = int(labels.sum()), int((~labels).sum())
    lead = values.shape[:-1]
    if positives == 0 or negatives == 0:
        return np.full(lead, math.nan)
    flat = values.reshape(-1, labels.shape[0])
    out = np.empty(flat.shape[0])
    for row, scores in enumerate(flat):
        successes = np.sort(scores[~labels])
        below = np.searchsorted(successes, scores[labels], side="left")
        tied = np.searchsorted(successes, scores[labels], side="right") - below
        out[row] = (int(below.sum()) + 0.5 * int(tied.sum())) / (positives * negatives)
    return out.reshape(lead)
