"""Evaluation metrics, Sec. 5 and App. B.4.

Failed rollouts are positives, successful ones negatives. ``Acc = (TPR + TNR) / 2`` (balanced).
The detection time of a true positive is ``DT_i = t_i / T`` (the paper, ``dt_mode="paper"``) or
``t_i / (T_max - 1)`` (the authors' code, ``dt_mode="reference"``; ``T_max`` is the longest rollout
over calibration and test there), ``t_i`` being the index of the first alarm. ``DT`` is the mean over
true positives only, and the balanced timestep-wise accuracy is
``TWA = 1/2 [sum_TP (1 - DT_i) / #P + #TN / #N]``.

Edge cases: without positives, TPR, DT and the positive half of TWA are undefined (NaN), and so are
Acc and TWA; without negatives likewise for TNR, Acc and TWA. DT is NaN without true positives. The
two halves of TWA are also returned (``twa_pos``, ``twa_neg``) so a one-class evaluation keeps its
defined half.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

DT_MODES = ("paper", "reference")


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


def evaluate(
    alarm_steps: Sequence[int | None],
    failed: Sequence[bool],
    t_max: int | Sequence[int],
    dt_mode: str = "paper",
) -> dict[str, Any]:
    """TPR, TNR, Acc, DT and balanced TWA of one failure predictor over a set of rollouts.

    Args:
        alarm_steps: Per rollout, the policy step of the first alarm or ``None``.
        failed: Per rollout, whether it failed (a positive).
        t_max: ``T`` of the DT formula, one value or one per rollout.
        dt_mode: ``"paper"`` (``t / T``) or ``"reference"`` (``t / (T - 1)``).

    Returns:
        ``tpr, tnr, acc, dt, twa, twa_pos, twa_neg`` and the counts ``tp, fn, tn, fp, n_pos, n_neg``.
    """
    if dt_mode not in DT_MODES:
        raise ValueError(f"unknown dt_mode {dt_mode!r}; expected one of {DT_MODES}")
    if len(alarm_steps) != len(failed):
        raise ValueError(f"{len(alarm_steps)} alarm steps but {len(failed)} outcomes")
    horizons = [int(t_max)] * len(failed) if isinstance(t_max, int) else [int(t) for t in t_max]
    if len(horizons) != len(failed):
        raise ValueError(f"{len(horizons)} t_max values but {len(failed)} outcomes")
    tp = fn = tn = fp = 0
    detection_times: list[float] = []
    for step, is_failure, horizon in zip(alarm_steps, failed, horizons):
        if is_failure:
            if step is None:
                fn += 1
            else:
                tp += 1
                detection_times.append(_detection_time(int(step), horizon, dt_mode))
        elif step is None:
            tn += 1
        else:
            fp += 1
    n_pos, n_neg = tp + fn, tn + fp
    tpr, tnr = _ratio(tp, n_pos), _ratio(tn, n_neg)
    twa_pos = _ratio(sum(1.0 - dt for dt in detection_times), n_pos)
    twa_neg = tnr
    return {
        "tpr": tpr,
        "tnr": tnr,
        "acc": (tpr + tnr) / 2.0,
        "dt": sum(detection_times) / tp if tp else math.nan,
        "twa": (twa_pos + twa_neg) / 2.0,
        "twa_pos": twa_pos,
        "twa_neg": twa_neg,
        "tp": tp,
        "fn": fn,
        "tn": tn,
        "fp": fp,
        "n_pos": n_pos,
        "n_neg": n_neg,
        "dt_mode": dt_mode,
    }
