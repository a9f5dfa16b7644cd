"""Per-step scores of every stream of a dataset, computed once per (dataset, settings, seed) and cached.

RND-OE and ACE come from :func:`fiper_ros.core.calibration.calibrate` and
:mod:`fiper_ros.core.scores` (the functions :func:`fiper_ros.core.monitor.predict_rollout` uses), so
the evaluation sees exactly the numbers of the runtime monitor. The baselines are fitted on the
successful calibration rollouts. Scores are kept for the successful calibration rollouts (to fit the
thresholds on) and for all test rollouts. Every per-step score gets the profile's ``score_epsilon``
(0 in the paper profile; the authors' code adds 1e-6 to every score, baselines included).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np
import torch

from fiper_ros.baselines.base import Baseline
from fiper_ros.baselines.logpzo import LogpZO
from fiper_ros.baselines.pca_kmeans import PCAKMeans
from fiper_ros.baselines.rnd_a import RNDA
from fiper_ros.baselines.stac import STAC
from fiper_ros.core.calibration import CalibrationSettings, calibrate
from fiper_ros.core.compat import get_profile
from fiper_ros.core.kinematics import RobotModel
from fiper_ros.core.rollout import Rollout
from fiper_ros.core.scores import act_scores, obs_scores, rollout_positions
from fiper_ros.evaluation.cache import ScoreCache, StreamScores, cache_key, code_version
from fiper_ros.evaluation.data import Dataset, DatasetError
from fiper_ros.evaluation.methods import SEEDLESS_STREAMS, MethodSettings

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


def _baseline(stream: str, settings: MethodSettings) -> Baseline:
    if stream == "stac":
        return STAC()
    if stream == "pca_kmeans":
        return PCAKMeans(settings.pca_kmeans)
    if stream == "logpzo":
        return LogpZO(settings.logpzo)
    if stream == "rnd_a":
        return RNDA(settings.rnd_a)
    raise ValueError(f"{stream!r} is not a baseline stream")


def _apply(score: Callable[[Rollout], np.ndarray], dataset: Dataset, epsilon: float) -> StreamScores:
    calibration = [np.asarray(score(r), dtype=np.float64) + epsilon for r in dataset.calibration_successes]
    return StreamScores(calibration, [np.asarray(score(r), dtype=np.float64) + epsilon for r in dataset.test])


def robot_for(dataset: Dataset, settings: MethodSettings) -> RobotModel | None:
    """The robot model ACE needs for ``dataset``: ``None`` for end-effector actions; for joint-space
    actions ``settings.robot``, else :class:`DatasetError`."""
    if dataset.action_space == "ee_position":
        return None
    if settings.robot is None:
        raise DatasetError(f"task {dataset.task!r} has {dataset.action_space} actions: ACE needs the robot's "
                           "URDF and EE frame (and the control period for velocities)")
    return settings.robot


def fiper_streams(dataset: Dataset, settings: MethodSettings, seed: int) -> dict[str, StreamScores]:
    """RND-OE and ACE scores through the core calibration (``core.scores``; epsilon included there)."""
    robot = robot_for(dataset, settings)
    calibration_settings = CalibrationSettings(alpha=settings.alpha, rnd=settings.rnd, seed=seed,
                                               profile=settings.profile, split="same",
                                               control_dt=None if robot is None else robot.control_dt)
    fk = None if robot is None else robot.forward_kinematics()
    calibration = calibrate(dataset.calibration, calibration_settings, fk=fk, refuse_infinite=False)
    projection = calibration.projection(fk)
    profile = calibration.profile

    def ace(rollout: Rollout) -> np.ndarray:
        return act_scores(rollout_positions(rollout, projection), calibration.cell, profile)

    def rnd(rollout: Rollout) -> np.ndarray:
        return obs_scores(calibration.rnd, rollout.embeddings, profile)

    return {"rnd_oe": _apply(rnd, dataset, 0.0), "ace": _apply(ace, dataset, 0.0)}  # epsilon added by core


def baseline_stream(stream: str, dataset: Dataset, settings: MethodSettings, seed: int) -> StreamScores:
    """Fit a baseline on the calibration successes and score every kept rollout."""
    baseline = _baseline(stream, settings).fit(dataset.calibration, seed)
    return _apply(baseline.scores, dataset, get_profile(settings.profile).score_epsilon)


def compute_streams(
    dataset: Dataset,
    streams: list[str],
    settings: MethodSettings,
    seed: int,
    cache: ScoreCache | None = None,
    threads: int = 1,
) -> tuple[dict[str, StreamScores], dict[str, float]]:
    """Scores of ``streams`` for one dataset and seed, from the cache where possible.

    Returns the scores and the seconds spent computing each stream (0 for cache hits).
    """
    data_digest = dataset.digest() if cache is not None else ""
    version = code_version() if cache is not None else ""
    joint_space = dataset.action_space != "ee_position"
    keys = {s: cache_key(data_digest, s, settings.stream_settings(s, joint_space),
                         None if s in SEEDLESS_STREAMS else seed, version)
            for s in streams}
    out: dict[str, StreamScores] = {}
    seconds: dict[str, float] = {}
    for stream in streams:
        cached = cache.get(keys[stream]) if cache is not None else None
        if cached is not None:
            out[stream], seconds[stream] = cached, 0.0
    missing = [s for s in streams if s not in out]
    with torch_threads(threads):
        if any(s in ("rnd_oe", "ace") for s in missing):
            start = time.perf_counter()
            both = fiper_streams(dataset, settings, seed)
            elapsed = time.perf_counter() - start
            for stream in ("rnd_oe", "ace"):
                if stream in missing:
                    out[stream], seconds[stream] = both[stream], elapsed / 2.0
        for stream in missing:
            if stream not in out:
                start = time.perf_counter()
                out[stream] = baseline_stream(stream, dataset, settings, seed)
                seconds[stream] = time.perf_counter() - start
    if cache is not None:
        for stream in missing:
            cache.put(keys[stream], out[stream])
    for stream in missing:
        LOG.info("%s %s seed %d: scores in %.1f s", dataset.task, stream, seed, seconds[stream])
    return {s: out[s] for s in streams}, seconds
