"""RND-OE, eq. (1) and App. A.2: trained with torch (core.rnd_train), scoring and stored with numpy (core.rnd_oe)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from helpers.core_data import TINY_RND, filled_rnd

from fiper_ros.core.rnd_oe import RNDOE, WEIGHTS_FILE, RNDConfig, RNDError, TrainProgress
from fiper_ros.core.rnd_train import TorchRND, fit_rnd, untrained_rnd

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
def trained(clusters: Clusters) -> TorchRND:
    model = TorchRND(32, TINY_RND, seed=3)
    model.train(clusters[0])
    return model


@pytest.fixture(scope="module")
def model(trained: TorchRND) -> RNDOE:
    return trained.numpy()


def scores(model: RNDOE, batch: np.ndarray) -> np.ndarray:
    return np.array([model.score_one(x) for x in batch])


def test_separates_an_off_distribution_cluster(model: RNDOE, clusters: Clusters) -> None:
    _, held_out, off = clusters
    assert np.min(scores(model, off)) > np.max(scores(model, held_out))


def test_training_lowers_the_id_score(clusters: Clusters, model: RNDOE) -> None:
    untrained = untrained_rnd(32, TINY_RND, seed=3)
    assert np.mean(scores(model, clusters[1])) < 0.5 * np.mean(scores(untrained, clusters[1]))


def test_deterministic_per_seed(clusters: Clusters, model: RNDOE) -> None:
    progress: list[TrainProgress] = []
    again = fit_rnd(clusters[0], TINY_RND, seed=3, progress=progress.append)
    assert again.digest() == model.digest()
    assert progress and progress[-1].epoch == len(progress)
    assert untrained_rnd(32, TINY_RND, seed=4).digest() != untrained_rnd(32, TINY_RND, seed=3).digest()


def test_numpy_and_torch_paths_agree(trained: TorchRND, model: RNDOE, clusters: Clusters) -> None:
    batch = np.concatenate([clusters[1][:20], clusters[2][:20]])
    assert np.allclose(scores(model, batch), trained.score(batch), rtol=1e-5, atol=1e-6)


def test_the_digest_is_that_of_the_torch_state_dicts(trained: TorchRND, model: RNDOE) -> None:
    """The content hash of a calibration covers the weights through this digest: the numpy parameters give the
    one the torch networks gave (names, shapes, float32 values), so a converted format-1 calibration keeps it."""
    import hashlib

    digest = hashlib.sha256()
    for index, network in enumerate((trained.target, trained.predictor)):
        for name, tensor in sorted(network.state_dict().items()):
            digest.update(f"{index}/{name}/{tuple(tensor.shape)}".encode())
            digest.update(tensor.numpy().tobytes())
    assert model.digest() == digest.hexdigest()


def test_paper_architecture() -> None:
    config = RNDConfig.paper()
    assert config.target_layers() == [(1024, "leaky_relu"), (2048, "leaky_relu"), (4096, "leaky_relu"), (512, None)]
    assert config.predictor_layers()[3:] == [(2048, "relu"), (1024, "relu"), (512, None)]
    small = TorchRND(8, RNDConfig.small())
    linear = small.predictor[0]
    weight = linear.weight.detach().numpy()
    assert weight.shape == (256, 8) and np.allclose(weight.T @ weight, 2.0 * np.eye(8), atol=1e-4)  # gain sqrt(2)
    assert not linear.bias.detach().numpy().any()


def test_save_load_round_trip(model: RNDOE, tmp_path: Path, clusters: Clusters) -> None:
    model.save(tmp_path)
    loaded = RNDOE.load(tmp_path)
    assert loaded.digest() == model.digest()
    assert loaded.config == model.config
    assert np.array_equal(scores(loaded, clusters[2]), scores(model, clusters[2]))  # bit for bit
    with pytest.raises(RNDError, match="missing"):
        RNDOE.load(tmp_path / "nowhere")


WEIGHT_DAMAGES = {
    "another shape": lambda good, first: {**good, first: np.zeros((3, 3), np.float32)},
    "another dtype": lambda good, first: {**good, first: good[first].astype(np.float64)},
    "an extra array": lambda good, first: {**good, "extra": np.zeros(1, np.float32)},
    "a missing array": lambda good, first: {k: v for k, v in good.items() if k != first},
}


@pytest.mark.parametrize("damage", WEIGHT_DAMAGES)
def test_the_weights_file_holds_exactly_the_described_arrays(damage: str, model: RNDOE, tmp_path: Path) -> None:
    """Every array's header is checked before its data is read: another shape or dtype, an extra or a missing
    array is refused, naming the file."""
    model.save(tmp_path)
    path = tmp_path / WEIGHTS_FILE
    good = dict(np.load(path))
    with path.open("wb") as stream:
        np.savez(stream, **WEIGHT_DAMAGES[damage](good, next(iter(good))))
    with pytest.raises(RNDError, match=f"^{path}: "):
        RNDOE.load(tmp_path)


def test_input_errors(model: RNDOE) -> None:
    with pytest.raises(RNDError, match="shape"):
        model.score_one(np.zeros(31))
    with pytest.raises(RNDError, match="NaN"):
        fit_rnd(np.full((2, 32), np.nan), TINY_RND)
    with pytest.raises(RNDError, match="at least 2"):
        fit_rnd(np.zeros((1, 32)), TINY_RND)
    with pytest.raises(RNDError, match="do not match"):
        RNDOE(32, TINY_RND, 0, model.parameters()["predictor"], model.parameters()["target"])


def _linear_pair(target_weight: float, predictor_weight: float) -> RNDOE:
    """A 1-input RND whose target is ``x -> target_weight x`` and predictor ``x -> predictor_weight x``."""
    return filled_rnd(1, RNDConfig(trunk=(), head=(), out_dim=1), target_weight, predictor_weight)


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
