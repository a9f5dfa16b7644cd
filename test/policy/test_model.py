"""Policy building blocks: shapes, dtypes, determinism, one batched pass, normalisation, save/load."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from helpers.policy_fixtures import random_observation, tiny_policy

from fiper_ros.policy.normalizer import RangeNormalizer
from fiper_ros.policy.policy import Policy


@pytest.mark.parametrize("task", ["sorting", "stacking", "pusht"])
def test_shapes_and_dtypes(task: str) -> None:
    policy = tiny_policy(task)
    config = policy.config
    embedding = policy.embed([random_observation(config)] * config.obs_horizon)
    assert embedding.shape == (config.embed_dim,) and embedding.dtype == np.float32
    chunks = policy.sample(embedding, 5, torch.Generator().manual_seed(0))
    assert chunks.shape == (5, config.horizon, config.action_dim) and chunks.dtype == np.float32
    assert np.all(np.isfinite(chunks))
    assert policy.sample(embedding).shape[0] == config.sample_batch


def test_short_history_is_padded_with_the_first_frame() -> None:
    policy = tiny_policy("stacking")
    obs = random_observation(policy.config)
    assert policy.config.obs_horizon == 2
    np.testing.assert_array_equal(policy.embed([obs]), policy.embed([obs, obs]))


@pytest.mark.parametrize("task", ["sorting", "pusht"])
def test_sampling_is_deterministic_per_seed_and_diverse(task: str) -> None:
    policy = tiny_policy(task)
    embedding = policy.embed([random_observation(policy.config)])
    first = policy.sample(embedding, 8, torch.Generator().manual_seed(3))
    again = policy.sample(embedding, 8, torch.Generator().manual_seed(3))
    other = policy.sample(embedding, 8, torch.Generator().manual_seed(4))
    np.testing.assert_array_equal(first, again)
    assert not np.allclose(first, other)
    assert np.std(first, axis=0).mean() > 1e-4  # the B samples differ from each other


@pytest.mark.parametrize("task", ["sorting", "pusht"])
def test_batch_is_sampled_in_one_batched_pass(task: str) -> None:
    policy = tiny_policy(task)
    calls: list[int] = []
    policy.net.register_forward_hook(lambda _m, inputs, _o: calls.append(inputs[0].shape[0]))
    encoder_calls: list[int] = []
    policy.encoder.register_forward_hook(lambda _m, inputs, _o: encoder_calls.append(inputs[1].shape[0]))
    policy.act([random_observation(policy.config)], 7, torch.Generator().manual_seed(0))
    steps = policy.config.integration_steps if task == "sorting" else policy.config.diffusion_sample_steps
    assert encoder_calls == [1]
    assert calls == [7] * steps


def test_normalisation_round_trip() -> None:
    data = np.random.default_rng(1).normal(size=(50, 3)) * [1.0, 10.0, 0.001]
    norm = RangeNormalizer.fit(data)
    x = torch.from_numpy(data.astype(np.float32))
    y = norm.normalize(x)
    assert y[:, :2].min() >= -1.0 - 1e-6 and y[:, :2].max() <= 1.0 + 1e-6
    assert y[:, :2].min() < -0.999 and y[:, :2].max() > 0.999
    assert y[:, 2].abs().max() < 0.5  # a near-constant dimension is not blown up to [-1, 1]
    torch.testing.assert_close(norm.unnormalize(y), x, atol=1e-5, rtol=1e-5)


def test_save_load_round_trip(tmp_path: Path) -> None:
    policy = tiny_policy("pusht", seed=2)
    policy.save(tmp_path, {"note": "test"})
    loaded = Policy.load(tmp_path)
    assert loaded.config == policy.config
    obs = [random_observation(policy.config)]
    np.testing.assert_array_equal(policy.embed(obs), loaded.embed(obs))
    embedding = policy.embed(obs)
    np.testing.assert_array_equal(policy.sample(embedding, 4, torch.Generator().manual_seed(1)),
                                  loaded.sample(embedding, 4, torch.Generator().manual_seed(1)))
