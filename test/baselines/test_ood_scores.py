"""Learned scores (RND-OE, RND-A) rate off-distribution inputs above the training data (logpZO:
test/core/test_logpzo.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from baselines.conftest import chunk_rollout
from fiper_ros.baselines.rnd_a import RNDA, RNDAConfig
from fiper_ros.core.rnd_oe import RNDConfig
from fiper_ros.core.rnd_train import fit_rnd
from helpers.core_data import cluster_rollout

SMALL_RND = RNDConfig(trunk=(64, 64), head=(64,), out_dim=16, max_epochs=30, lr=1e-3)


def _clusters() -> tuple[list, list]:
    rng = np.random.default_rng(0)
    train = [cluster_rollout(rng, i, (0.0, 0.0)) for i in range(8)]
    far = [cluster_rollout(rng, 100 + i, (3.0, -3.0)) for i in range(2)]
    return train, far


def test_rnd_oe_scores_an_off_distribution_cluster_higher() -> None:
    train, far = _clusters()
    model = fit_rnd(np.concatenate([r.embeddings for r in train]), SMALL_RND, seed=0)
    inside = np.mean([model.score_one(x) for r in train for x in r.embeddings])
    outside = np.mean([model.score_one(x) for r in far for x in r.embeddings])
    assert outside > 3.0 * inside, (inside, outside)


def test_rnd_a_scores_off_distribution_chunks_higher_and_round_trips(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    train = [chunk_rollout(rng, i, noise=0.005) for i in range(8)]
    noisy = [chunk_rollout(rng, 100 + i, noise=0.5) for i in range(2)]
    config = RNDAConfig(channels=8, train_samples=8, score_samples=8, rnd=SMALL_RND)
    model = RNDA(config).fit(train, seed=0)
    inside = np.mean([model.scores(r).mean() for r in train])
    outside = np.mean([model.scores(r).mean() for r in noisy])
    assert outside > 3.0 * inside, (inside, outside)
    assert model.scores(noisy[0]).shape == (noisy[0].length,)
    np.testing.assert_array_equal(RNDA(config).fit(train, seed=0).scores(noisy[0]), model.scores(noisy[0]))
    model.save(tmp_path)
    np.testing.assert_allclose(RNDA.load(tmp_path).scores(noisy[0]), model.scores(noisy[0]), rtol=1e-6)
