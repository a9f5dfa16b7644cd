"""PCA-kmeans (core/pca_kmeans.py): a score by hand, zero at a centroid, mean-centred PCA, seeded, step by step
equal to the whole rollout, save/load of numpy files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fiper_ros.core.pca_kmeans import PCAKMeans, PCAKMeansConfig, PCAKMeansError, kmeans
from fiper_ros.core.rollout import Rollout
from helpers.core_data import cluster_rollout


def rollout(embeddings: np.ndarray, success: bool | None = True) -> Rollout:
    return Rollout("r", "test", "id", np.asarray(embeddings, dtype=np.float64), None, 1, success)


def test_a_score_by_hand() -> None:
    # Two pairs on the x axis (y = 0; values exact in float32): centred on x = 5.25, clusters at 0.25 and 10.25.
    points = np.array([[0.0, 0], [0.5, 0], [10.0, 0], [10.5, 0]])
    model = PCAKMeans(PCAKMeansConfig(components=1, clusters=2)).fit([rollout(points), rollout([[50.0, 0]], False)])
    assert model.pca is not None and model.centroids is not None
    np.testing.assert_allclose(np.sort(np.abs(model.centroids[:, 0])), [5.0, 5.0], atol=1e-12)
    assert model.score_one(np.array([5.25, 0.0])) == pytest.approx(5.0, abs=1e-12)  # halfway: 5 from both
    assert model.score_one(np.array([0.25, 7.0])) == pytest.approx(0.0, abs=1e-12)  # y is no component
    assert model.score_one(np.array([-3.0, 0.0])) == pytest.approx(3.25, abs=1e-12)


def test_score_is_zero_at_a_centroid_and_grows_away_from_it() -> None:
    rng = np.random.default_rng(0)
    model = PCAKMeans(PCAKMeansConfig(components=2, clusters=8)).fit([cluster_rollout(rng, i, (1.0, 2.0))
                                                                      for i in range(5)])
    assert model.centroids is not None and model.pca is not None
    at_centroid = model.pca.mean + model.centroids @ model.pca.basis
    scores = model.score_embeddings(np.stack([at_centroid[0], at_centroid[0] + 5.0]))
    assert scores[0] < 1e-12
    assert scores[1] > 1.0


def test_pca_is_mean_centred() -> None:
    rng = np.random.default_rng(1)
    # Large offset along x, all the variance along y: centred PCA must pick y, not the mean direction x.
    points = np.column_stack([100.0 + 0.01 * rng.normal(size=200), rng.normal(size=200)])
    model = PCAKMeans(PCAKMeansConfig(components=1, clusters=4)).fit([rollout(points)])
    assert model.pca is not None
    assert abs(model.pca.basis[0, 1]) > 0.99
    np.testing.assert_allclose(model.pca.project(points).mean(), 0.0, atol=1e-8)


def test_kmeans_is_seeded_and_uses_fewer_centroids_for_few_samples() -> None:
    x = np.random.default_rng(2).normal(size=(40, 3))
    np.testing.assert_array_equal(kmeans(x, 5, seed=3), kmeans(x, 5, seed=3))
    assert kmeans(x[:3], 64, seed=0).shape[0] <= 3


def test_a_whole_rollout_is_scored_step_by_step() -> None:
    rng = np.random.default_rng(5)
    model = PCAKMeans(PCAKMeansConfig(components=2, clusters=4)).fit([cluster_rollout(rng, i, (0.0, 0.0))
                                                                      for i in range(3)])
    probe = cluster_rollout(rng, 9, (1.0, -1.0))
    whole = model.scores(probe)
    assert np.array_equal(whole, [model.score_one(x) for x in probe.embeddings])
    assert np.array_equal(whole, model.score_embeddings(probe.embeddings.astype(np.float64)))


def test_save_and_load_keep_the_scores(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    rollouts = [cluster_rollout(rng, i, (0.0, 0.0)) for i in range(3)]
    model = PCAKMeans(PCAKMeansConfig(components=2, clusters=4)).fit(rollouts, seed=1)
    model.save(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pca_kmeans.json", "pca_kmeans.npz"]
    loaded = PCAKMeans.load(tmp_path)
    assert loaded.digest() == model.digest() and loaded.config == model.config and loaded.seed == 1
    np.testing.assert_array_equal(loaded.scores(rollouts[0]), model.scores(rollouts[0]))
    assert PCAKMeans(PCAKMeansConfig(components=2, clusters=4)).fit(rollouts, seed=2).digest() != model.digest()
    with pytest.raises(PCAKMeansError, match="pca_kmeans model file missing"):
        PCAKMeans.load(tmp_path / "nowhere")


def test_bad_input_is_refused_in_one_line() -> None:
    with pytest.raises(PCAKMeansError, match="none given"):
        PCAKMeans().fit([rollout([[0.0, 1.0]], success=False)])
    with pytest.raises(PCAKMeansError, match="not fitted"):
        PCAKMeans().score_one(np.zeros(2))
    model = PCAKMeans(PCAKMeansConfig(components=1, clusters=2)).fit([rollout([[0.0, 0.0], [1.0, 1.0]])])
    with pytest.raises(PCAKMeansError, match=r"^embeddings must have shape \(2\) with no empty axis, got \(3,\)$"):
        model.score_one(np.zeros(3))
    with pytest.raises(PCAKMeansError, match="NaN/inf"):
        model.score_embeddings(np.array([[0.0, np.nan]]))
    with pytest.raises(PCAKMeansError, match="too large to score"):
        model.score_one(np.array([1.5e308, 1.5e308]))
