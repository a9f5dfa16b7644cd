"""RND-OE, eq. (1) and App. A.2."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from helpers.core_data import TINY_RND

from fiper_ros.core.rnd_oe import RNDOE, RNDConfig, RNDError, TrainProgress

Clusters = tuple[np.ndarray, np.ndarray, np.ndarray]


@pytest.fixture(scope="module")
def clusters() -> Clusters:
    rng = np.random.default_rng(0)
    centers = rng.normal(size=(4, 32))
    train = centers[rng.integers(0, 4, 800)] + 0.2 * rng.normal(size=(800, 32))
    held_out = centers[rng.integers(0, 4, 200)] + 0.2 * rng.normal(size=(200, 32))
    off = rng.normal(size=(200, 32)) + 2.0
    return train.astype(np.float32), held_out.astype(np.float32), off.astype(np.float32)


@pytest.fixture(scope="module")
def model(clusters: Clusters) -> RNDOE:
    return RNDOE.fit(clusters[0], TINY_RND, seed=3)


def test_separates_an_off_distribution_cluster(model: RNDOE, clusters: Clusters) -> None:
    _, held_out, off = clusters
    assert np.min(model.score(off)) > np.max(model.score(held_out))


def test_training_lowers_the_id_score(clusters: Clusters, model: RNDOE) -> None:
    untrained = RNDOE(32, TINY_RND, seed=3)
    assert np.mean(model.score(clusters[1])) < 0.5 * np.mean(untrained.score(clusters[1]))


def test_deterministic_per_seed(clusters: Clusters, model: RNDOE) -> None:
    progress: list[TrainProgress] = []
    again = RNDOE.fit(clusters[0], TINY_RND, seed=3, progress=progress.append)
    assert again.digest() == model.digest()
    assert progress and progress[-1].epoch == len(progress)
    assert RNDOE(32, TINY_RND, seed=4).digest() != RNDOE(32, TINY_RND, seed=3).digest()


def test_numpy_and_torch_paths_agree(model: RNDOE, clusters: Clusters) -> None:
    batch = np.concatenate([clusters[1][:20], clusters[2][:20]])
    torch_scores = model.score(batch)
    numpy_scores = np.array([model.score_one(x) for x in batch])
    assert np.allclose(numpy_scores, torch_scores, rtol=1e-5, atol=1e-6)


def test_paper_architecture() -> None:
    config = RNDConfig.paper()
    assert config.target_layers() == [(1024, "leaky_relu"), (2048, "leaky_relu"), (4096, "leaky_relu"), (512, None)]
    assert config.predictor_layers()[3:] == [(2048, "relu"), (1024, "relu"), (512, None)]
    small = RNDOE(8, RNDConfig.small())
    linear = small.predictor[0]
    weight = linear.weight.detach().numpy()
    assert weight.shape == (256, 8) and np.allclose(weight.T @ weight, 2.0 * np.eye(8), atol=1e-4)  # gain sqrt(2)
    assert not linear.bias.detach().numpy().any()


def test_save_load_round_trip(model: RNDOE, tmp_path: Path, clusters: Clusters) -> None:
    model.save(tmp_path)
    loaded = RNDOE.load(tmp_path)
    assert loaded.digest() == model.digest()
    assert loaded.config == model.config
    assert loaded.score_one(clusters[2][0]) == model.score_one(clusters[2][0])
    with pytest.raises(RNDError, match="missing"):
        RNDOE.load(tmp_path / "nowhere")


def test_input_errors(model: RNDOE) -> None:
    with pytest.raises(RNDError, match="shape"):
        model.score_one(np.zeros(31))
    with pytest.raises(RNDError, match="NaN"):
        model.score(np.full((2, 32), np.nan))
    with pytest.raises(RNDError, match="at least 2"):
        RNDOE.fit(np.zeros((1, 32)), TINY_RND)


def _linear_pair(target_weight: float, predictor_weight: float) -> RNDOE:
    """A 1-input RND whose target is ``x -> target_weight x`` and predictor ``x -> predictor_weight x``."""
    import torch

    model = RNDOE(1, RNDConfig(trunk=(), head=(), out_dim=1), seed=0)
    with torch.no_grad():
        model.target[0].weight.fill_(target_weight)
        model.predictor[0].weight.fill_(predictor_weight)
    model._cache_numpy()
    return model


def test_float32_overflow_is_recomputed_in_float64() -> None:
    # Issue #27: 3x and 2x of x = 3e38 overflow float32 to inf, inf - inf = NaN, and NaN > gamma is False:
    # the old score_one returned NaN, which the fusion read as "below the threshold". By hand, the score
    # is |3x - 2x| = x.
    x = float(np.float32(3e38))
    model = _linear_pair(2.0, 3.0)
    assert model.score_one(np.array([x], np.float32)) == pytest.approx(x, rel=1e-12)
    assert model.score_one(np.array([-x], np.float32)) == pytest.approx(x, rel=1e-12)
    # the float32 path is kept where it does not overflow: |3 - 2| * 1.5 = 1.5 exactly
    assert model.score_one(np.array([1.5], np.float32)) == 1.5


def test_a_score_beyond_float64_stays_non_finite_for_the_caller_to_reject() -> None:
    from helpers.core_data import overflowing_rnd

    assert not np.isfinite(overflowing_rnd(3).score_one(np.ones(3, np.float32)))
