"""Every learned score is fitted on the successes the calibration split gives it, the same split for all."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fiper_ros.core.calibration import split_successes
from fiper_ros.core.logpzo import LogpZO
from fiper_ros.core.pca_kmeans import PCAKMeans
from fiper_ros.evaluation.data import Dataset, DatasetError
from fiper_ros.evaluation.methods import MethodSettings
from fiper_ros.evaluation.scoring import calibration_split, check_split, compute_streams, torch_threads

SEED = 1


def test_split_baselines_are_fitted_on_the_fit_part_only(tiny_dataset: Dataset, tiny_settings: MethodSettings) -> None:
    good = tiny_dataset.calibration_successes
    split = calibration_split(tiny_dataset, tiny_settings, SEED)
    assert split == split_successes(len(good), tiny_settings.calibration_settings(SEED))  # the core's split
    assert not set(split.fit) & set(split.conformal) and len(split.fit) + len(split.conformal) == len(good)
    streams, _ = compute_streams(tiny_dataset, ["pca_kmeans", "logpzo"], tiny_settings, SEED)
    fit = [good[i] for i in split.fit]
    with torch_threads(1):  # as compute_streams: another thread count changes torch's float sums
        for name, model in (("pca_kmeans", PCAKMeans(tiny_settings.pca_kmeans).fit(fit, SEED)),
                            ("logpzo", LogpZO(tiny_settings.logpzo).fit(fit, SEED))):
            scores = streams[name]
            assert scores.fit is not None
            for got, rollout in zip(scores.fit, fit):
                np.testing.assert_array_equal(got, model.scores(rollout))
            for got, i in zip(scores.conformal, split.conformal):
                np.testing.assert_array_equal(got, model.scores(good[i]))
            for got, rollout in zip(scores.test, tiny_dataset.test):
                np.testing.assert_array_equal(got, model.scores(rollout))
    everything = PCAKMeans(tiny_settings.pca_kmeans).fit(good, SEED)
    assert not np.array_equal(streams["pca_kmeans"].conformal[0], everything.scores(good[split.conformal[0]]))


def test_cross_scores_each_fold_with_a_model_that_did_not_see_it(tiny_dataset: Dataset,
                                                                  tiny_settings: MethodSettings) -> None:
    settings = replace(tiny_settings, split="cross")
    good = tiny_dataset.calibration_successes
    split = calibration_split(tiny_dataset, settings, SEED)
    assert len(split.folds) == 5 and sorted(i for fold in split.folds for i in fold) == list(range(len(good)))
    streams, _ = compute_streams(tiny_dataset, ["pca_kmeans"], settings, SEED)
    scores = streams["pca_kmeans"]
    assert scores.fit is None and len(scores.conformal) == len(good)  # the CP band splits I1 off these
    for fold in split.folds:
        model = PCAKMeans(settings.pca_kmeans).fit([good[i] for i in range(len(good)) if i not in fold], SEED)
        for i in fold:
            np.testing.assert_array_equal(scores.conformal[i], model.scores(good[i]))
    deployed = PCAKMeans(settings.pca_kmeans).fit(good, SEED)
    np.testing.assert_array_equal(scores.test[0], deployed.scores(tiny_dataset.test[0]))


def test_a_split_that_leaves_the_models_too_few_successes_is_refused(tiny_dataset: Dataset,
                                                                     tiny_settings: MethodSettings) -> None:
    few = Dataset("few", tiny_dataset.calibration_successes[:7], tiny_dataset.test)
    with pytest.raises(DatasetError, match=r"task 'few': the split calibration split fits the score models on 3 "
                                           r"of 7 successes, fewer than the 4 they need"):
        check_split(few, tiny_settings)
    check_split(few, replace(tiny_settings, split="same"))
    with pytest.raises(DatasetError, match="5-fold cross-fitting needs at least 5 successes, got 4"):
        check_split(Dataset("four", few.calibration[:4], few.test), replace(tiny_settings, split="cross"))
