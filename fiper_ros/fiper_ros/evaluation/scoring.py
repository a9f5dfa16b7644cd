"""Per-step scores of every stream of a dataset, computed once per (dataset, settings, split, seed) and cached.

RND-OE and ACE come from :func:`fiper_ros.core.calibration.calibrate` and
:mod:`fiper_ros.core.scores` (the functions :func:`fiper_ros.core.monitor.predict_rollout` uses), so
the evaluation sees exactly the numbers of the runtime monitor. Every learned quantity a threshold
depends on (RND-OE, ``R_d``, the baselines' models) is fitted on the successes the calibration split
gives it (:func:`fiper_ros.core.calibration.split_successes`, the same split for every stream of a task
and seed):

- ``"split"``: fitted on the fit part; every calibration success and test rollout scored by that model;
- ``"cross"``: each fold of the successes scored by a model fitted on the other folds, the test rollouts
  by a model fitted on all successes (the deployed one);
- ``"same"``: fitted on all successes, which are then scored by it (the paper's Remark 1).

Scores are kept for the successful calibration rollouts (:class:`fiper_ros.evaluation.cache.RolloutScores`;
:class:`fiper_ros.evaluation.cache.StreamScores` separates them into the fit and the conformal part) and
for all test rollouts. Every per-step score gets the profile's ``score_epsilon`` (0 in the paper profile;
the authors' code adds 1e-6 to every score, baselines included); the elapsed-time stream is exactly 1, a logged
signal its magnitude, and a user's external scores (:mod:`fiper_ros.evaluation.external`) are taken as given.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import replace

import numpy as np
import torch

from fiper_ros.baselines.base import Baseline, BaselineError
from fiper_ros.baselines.rnd_a import RNDA
from fiper_ros.baselines.stac import STAC, check_overlap
from fiper_ros.core.calibration import CalibrationError, CalibrationSplit, split_successes
from fiper_ros.core.detectors import ACE, CONSISTENCY, SIGNAL_PREFIX, info
from fiper_ros.core.kinematics import RobotModel
from fiper_ros.core.profiles import get_profile
from fiper_ros.core.rollout import Rollout
from fiper_ros.core.scorers import FitContext, fit_scorer
from fiper_ros.evaluation.cache import RolloutScores, ScoreCache, StreamScores, cache_key, code_version
from fiper_ros.evaluation.data import Dataset, DatasetError
from fiper_ros.evaluation.methods import MethodSettings, fitted

LOG = logging.getLogger(__name__)


@contextmanager
def torch_threads(count: int) -> Iterator[None]:
    """Run torch with ``count`` intra-op threads (1 avoids oversubscription on a shared 2-core machine)."""
    previous = torch.get_num_threads()
    torch.set_num_threads(count)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


#: The evaluation's own baselines: streams no calibration declares (the others are the core's detectors).
BASELINES = ("stac", "rnd_a")


def _baseline(stream: str, settings: MethodSettings) -> Baseline:
    if stream == "stac":
        return STAC()
    if stream == "rnd_a":
        return RNDA(settings.rnd_a)
    raise ValueError(f"{stream!r} is not a baseline stream")


Scorer = Callable[[Rollout], np.ndarray]
#: Fits score models on some successful calibration rollouts; returns the scorer of every stream it serves.
Fitter = Callable[[Sequence[Rollout]], dict[str, Scorer]]


def robot_for(dataset: Dataset, settings: MethodSettings) -> RobotModel | None:
    """The robot model ACE needs for ``dataset``: ``None`` for end-effector actions; for joint-space
    actions ``settings.robot``, else :class:`DatasetError`."""
    if dataset.action_space == "ee_position":
        return None
    if settings.robot is None:
        raise DatasetError(f"task {dataset.task!r} has {dataset.action_space} actions: ACE needs the robot's "
                           "URDF and EE frame (and the control period for velocities)")
    return settings.robot


def check_streams(dataset: Dataset, streams: Sequence[str]) -> None:
    """Refuse a dataset a stream cannot score, before any work: STAC and action consistency on chunks without an
    overlap (``h = H``), a logged signal a rollout lacks."""
    overlapping = [s for s in ("stac", CONSISTENCY) if s in streams]
    signals = [s.removeprefix(SIGNAL_PREFIX) for s in streams if info(s).reads == "signal"]
    for rollout in (*dataset.calibration, *dataset.test):
        where = f"task {dataset.task!r}, rollout {rollout.rollout_id!r}"
        for stream in overlapping:
            try:
                check_overlap(rollout.exec_steps, rollout.actions.shape[2])
            except BaselineError as error:
                raise DatasetError(f"{where}: {error} (leave {info(stream).label} out: --methods without "
                                   f"{stream})") from error
        missing = [name for name in signals if name not in rollout.signals] if signals else []
        if missing:
            raise DatasetError(f"{where}: no logged signal {', '.join(missing)} (it has "
                               f"{', '.join(sorted(rollout.signals)) or 'none'})")


def check_dataset(dataset: Dataset, settings: MethodSettings, streams: Sequence[str]) -> None:
    """Everything the scores of ``dataset`` would stop on, checked before any work (:class:`DatasetError`):
    the robot model of joint-space actions, the calibration split, what the streams need."""
    robot_for(dataset, settings)
    check_split(dataset, settings)
    check_streams(dataset, streams)


def calibration_split(dataset: Dataset, settings: MethodSettings, seed: int) -> CalibrationSplit:
    """The split of ``dataset``'s calibration successes for ``seed``: the core's, shared by every stream."""
    try:
        return split_successes(len(dataset.calibration_successes), settings.calibration_settings(seed))
    except CalibrationError as error:
        raise DatasetError(f"task {dataset.task!r}: {error}") from error


def check_split(dataset: Dataset, settings: MethodSettings) -> None:
    """Refuse a dataset whose split leaves a score model fewer successes than the core calibration needs."""
    split = calibration_split(dataset, settings, 0)
    count = len(dataset.calibration_successes)
    need = settings.calibration_settings(0).min_rollouts
    fitted = ([count - len(fold) for fold in split.folds] if split.mode == "cross" else [len(split.fit)])
    if min(fitted) < need:
        raise DatasetError(f"task {dataset.task!r}: the {split.mode} calibration split fits the score models on "
                           f"{min(fitted)} of {count} successes, fewer than the {need} they need (more "
                           "calibration successes, or --split same)")


def detector_fitter(stream: str, dataset: Dataset, settings: MethodSettings, seed: int) -> Fitter:
    """A detector a calibration can declare (:data:`fiper_ros.core.detectors.CALIBRATED`, a logged signal) fitted on
    the successes given exactly as :func:`fiper_ros.core.calibration.calibrate` fits it (:func:`fit_scorer`: the
    profile's epsilon, ACE's ranges over the calibration failures too where the profile takes them); its
    whole-rollout scores."""
    robot = robot_for(dataset, settings) if stream == ACE else None
    fk = None if robot is None else robot.forward_kinematics()
    profile = get_profile(settings.profile)
    failed = [r for r in dataset.calibration if r.success is not True] if profile.ranges_from_all else []
    context = FitContext(seed, profile, settings.detector_options(robot), dataset.action_space, fk, failed)

    def fit(successes: Sequence[Rollout]) -> dict[str, Scorer]:
        scorer = fit_scorer(stream, successes, context)
        return {stream: lambda rollout: scorer.scores(rollout, fk)}

    return fit


def baseline_fitter(stream: str, settings: MethodSettings, seed: int) -> Fitter:
    """An evaluation baseline a calibration cannot declare (STAC, RND-A) fitted on the successes given; its scores
    get the profile's epsilon."""
    epsilon = get_profile(settings.profile).score_epsilon

    def fit(successes: Sequence[Rollout]) -> dict[str, Scorer]:
        baseline = _baseline(stream, settings).fit(successes, seed)
        return {stream: lambda rollout: np.asarray(baseline.scores(rollout), dtype=np.float64) + epsilon}

    return fit


def external_fitter(stream: str, settings: MethodSettings) -> Fitter:
    """Scores computed elsewhere (``--scores NAME=FILE``), used as given: nothing is fitted, the successes given are
    ignored (the file was checked against the data by :func:`fiper_ros.evaluation.external.check_covers`)."""
    given = settings.external_scores(stream).scores
    return lambda successes: {stream: lambda rollout: given[rollout.rollout_id]}


def _out_of_fold(fit: Fitter, good: Sequence[Rollout], members: Sequence[int], folds: Sequence[Sequence[int]]
                 ) -> dict[int, dict[str, np.ndarray]]:
    """Scores of ``good[i]`` for every ``i`` of the folds, each by the models fitted on the other members."""
    out: dict[int, dict[str, np.ndarray]] = {}
    for fold in folds:
        scorers = fit([good[i] for i in members if i not in fold])
        for i in fold:
            out[i] = {name: score(good[i]) for name, score in scorers.items()}
    return out


def split_scores(fit: Fitter, dataset: Dataset, split: CalibrationSplit, fitted: bool = True
                 ) -> dict[str, RolloutScores]:
    """Scores of the calibration successes and the test rollouts with models fitted as ``split`` says
    (see the module docstring), for every stream ``fit`` serves; with shape folds (and a ``fitted`` stream:
    one that learns from the successes) also the fit part's cross-fitted shape curves."""
    good = dataset.calibration_successes
    shape: dict[int, dict[str, np.ndarray]] | None = None
    if split.mode == "cross":
        folded = _out_of_fold(fit, good, range(len(good)), split.folds)
        calibration = [folded[i] for i in range(len(good))]
        deployed = fit(good)
    else:
        deployed = fit([good[i] for i in split.fit])
        calibration = [{name: score(r) for name, score in deployed.items()} for r in good]
        if split.shape_folds and fitted:
            shape = _out_of_fold(fit, good, split.fit, split.shape_folds)
    return {name: RolloutScores([np.asarray(c[name], dtype=np.float64) for c in calibration],
                                [np.asarray(score(r), dtype=np.float64) for r in dataset.test],
                                None if shape is None else [np.asarray(shape[i][name], dtype=np.float64)
                                                            for i in split.fit])
            for name, score in deployed.items()}


def stream_keys(dataset: Dataset, streams: Sequence[str], settings: MethodSettings, seed: int) -> dict[str, str]:
    """The score cache's key of every stream of ``dataset`` and ``seed``."""
    data_digest, version = dataset.digest(), code_version()
    joint_space = dataset.action_space != "ee_position"
    return {s: cache_key(data_digest, s, settings.stream_settings(s, joint_space), settings.stream_seed(s, seed),
                         version)
            for s in streams}


def cached_streams(dataset: Dataset, streams: Sequence[str], settings: MethodSettings, seed: int,
                   cache: ScoreCache | None) -> tuple[dict[str, str], dict[str, RolloutScores]]:
    """The cache key of every stream of ``dataset`` and ``seed`` (empty without a cache) and the scores the cache
    holds."""
    if cache is None:
        return {}, {}
    keys = stream_keys(dataset, streams, settings, seed)
    found = {s: cache.get(keys[s]) for s in streams}
    return keys, {s: scores for s, scores in found.items() if scores is not None}


def score_stream(dataset: Dataset, stream: str, settings: MethodSettings, seed: int, threads: int = 1
                 ) -> tuple[RolloutScores, float]:
    """One stream's scores of ``dataset`` for ``seed``, computed (no cache) with models fitted as the split of
    ``seed`` says (:func:`calibration_split`); returns them and the seconds spent.

    Raises:
        DatasetError: The split or the stream cannot serve ``dataset``.
    """
    split = calibration_split(dataset, settings, seed)
    start = time.perf_counter()
    with torch_threads(threads):
        # Nothing is fitted for an unfitted stream: every split scores it alike, so it is scored once.
        own = split if fitted(stream) else calibration_split(
            dataset, replace(settings, split="same", shape_folds=0), seed)
        fitter = (baseline_fitter(stream, settings, seed) if stream in BASELINES
                  else external_fitter(stream, settings) if info(stream).reads == "external"
                  else detector_fitter(stream, dataset, settings, seed))
        scores = split_scores(fitter, dataset, own, fitted(stream))[stream]
    seconds = time.perf_counter() - start
    LOG.info("%s %s seed %d (%s split): scores in %.1f s", dataset.task, stream, seed, split.mode, seconds)
    return scores, seconds


def separated_streams(dataset: Dataset, streams: Sequence[str], settings: MethodSettings, seed: int,
                      raw: dict[str, RolloutScores], computed: dict[str, str], cache: ScoreCache | None
                      ) -> dict[str, StreamScores]:
    """``raw`` scores of ``streams`` separated by the split of ``seed``, in the order of ``streams``, after the
    ``computed`` ones (stream -> cache key) went into ``cache``."""
    if cache is not None:
        for stream, key in computed.items():
            cache.put(key, raw[stream])
    split = calibration_split(dataset, settings, seed)
    return {s: StreamScores.of(raw[s], split) for s in streams}


def compute_streams(
    dataset: Dataset,
    streams: list[str],
    settings: MethodSettings,
    seed: int,
    cache: ScoreCache | None = None,
    threads: int = 1,
) -> tuple[dict[str, StreamScores], dict[str, float]]:
    """Scores of ``streams`` for one dataset and seed, from the cache where possible (:func:`cached_streams`), else
    computed (:func:`score_stream`), separated by the split of ``seed`` (:func:`separated_streams`).

    Returns the scores and the seconds spent computing each stream (0 for cache hits).
    """
    calibration_split(dataset, settings, seed)  # a split that cannot be drawn stops before the cache is read
    keys, raw = cached_streams(dataset, streams, settings, seed, cache)
    seconds = dict.fromkeys(raw, 0.0)
    missing = [s for s in streams if s not in raw]
    for stream in missing:
        raw[stream], seconds[stream] = score_stream(dataset, stream, settings, seed, threads)
    computed = {s: keys[s] for s in missing if keys}
    return separated_streams(dataset, streams, settings, seed, raw, computed, cache), seconds
