"""logpZO (core/logpzo.py): scores by hand with set weights, numpy scoring against the torch path it replaces,
training (core/logpzo_train.py) seeded, off-distribution clusters scored higher, files and scoring without torch."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch

from fiper_ros.core.logpzo import LogpZO, LogpZOConfig, LogpZOError
from fiper_ros.core.rollout import Rollout
from fiper_ros.core.torch_mlp import build_mlp
from helpers.core_data import cluster_rollout

SMALL = LogpZOConfig(hidden=(64, 64), epochs=40)


def _clusters() -> tuple[list[Rollout], list[Rollout]]:
    rng = np.random.default_rng(0)
    train = [cluster_rollout(rng, i, (0.0, 0.0)) for i in range(8)]
    far = [cluster_rollout(rng, 100 + i, (3.0, -3.0)) for i in range(2)]
    return train, far


@pytest.fixture(scope="module")
def fitted() -> tuple[LogpZO, list[Rollout], list[Rollout]]:
    train, far = _clusters()
    failure = cluster_rollout(np.random.default_rng(1), 50, (9.0, 9.0), success=False)
    return LogpZO(SMALL).fit([*train, failure], 0), train, far


def _set_weights(steps: int, mean: list[float], std: list[float], weights: dict[str, list]) -> LogpZO:
    """A logpZO of E = 2, hidden (2,), with the given standardisation and velocity net ``0.*`` (3 -> 2, ReLU) and
    ``2.*`` (2 -> 2)."""
    config = LogpZOConfig(hidden=(2,), steps=steps)
    arrays = {"mean": np.array(mean), "std": np.array(std)}
    arrays |= {f"velocity/{name}": np.array(value, dtype=np.float32) for name, value in weights.items()}
    return LogpZO.from_stored({"config": config.to_dict(), "seed": 0, "embedding_dim": 2}, arrays)


ZERO_NET = {"0.weight": np.zeros((2, 3)), "0.bias": [0, 0], "2.weight": np.zeros((2, 2))}


def test_one_euler_step_by_hand() -> None:
    # v(x, s) = (1, -2) everywhere; (3, 5) standardised with mean 1, std 2 is (1, 2); Z = (2, 0), ||Z||^2 = 4
    model = _set_weights(1, [1.0, 1.0], [2.0, 2.0], {**ZERO_NET, "2.bias": [1, -2]})
    assert model.score_one(np.array([3.0, 5.0])) == 4.0


def test_euler_steps_read_the_time_by_hand() -> None:
    # v(x, s) = (s, 0): two steps at s = 0 and 0.5 move x = (1, 2) by 0 and 0.5 / 2: Z = (1.25, 2), 1.5625 + 4
    net = {"0.weight": [[0, 0, 1], [0, 0, 0]], "0.bias": [0, 0], "2.weight": [[1, 0], [0, 0]], "2.bias": [0, 0]}
    model = _set_weights(2, [0.0, 0.0], [1.0, 1.0], net)
    assert model.score_one(np.array([1.0, 2.0])) == 5.5625
    assert _set_weights(1, [0.0, 0.0], [1.0, 1.0], net).score_one(np.array([1.0, 2.0])) == 5.0  # s = 0 only


def test_the_standardisation_is_that_of_the_successes(fitted: tuple[LogpZO, list[Rollout], list[Rollout]]) -> None:
    model, train, _ = fitted
    data = np.concatenate([r.embeddings for r in train]).astype(np.float64)  # the failure is not fitted on
    np.testing.assert_array_equal(model.mean, data.mean(axis=0))
    np.testing.assert_array_equal(model.std, data.std(axis=0))
    plain = LogpZO(LogpZOConfig(hidden=(8,), epochs=1, standardize=False)).fit(train)
    np.testing.assert_array_equal(plain.mean, [0.0, 0.0])
    np.testing.assert_array_equal(plain.std, [1.0, 1.0])


def test_an_off_distribution_cluster_scores_higher_and_training_is_seeded(
        fitted: tuple[LogpZO, list[Rollout], list[Rollout]]) -> None:
    model, train, far = fitted
    inside = np.mean([model.scores(r).mean() for r in train])
    outside = np.mean([model.scores(r).mean() for r in far])
    assert outside > 3.0 * inside, (inside, outside)
    again = LogpZO(SMALL).fit(train, seed=0)
    assert again.digest() == model.digest()
    assert LogpZO(SMALL).fit(train, seed=1).digest() != model.digest()


def test_more_euler_steps_still_separate() -> None:
    train, far = _clusters()
    model = LogpZO(LogpZOConfig(hidden=(64, 64), epochs=40, steps=4)).fit(train, seed=1)
    assert np.mean([model.scores(r).mean() for r in far]) > np.mean([model.scores(r).mean() for r in train])


def _torch_scores(model: LogpZO, embeddings: np.ndarray) -> np.ndarray:
    """The scores as the torch path computed them before numpy did: one batch, float32 net, float64 norm."""
    assert model.network is not None
    network = build_mlp(model.embedding_dim + 1, model.config.velocity_layers(model.embedding_dim),
                        torch.Generator().manual_seed(0))
    network.load_state_dict({name: torch.from_numpy(np.array(a)) for name, a in model.network.parameters.items()})
    x = torch.from_numpy(((np.asarray(embeddings, dtype=np.float64) - model.mean) / model.std).astype(np.float32))
    steps = model.config.steps
    with torch.no_grad():
        for k in range(steps):
            x = x + network(torch.cat([x, torch.full((x.shape[0], 1), k / steps)], dim=1)) / steps
    return torch.sum(x.double() ** 2, dim=1).numpy()


@pytest.mark.parametrize("steps", [1, 3])
def test_numpy_and_torch_paths_agree(steps: int) -> None:
    """Every score that is judged is numpy's; torch's batch path differs by float32 rounding (measured on these
    data: at most 3.2e-7 relative)."""
    train, far = _clusters()
    model = LogpZO(LogpZOConfig(hidden=(64, 64), epochs=10, steps=steps)).fit(train, seed=2)
    probe = np.concatenate([r.embeddings for r in (*train[:2], *far)])
    np.testing.assert_allclose(model.score_embeddings(probe), _torch_scores(model, probe), rtol=1e-5, atol=0)


def test_save_load_and_scoring_without_torch(fitted: tuple[LogpZO, list[Rollout], list[Rollout]],
                                             tmp_path: Path) -> None:
    model, _, far = fitted
    model.save(tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["logpzo.json", "logpzo.npz"]
    loaded = LogpZO.load(tmp_path)
    assert loaded.digest() == model.digest() and loaded.config == model.config
    expected = model.scores(far[0])
    np.testing.assert_array_equal(loaded.scores(far[0]), expected)
    np.save(tmp_path / "probe.npy", far[0].embeddings)
    code = textwrap.dedent(f"""
        import sys
        sys.modules["torch"] = None  # import torch raises ImportError
        import numpy as np
        import fiper_ros.core.consistency, fiper_ros.core.pca_kmeans, fiper_ros.core.progress
        from fiper_ros.core.logpzo import LogpZO
        scores = LogpZO.load({str(tmp_path)!r}).score_embeddings(np.load({str(tmp_path / "probe.npy")!r}))
        print(repr(scores.tolist()))
        """)
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 0, result.stderr
    assert eval(result.stdout) == expected.tolist()  # our own child's repr of floats


def test_bad_input_is_refused_in_one_line(fitted: tuple[LogpZO, list[Rollout], list[Rollout]]) -> None:
    model, _, _ = fitted
    with pytest.raises(LogpZOError, match=r"^embeddings must have shape \(2\) with no empty axis, got \(1, 2\)$"):
        model.score_one(np.zeros((1, 2)))
    with pytest.raises(LogpZOError, match="NaN/inf"):
        model.score_embeddings(np.array([[np.inf, 0.0]]))
    with pytest.raises(LogpZOError, match="not fitted"):
        LogpZO().score_one(np.zeros(2))
    with pytest.raises(LogpZOError, match="none given"):
        LogpZO().fit([cluster_rollout(np.random.default_rng(0), 0, (0.0, 0.0), success=False)])
    with pytest.raises(LogpZOError, match="at least one Euler step"):
        LogpZOConfig(steps=0)
    with pytest.raises(LogpZOError, match="the score overflows"):
        _set_weights(1, [0.0, 0.0], [1e-30, 1.0], {**ZERO_NET, "2.bias": [0, 0]}).score_one(np.array([1e10, 0.0]))
    with pytest.raises(LogpZOError, match="velocity net"):
        _set_weights(1, [0.0, 0.0], [1.0, 1.0], ZERO_NET)  # 2.bias missing
