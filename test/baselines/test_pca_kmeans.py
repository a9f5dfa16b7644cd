"""PCA-kmeans: zero at a centroid, mean-centred PCA, seeded, save/load."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from baselines.conftest import cluster_rollout
from fiper_ros.baselines.pca_kmeans import PCAKMeans, PCAKMeansConfig, kmeans
from fiper_ros.core.rollout import Rollout


def test_score_is_zero_at_a_centroid_and_grows_away_from_it() -> None:
    rng = np.random.default_rng(0)
    model = PCAKMeans(PCAKMeansConfig(components=2, clusters=8)).fit([cluster_rollout(rng, i, (1.0, 2.0)) for i in range(5)])
    assert model.centroids is not None and model.components is not None and model.mean is not None
    at_centroid = model.mean + model.centroids @ model.components
    probe = Rollout("probe", "test", "id", np.stack([at_centroid[0], at_centroid[0] + 5.0]), np.zeros((2, 2, 8, 2)), 4, True)
    scores = model.scores(probe)
    assert scores[0] < 1e-6
    assert scores[1] > 1.0


def test_pca_is_mean_centred() -> None:
    rng = np.random.default_rng(1)
    # Large offset along x, all the variance along y: centred PCA must pick y, not the mean direction x.
    points = np.column_stack([100.0 + 0.01 * rng.normal(size=200), rng.normal(size=200)])
    rollout = Rollout("r", "test", "id", points, np.zeros((200, 2, 8, 2)), 4, True)
    model = PCAKMeans(PCAKMeansConfig(components=1, clusters=4)).fit([rollout])
    assert model.components is not None
    assert abs(model.components[0, 1]) > 0.99
    np.testing.assert_allclose(model.project(points).mean(), 0.0, atol=1e-8)


def test_kmeans_is_seeded_and_uses_fewer_centroids_for_few_samples() -> None:
    x = np.random.default_rng(2).normal(size=(40, 3))
    np.testing.assert_array_equal(kmeans(x, 5, seed=3), kmeans(x, 5, seed=3))
    assert kmeans(x[:3], 64, seed=0).shape[0] <= 3


def test_save_and_load_keep_the_scores(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    rollouts = [cluster_rollout(rng, i, (0.0, 0.0)) for i in range(3)]
    model = PCAKMeans(PCAKMeansConfig(components=2, clusters=4)).fit(rollouts, seed=1)
    model.save(tmp_path)
    np.testing.assert_array_equal(PCAKMeans.load(tmp_path).scores(rollouts[0]), model.scores(rollouts[0]))
