"""``--auto``: the scores the choice rests on (fold models of the fit part, failure proxies) and the calibration of
the chosen configuration.

:func:`auto_scores` scores one task's fit-part successes and the proxies made from them
(:func:`fiper_ros.core.auto.make_proxy`) with models fitted on the other folds of the fit part (the folds the
final calibration's cross-fitted shapes use, ``shape_folds``); :func:`choose_configuration` applies the rule of
:mod:`fiper_ros.core.auto` to them; :func:`auto_calibrate` calibrates the chosen configuration and stores the
choice in the calibration (``auto``). Only rollouts with ``success is True`` are read, and only those of the fit
part: the conformal part is left to the final thresholds. The ``transfer`` rule scores nothing: it reads what
detectors the successes can feed and how many conformal successes each task has (:func:`transfer_choice`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from fiper_ros.core.auto import (DEFAULT_PROMISE, PROXY_TWA, TRANSFER, AutoChoice, AutoError, AutoSettings,
                                 EmbeddingSpread, TaskScores, choose, make_proxy, stall_length)
from fiper_ros.core.calibration.fit import calibrate, conformal_count, split_successes
from fiper_ros.core.calibration.model import Calibration
from fiper_ros.core.calibration.settings import CalibrationSettings
from fiper_ros.core.detectors import (ACE, CONSISTENCY, ELAPSED, LOGPZO, PCA_KMEANS, PROGRESS, RND_OE, info,
                                      signal_stream)
from fiper_ros.core.kinematics import ForwardKinematics
from fiper_ros.core.rnd_oe import ProgressCallback
from fiper_ros.core.rollout import Rollout
from fiper_ros.core.scorers import FitContext, fit_scorer
from fiper_ros.core.thresholds import minimum_conformal_set
from fiper_ros.core.transfer import Prior, PriorEntry, TransferChoice, choose_from_prior, threshold_delta

#: Called with a short note as the fold models are fitted (progress of a long run).
Note = Callable[[str], None]
#: The embedding detectors every rollout can feed.
EMBEDDING_DETECTORS = (RND_OE, LOGPZO, PCA_KMEANS, PROGRESS)


def available_detectors(successes: Sequence[Rollout]) -> tuple[str, ...]:
    """The detectors the successes can feed: the embedding ones, ACE and action consistency where every success has
    action batches, every signal every success logged, and the elapsed time."""
    out = list(EMBEDDING_DETECTORS)
    if successes and all(r.has_actions for r in successes):
        out += [ACE, CONSISTENCY]
    common = set.intersection(*(set(r.signals) for r in successes)) if successes else set()
    return (*out, *(signal_stream(s) for s in sorted(common)), ELAPSED)


def auto_scores(good: Sequence[Rollout], members: Sequence[int], folds: Sequence[Sequence[int]],
                detectors: Sequence[str], context: FitContext, fk: ForwardKinematics | None, settings: AutoSettings,
                seed: int, note: Note | None = None) -> TaskScores:
    """Per detector, the scores of ``good[i]`` for every ``i`` of ``members`` (in that order) and of the proxies
    made from them (none for a rule that reads no proxy), each fold's by the models fitted on the other members (the
    fitted ones; the others fit nothing)."""
    position = {index: n for n, index in enumerate(members)}
    successes: dict[str, list[np.ndarray]] = {d: [np.empty(0)] * len(members) for d in detectors}
    proxies: dict[str, list[np.ndarray]] = {d: [] for d in detectors}
    kinds: list[str] = []
    sources: list[int] = []
    stall = stall_length([good[i] for i in members], settings)
    made_kinds = settings.proxies if settings.rule == PROXY_TWA else ()
    for number, fold in enumerate(folds, 1):
        train = [good[i] for i in members if i not in fold]
        scorers = {}
        for d in detectors:
            if note is not None and info(d).fitted:
                note(f"fold {number}/{len(folds)}: fitting {info(d).label} on {len(train)} successes")
            scorers[d] = fit_scorer(d, train, context)
        spread = EmbeddingSpread.of(train)
        for i in fold:
            rng = np.random.default_rng([seed, 37, i])
            made = [make_proxy(good[i], kind, rng, spread, stall, settings.drift_scale) for kind in made_kinds]
            for d, scorer in scorers.items():
                successes[d][position[i]] = scorer.scores(good[i], fk)
                proxies[d].extend(scorer.scores(p, fk) for p in made)
            kinds.extend(made_kinds)
            sources.extend([position[i]] * len(made))
    return TaskScores(successes, proxies, tuple(kinds), tuple(sources))


def auto_split_settings(settings: CalibrationSettings, auto: AutoSettings) -> CalibrationSettings:
    """``settings`` with the fit part's folds of ``auto`` (its ``shape_folds``); :class:`AutoError` for a split that
    has no fit part."""
    if settings.split != "split":
        raise AutoError(f"--auto chooses on the fit part of a split conformal calibration (--split split), not "
                        f"--split {settings.split}")
    return replace(settings, shape_folds=auto.folds)


def _successes_by_task(rollouts: Sequence[Rollout], settings: CalibrationSettings) -> dict[str, list[Rollout]]:
    """Per task (sorted by name) its ``success is True`` rollouts, at least ``min_rollouts`` of each
    (:class:`AutoError`); of any other rollout only the flag is read."""
    good_ones = [r for r in rollouts if r.success is True]
    tasks = {name: [r for r in good_ones if r.task == name] for name in sorted({r.task for r in good_ones})}
    for name, good in tasks.items():
        if len(good) < settings.min_rollouts:
            raise AutoError(f"--auto needs at least {settings.min_rollouts} successful rollouts of task {name!r}, got "
                            f"{len(good)}")
    return tasks


def finite_at_delta(entry: PriorEntry, conformal_successes: Sequence[int], settings: CalibrationSettings,
                    promise: str = DEFAULT_PROMISE) -> bool:
    """Whether ``entry``'s threshold is finite at ``settings.delta`` under ``promise`` (its thresholds at
    :func:`~fiper_ros.core.transfer.threshold_delta`) on every task whose number of successes is in
    ``conformal_successes`` (the conformal part of each task's split gets :func:`conformal_count` of them; the
    conformal quantile is finite with at least :func:`minimum_conformal_set` scores; a plain quantile always is).
    Thresholds pooled over the tasks (``settings.pooled``) take one quantile of every task's conformal scores: the
    sum must reach it."""
    chosen = replace(settings, **entry.settings(), delta=threshold_delta(entry, settings.delta, promise))
    if not chosen.profile_obj.conformal:
        return True
    need = minimum_conformal_set(chosen.delta)
    counts = [conformal_count(n, chosen.split, chosen) for n in conformal_successes]
    return sum(counts) >= need if chosen.pooled else all(count >= need for count in counts)


def transfer_choice(rollouts: Sequence[Rollout], settings: CalibrationSettings, auto: AutoSettings, prior: Prior,
                    detectors: Sequence[str] | None = None) -> TransferChoice:
    """The ``transfer`` rule's choice (:func:`fiper_ros.core.transfer.choose_from_prior`) for the successes of
    ``rollouts``: the best entry of ``prior`` among ``detectors`` (default: every one they can feed,
    :func:`available_detectors`) whose threshold is finite at ``settings.delta`` on every task
    (:func:`finite_at_delta`). Of the successes only their streams and number are read."""
    split_settings = auto_split_settings(settings, auto)
    tasks = _successes_by_task(rollouts, settings)
    if not tasks:
        raise AutoError("auto needs the successes of at least one task")
    good_ones = [r for good in tasks.values() for r in good]
    pool = tuple(detectors) if detectors is not None else available_detectors(good_ones)
    counts = [len(good) for good in tasks.values()]
    return choose_from_prior(prior, pool, lambda entry: finite_at_delta(entry, counts, split_settings, auto.promise),
                             auto, settings.delta)


def choose_configuration(rollouts: Sequence[Rollout], settings: CalibrationSettings, auto: AutoSettings,
                         detectors: Sequence[str] | None = None, fk: ForwardKinematics | None = None,
                         note: Note | None = None, prior: Prior | None = None) -> AutoChoice | TransferChoice:
    """The rule's choice (:func:`fiper_ros.core.auto.choose`) on the successes of ``rollouts`` (every task's fit part,
    split as ``settings`` with ``auto.folds`` shape folds), among ``detectors`` (default: every one they can feed,
    :func:`available_detectors`); the ``transfer`` rule's (:func:`transfer_choice`) from ``prior``, which it needs.
    Nothing but ``success is True`` rollouts is read."""
    if auto.rule == TRANSFER:
        if prior is None:
            raise AutoError("the transfer rule needs a prior (--auto-prior FILE)")
        return transfer_choice(rollouts, settings, auto, prior, detectors)
    split_settings = auto_split_settings(settings, auto)
    tasks = _successes_by_task(rollouts, settings)
    good_ones = [r for good in tasks.values() for r in good]
    pool = tuple(detectors) if detectors is not None else available_detectors(good_ones)
    context = FitContext(settings.seed, settings.profile_obj, settings.options(), "ee_position", fk)
    scores = {}
    for name, good in tasks.items():
        split = split_successes(len(good), split_settings)
        own = replace(context, action_space=good[0].action_space)
        scores[name] = auto_scores(good, split.fit, split.shape_folds, pool, own, fk, auto, settings.seed, note)
    return choose(scores, pool, auto, settings.threshold_settings(), settings.seed)


def transfer_settings(settings: CalibrationSettings, choice: TransferChoice) -> CalibrationSettings:
    """``settings`` with the transfer rule's chosen entry, its thresholds at the delta the choice's promise gives
    them (:attr:`~fiper_ros.core.transfer.TransferChoice.threshold_delta`)."""
    return replace(settings, **choice.chosen.settings(), delta=choice.threshold_delta)


def chosen_settings(settings: CalibrationSettings, choice: AutoChoice | TransferChoice) -> CalibrationSettings:
    """``settings`` with the chosen configuration (a transfer choice's thresholds at its
    :func:`transfer_settings` delta), its shapes cross-fitted in the rule's folds."""
    chosen = transfer_settings(settings, choice) if isinstance(choice, TransferChoice) else \
        replace(settings, **choice.chosen.settings())
    return replace(chosen, shape_folds=choice.settings.folds)


def auto_calibrate(rollouts: Sequence[Rollout], settings: CalibrationSettings, auto: AutoSettings,
                   detectors: Sequence[str] | None = None, fk: ForwardKinematics | None = None,
                   progress: ProgressCallback | None = None, note: Note | None = None, prior: Prior | None = None
                   ) -> tuple[Calibration, AutoChoice | TransferChoice]:
    """Choose the configuration (:func:`choose_configuration`; the ``transfer`` rule from ``prior``), calibrate it
    (:func:`calibrate`) and store the choice in the calibration's ``auto`` record."""
    choice = choose_configuration(rollouts, settings, auto, detectors, fk, note, prior)
    calibration = calibrate(rollouts, chosen_settings(settings, choice), fk=fk, progress=progress)
    calibration.auto = choice.record()
    return calibration, choice
