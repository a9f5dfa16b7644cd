"""Fitting a calibration (Sec. 4, App. A): the split, the detectors' models, their windowed curves and the
thresholds.

Per task (rollouts of several tasks are calibrated together, each task its own models and shapes), only the
successful rollouts serve (``D_c`` of Sec. 4.3). Which of them fits what is the ``split``:

- ``"split"`` (default): split conformal. A seeded ``conformal_fraction`` of the successes is the conformal set:
  nothing is fitted on it but the thresholds' conformal quantiles. Every detector's model (RND-OE, ``R_d``, ...)
  and the thresholds' per-step shape (the CP band's ``mu``, ``s``; CP scaled's ``q``) are fitted on the rest, the
  fit part; with ``shape_folds`` K the shape comes from the fit part's cross-fitted curves. A new successful
  rollout is then exchangeable with the conformal set, as Proposition 1 assumes (Remark 1: ``D_ID`` and ``D_c``
  disjoint).
- ``"cross"``: K-fold cross-fitting. Each success is scored by models fitted without its fold, the thresholds
  are fitted on all these out-of-fold curves, and the deployed models are fitted on all successes: the
  guarantee is approximate (it holds to the extent that a model fitted on all successes scores a new one like a
  fold model scores its held-out fold).
- ``"same"``: the paper's Remark 1 choice, ``D_ID = D_c``. Not covered by Proposition 1: a model's scores of its
  own training rollouts are lower than those of new successes, so the thresholds come out too low.

Thresholds: with ``and`` / ``or`` each detector its own (:func:`fiper_ros.core.thresholds.fit_threshold`); with a
joint combine (``max``, ``kth:K``) one conformal factor over the detectors normalised by their shapes (and with
``equalise`` equalised on the fit part's curves; :func:`fiper_ros.core.combination.fit_joint`); ``pooled``: that factor (or each detector's) over every task's
conformal rollouts.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from fiper_ros.core.calibration.model import Calibration, CalibrationMismatch, DetectorPart, Layout, TaskPart
from fiper_ros.core.calibration.settings import CalibrationSettings
from fiper_ros.core.calibration_file import CalibrationError
from fiper_ros.core.combination import GroupCurves, fit_joint
from fiper_ros.core.detectors import LABELS, info
from fiper_ros.core.fusion import exceeds, fuse_votes
from fiper_ros.core.kinematics import ForwardKinematics
from fiper_ros.core.rnd_oe import ProgressCallback
from fiper_ros.core.rollout import Rollout, successful
from fiper_ros.core.scorers import FitContext, Scorer, fit_scorer
from fiper_ros.core.thresholds import Threshold, ThresholdError, _split, fit_threshold, minimum_conformal_set
from fiper_ros.core.window import aggregate

LOG = logging.getLogger(__name__)

#: Windowed curves (eqs. 2, 5) per declared detector, one per rollout (the same rollouts for every detector).
Curves = dict[str, list[np.ndarray]]


@dataclass(frozen=True)
class CalibrationSplit:
    """Which successful calibration rollouts (indices into one task's successes) fitted what."""

    mode: str
    fit: tuple[int, ...]
    """Fitted the models (and, with ``"split"``, the thresholds' per-step shape)."""
    conformal: tuple[int, ...]
    """Fitted the thresholds (their conformal quantiles)."""
    folds: tuple[tuple[int, ...], ...] = ()
    """With ``"cross"``: the K folds; fold ``k``'s curves come from models fitted without it."""
    shape_folds: tuple[tuple[int, ...], ...] = ()
    """With ``"split"`` and ``shape_folds`` K >= 2: K folds of :attr:`fit`; the shape curves of a fold's
    rollouts come from models fitted on the rest of the fit part (empty: in-sample shape curves)."""


def split_successes(count: int, settings: CalibrationSettings) -> CalibrationSplit:
    """The split of ``count`` successes that ``settings`` asks for, seeded by ``settings.seed``."""
    everything = tuple(range(count))
    if settings.split == "same":
        return CalibrationSplit("same", everything, everything)
    order = np.random.default_rng([settings.seed, 19]).permutation(count)  # not the CP band's stream
    if settings.split == "cross":
        if count < settings.folds:
            raise CalibrationError(f"{settings.folds}-fold cross-fitting needs at least {settings.folds} successes, "
                                   f"got {count}")
        folds = tuple(tuple(sorted(int(i) for i in fold)) for fold in np.array_split(order, settings.folds))
        return CalibrationSplit("cross", everything, everything, folds)
    conformal = min(max(round(settings.conformal_fraction * count), 1), count - 1)
    fit = tuple(sorted(int(i) for i in order[conformal:]))
    shape_folds: tuple[tuple[int, ...], ...] = ()
    if settings.shape_folds:
        if len(fit) < settings.shape_folds:
            raise CalibrationError(f"{settings.shape_folds}-fold cross-fitted shapes need at least "
                                   f"{settings.shape_folds} successes in the fit part, got {len(fit)}")
        shuffled = np.random.default_rng([settings.seed, 29]).permutation(np.array(fit))
        shape_folds = tuple(tuple(sorted(int(i) for i in fold))
                            for fold in np.array_split(shuffled, settings.shape_folds))
    return CalibrationSplit("split", fit, tuple(sorted(int(i) for i in order[:conformal])), shape_folds=shape_folds)


def _layout(rollout: Rollout, settings: CalibrationSettings) -> Layout:
    """The layout of ``rollout`` as the declared detectors read it (the action fields only if one reads actions)."""
    if not settings.needs_actions:
        return Layout(rollout.embeddings.shape[1])
    if rollout.actions is None:
        readers = [info(d).label for d in settings.detectors if info(d).reads == "actions"]
        raise CalibrationError(f"rollout {rollout.rollout_id!r} has no action batches, which {' and '.join(readers)} "
                               "read: declare detectors without them for an observation-only calibration "
                               "(fiper calibrate --detectors rnd_oe)")
    _, _, horizon, dims = rollout.actions.shape
    return Layout(rollout.embeddings.shape[1], dims, horizon, rollout.exec_steps, rollout.action_space)


def _check_layout(rollouts: Sequence[Rollout], settings: CalibrationSettings) -> Layout:
    expected = _layout(rollouts[0], settings)
    for rollout in rollouts[1:]:
        got = _layout(rollout, settings)
        for name, want in expected.__dict__.items():
            if getattr(got, name) != want:
                raise CalibrationMismatch(f"{name} of rollout {rollout.rollout_id!r}", want, getattr(got, name))
    return expected


def _curves(scorers: Mapping[str, Scorer], rollouts: Sequence[Rollout], settings: CalibrationSettings,
            fk: ForwardKinematics | None) -> Curves:
    """The windowed curves of ``rollouts`` under ``scorers``, per declared detector."""
    return {d: [aggregate(scorer.scores(r, fk), settings.aggregation_of(d), settings.window_of(d)) for r in rollouts]
            for d, scorer in scorers.items()}


@dataclass
class _Task:
    """One task's successes, split, deployed scorers and curves (conformal ``I2``; shape ``I1`` where the split
    gives one)."""

    name: str
    good: list[Rollout]
    split: CalibrationSplit
    scorers: dict[str, Scorer]
    conformal: Curves
    shape: Curves | None


def _fit(good: Sequence[Rollout], settings: CalibrationSettings, context: FitContext) -> dict[str, Scorer]:
    return {d: fit_scorer(d, good, context) for d in settings.detectors}


def _task(name: str, rollouts: Sequence[Rollout], settings: CalibrationSettings, layout: Layout,
          fk: ForwardKinematics | None, progress: ProgressCallback | None) -> _Task:
    """Split one task's successes, fit its models and score its curves."""
    good = successful(list(rollouts))
    if len(good) < settings.min_rollouts:
        where = f" of task {name!r}" if name else ""
        raise CalibrationError(f"calibration needs at least {settings.min_rollouts} successful rollouts{where}, got "
                               f"{len(good)} (of {len(rollouts)} given)")
    failed = [r for r in rollouts if r.success is not True] if settings.profile_obj.ranges_from_all else []
    context = FitContext(settings.seed, settings.profile_obj, settings.options(), layout.action_space or "ee_position",
                         fk, failed, progress)
    quiet = replace(context, progress=None)
    split = split_successes(len(good), settings)
    LOG.info("calibrating%s on %d successful rollouts (%s split: %d fit, %d conformal)", f" {name}" if name else "",
             len(good), split.mode, len(split.fit), len(split.conformal))
    scorers = _fit([good[i] for i in split.fit], settings, context)
    shape = None
    if split.mode == "same":
        conformal = _curves(scorers, good, settings, fk)
    elif split.mode == "split":
        conformal = _curves(scorers, [good[i] for i in split.conformal], settings, fk)
        shape = _out_of_fold(good, split.fit, split.shape_folds, settings, quiet, fk) if split.shape_folds else \
            _curves(scorers, [good[i] for i in split.fit], settings, fk)
    else:  # cross: each fold scored by models fitted without it, in the order of the successes
        conformal = _out_of_fold(good, range(len(good)), split.folds, settings, quiet, fk)
    return _Task(name, good, split, scorers, conformal, shape)


def _out_of_fold(good: Sequence[Rollout], members: Sequence[int], folds: Sequence[Sequence[int]],
                 settings: CalibrationSettings, context: FitContext, fk: ForwardKinematics | None) -> Curves:
    """The curves of ``good[i]`` for every member ``i`` (in ``members`` order), each fold's by models fitted on the
    other members."""
    position = {index: n for n, index in enumerate(members)}
    out: Curves = {d: [np.empty(0)] * len(position) for d in settings.detectors}
    for fold in folds:
        scorers = _fit([good[i] for i in members if i not in fold], settings, context)
        for d, curves in _curves(scorers, [good[i] for i in fold], settings, fk).items():
            for i, curve in zip(fold, curves):
                out[d][position[i]] = curve
    return out


def _normalised_groups(conformal: Mapping[str, Curves], shape: Mapping[str, Curves | None],
                       settings: CalibrationSettings) -> dict[str, GroupCurves]:
    """Shape and conformal curves per task for a normalised fit (a joint combine, pooled thresholds): the split's,
    or (no fit part: same data, cross-fitted) a seeded ``I1`` / ``I2`` split of the conformal curves, as the CP
    band makes it without shape curves."""
    out = {}
    for name, curves in conformal.items():
        if shape[name] is not None:
            out[name] = GroupCurves(shape[name], curves)
            continue
        first, second = _split(len(curves[settings.detectors[0]]), settings.threshold_settings())
        out[name] = GroupCurves({d: [c[i] for i in first] for d, c in curves.items()},
                                {d: [c[i] for i in second] for d, c in curves.items()})
    return out


def fit_thresholds(conformal: Mapping[str, Curves], shape: Mapping[str, Curves | None],
                   settings: CalibrationSettings) -> tuple[dict[str, dict[str, Threshold]], dict[str, Any]]:
    """Every task's per-detector thresholds from its conformal curves (and shape curves, ``None`` without a fit
    part), and the joint factor's summary (empty without a joint combine)."""
    detectors, combine = settings.detectors, settings.combine_rule
    out: dict[str, dict[str, Threshold]] = {name: {} for name in conformal}
    if not settings.normalised:
        ts = settings.threshold_settings()
        for name, curves in conformal.items():
            for d in detectors:
                out[name][d] = fit_threshold(curves[d], ts, None if shape[name] is None else shape[name][d])
        return out, {}
    groups = _normalised_groups(conformal, shape, settings)
    kinds = {d: settings.shape_of(d) for d in detectors}
    members = [detectors] if combine.joint else [(d,) for d in detectors]
    votes = settings.votes if combine.joint else 1
    pools = [groups] if settings.pooled else [{name: group} for name, group in groups.items()]
    summary: dict[str, Any] = {"votes": votes} if combine.joint else {}
    if settings.equalise != "none":
        summary["equalise"] = settings.equalise
    for pool in pools:
        for chosen in members:
            try:
                joint = fit_joint({name: GroupCurves({d: g.shape[d] for d in chosen},
                                                     {d: g.conformal[d] for d in chosen})
                                   for name, g in pool.items()}, chosen, kinds, votes, settings.threshold_settings(),
                                  settings.equalise, settings.equalise_level)
            except ThresholdError as error:  # e.g. a detector whose maxima cannot be equalised: one line, by name
                raise CalibrationError(str(error)) from error
            for name in pool:
                out[name].update(joint.thresholds[name])
            if combine.joint and settings.pooled:
                summary.update({"k": joint.k, "m": joint.m, "conformal": joint.conformal})
    return out, summary


def _alarmed(curves: Mapping[str, np.ndarray], thresholds: Mapping[str, Threshold], votes: int) -> bool:
    """Whether one rollout's curves make an alarm at some step under ``thresholds``."""
    decisions = [exceeds(curve, thresholds[d].over(curve.shape[0])) for d, curve in curves.items()]
    return bool(np.any(fuse_votes(decisions, votes)))


def false_alarm_estimate(conformal: Mapping[str, Curves], shape: Mapping[str, Curves | None],
                         settings: CalibrationSettings) -> dict[str, Any]:
    """Leave-one-out estimate of the false-alarm rate on new successes: each conformal rollout judged (the votes
    of the declared detectors at any step) by thresholds fitted without it (with pooled thresholds: over every
    task's other conformal rollouts). Its curves are held out from the score models with ``"split"`` and
    ``"cross"``; with ``"same"`` the models saw it, so the estimate is optimistic."""
    alarms = total = 0
    for name, curves in conformal.items():
        for j in range(len(curves[settings.detectors[0]])):
            without = {d: [c for i, c in enumerate(own) if i != j] for d, own in curves.items()}
            others = {**conformal, name: without} if settings.pooled else {name: without}
            thresholds, _ = fit_thresholds(others, {n: shape[n] for n in others}, settings)
            alarms += _alarmed({d: curves[d][j] for d in settings.detectors}, thresholds[name], settings.votes)
            total += 1
    rate = alarms / total
    return {"method": "leave-one-out over the conformal rollouts", "rollouts": total, "false_alarms": alarms,
            "rate": rate, "standard_error": math.sqrt(rate * (1.0 - rate) / total),
            "held_out_from_models": settings.split != "same"}


def conformal_count(successes: int, mode: str, settings: CalibrationSettings) -> int:
    """How many scores a threshold's conformal quantile gets from ``successes`` successes of one task."""
    conformal = successes if mode != "split" else min(max(round(settings.conformal_fraction * successes), 1),
                                                         successes - 1)
    if (settings.threshold in ("cp_band", "cp_scaled", "gaussian") or settings.normalised) and mode != "split":
        conformal -= min(max(round(settings.band_split * conformal), 1), conformal - 1)  # the band's own I2
    return conformal


def _check_finite(thresholds: Mapping[str, Mapping[str, Threshold]], tasks: Sequence[_Task],
                  settings: CalibrationSettings) -> None:
    """Refuse a threshold that is +inf somewhere, naming the fewest successes that would do."""
    for task in tasks:
        for d, threshold in thresholds[task.name].items():
            if np.isfinite(threshold.values).all():
                continue
            need = minimum_conformal_set(settings.delta)
            have = int(threshold.params.get("m2", threshold.params.get("m", 0)))
            successes = len(task.good) if not settings.pooled else sum(len(t.good) for t in tasks)
            smallest = next(m for m in range(successes + 1, 1_000_000)
                            if conformal_count(m, task.split.mode, settings) >= need)
            label = LABELS.get(d, d) if not settings.combine_rule.joint else str(settings.combine_rule)
            where = f" of task {task.name!r}" if task.name and not settings.pooled else ""
            hint = "" if settings.pooled or len(tasks) == 1 else ", or pool the tasks (--pool)"
            raise CalibrationError(
                f"the {label} threshold{where} ({settings.threshold}) is +inf: its conformal quantile at "
                f"delta={settings.delta:g} needs at least {need} rollouts, this calibration gives it {have} of "
                f"{successes} successes; calibrate on at least {smallest} successful rollouts (or raise --delta"
                f"{hint})")


def _record(task: _Task, thresholds: Mapping[str, Threshold], settings: CalibrationSettings) -> dict[str, Any]:
    """Which successes fitted what, by rollout id, and how many rollouts each threshold rests on."""
    ids = [str(r.rollout_id) for r in task.good]
    split = task.split
    return {"mode": split.mode, "seed": settings.seed, "successes": len(task.good),
            "fit": [ids[i] for i in split.fit], "conformal": [ids[i] for i in split.conformal],
            **({"folds": [[ids[i] for i in fold] for fold in split.folds]} if split.folds else {}),
            **({"shape_folds": [[ids[i] for i in fold] for fold in split.shape_folds]} if split.shape_folds else {}),
            "behind_thresholds": {d: _behind(t) for d, t in thresholds.items()}}


def _behind(threshold: Threshold) -> dict[str, int]:
    """How many rollouts a threshold's shape and conformal quantile rest on."""
    params = threshold.params
    if "m2" in params:
        return {"shape": int(params["m1"]), "conformal": int(params["m2"])}
    return {"conformal": int(params["m"])}


def calibrate(
    rollouts: Sequence[Rollout],
    settings: CalibrationSettings | None = None,
    fk: ForwardKinematics | None = None,
    progress: ProgressCallback | None = None,
    refuse_infinite: bool = True,
) -> Calibration:
    """Fit every declared detector and the thresholds from calibration rollouts, per task, split as
    ``settings.split`` says (module docstring).

    Only rollouts with ``success is True`` are used, except that the ``"reference"`` profile takes ACE's ``R_d``
    over the failed rollouts too, as the authors' code does.

    Args:
        rollouts: Calibration rollouts (of one task, or of several: each task its own models and shapes).
        settings: Hyperparameters; defaults to :class:`CalibrationSettings`.
        fk: Forward kinematics for ACE on joint-space actions.
        progress: Called after every RND-OE training epoch (of the deployed model).
        refuse_infinite: Raise :class:`CalibrationError` for a threshold that is +inf (too few conformal
            rollouts for delta), naming the fewest successes that would do; False keeps it (the
            evaluation shows such cells instead of using them).
    """
    settings = settings or CalibrationSettings()
    rollouts = list(rollouts)
    if not successful(rollouts):
        raise CalibrationError(f"calibration needs at least {settings.min_rollouts} successful rollouts, got 0 "
                               f"(of {len(rollouts)} given)")
    layout = _check_layout(rollouts, settings)
    names = sorted({r.task for r in rollouts})
    tasks = [_task(name, [r for r in rollouts if r.task == name], settings, layout, fk, progress) for name in names]
    conformal = {task.name: task.conformal for task in tasks}
    shape = {task.name: task.shape for task in tasks}
    thresholds, joint = fit_thresholds(conformal, shape, settings)
    if refuse_infinite:
        _check_finite(thresholds, tasks, settings)
    estimate = false_alarm_estimate(conformal, shape, settings)
    parts = {task.name: TaskPart({d: DetectorPart(task.scorers[d], thresholds[task.name][d]) for d in settings.detectors},
                                 len(task.good), _record(task, thresholds[task.name], settings))
             for task in tasks}
    return Calibration(settings, layout, parts, joint, estimate)
