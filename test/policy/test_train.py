"""Training on (synthetic) demonstrations: the loss falls, runs are deterministic per seed, resume is exact
(also after a stop at an earlier epoch of the schedule);
the open-loop fit check against the demonstrations."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from helpers.policy_fixtures import tiny_config, tiny_policy, write_demos

from fiper_ros.policy.dataset import DemoDataset
from fiper_ros.policy.fit import open_loop_fit
from fiper_ros.policy.policy import Policy
from fiper_ros.policy.train import Progress, train


def _quiet(_: Progress) -> None:
    pass


def _state(policy: Policy) -> dict[str, torch.Tensor]:
    return {k: v.clone() for k, v in policy.state_dict().items()}


def test_dataset_windows(demo_dir: Path) -> None:
    config = tiny_config(obs_horizon=2)
    data = DemoDataset(demo_dir, config.obs_horizon, config.horizon, config.image_size)
    assert len(data) == 3 * 12 and data.episodes == 3
    batch = data.batch(torch.tensor([0, 11]))
    assert batch.images[0].shape == (2, 2, 3, 16, 16) and batch.images[0].dtype == torch.uint8
    raw = np.load(demo_dir / "episode_000000.npz")["actions"]
    np.testing.assert_array_equal(batch.actions[0].numpy(), raw[:8])
    np.testing.assert_array_equal(batch.actions[1].numpy(), np.repeat(raw[11:12], 8, axis=0))  # tail padding
    np.testing.assert_array_equal(batch.proprio[0, 0], batch.proprio[0, 1])  # history clamped at the start


@pytest.mark.parametrize("task", ["sorting", "pusht"])
def test_training_reduces_the_loss_and_writes_the_model(tmp_path: Path, task: str) -> None:
    config = tiny_config(task, epochs=6, lr=3e-3)
    demos = write_demos(tmp_path / "demos", config)
    losses: list[float] = []
    train(config, demos, tmp_path / "model", tmp_path / "run", seed=0, progress=lambda p: losses.append(p.loss),
          report_every=1)
    assert np.mean(losses[-4:]) < np.mean(losses[:4])
    document = yaml.safe_load((tmp_path / "model" / "policy.yaml").read_text())
    assert document["config"]["task"] == task and len(document["info"]["data_hash"]) == 64
    assert len(document["action_stats"]["low"]) == config.action_dim
    assert Policy.load(tmp_path / "model").config == config


def test_training_is_deterministic_and_resumes_exactly(tmp_path: Path, demo_dir: Path) -> None:
    two = tiny_config(epochs=2)
    full = _state(train(two, demo_dir, tmp_path / "a", tmp_path / "run_a", seed=5, progress=_quiet))
    repeat = _state(train(two, demo_dir, tmp_path / "b", tmp_path / "run_b", seed=5, progress=_quiet))
    other = _state(train(two, demo_dir, tmp_path / "c", tmp_path / "run_c", seed=6, progress=_quiet))
    for key in full:
        torch.testing.assert_close(full[key], repeat[key], rtol=0, atol=0)
    assert any(not torch.equal(full[k], other[k]) for k in full)

    class Interrupt(Exception):
        pass

    def stop_in_epoch_two(report: Progress) -> None:
        if report.epoch == 2:
            raise Interrupt

    with pytest.raises(Interrupt):
        train(two, demo_dir, tmp_path / "d", tmp_path / "run_d", seed=5, progress=stop_in_epoch_two)
    assert (tmp_path / "run_d" / "checkpoint.pt").exists() and not (tmp_path / "d").exists()
    resumed = _state(train(two, demo_dir, tmp_path / "d", tmp_path / "run_d", seed=5, progress=_quiet))
    for key in full:
        torch.testing.assert_close(full[key], resumed[key], rtol=0, atol=0)


def test_stop_after_writes_the_model_of_that_epoch_and_the_schedule_goes_on(tmp_path: Path, demo_dir: Path) -> None:
    three = tiny_config(epochs=3)
    full = train(three, demo_dir, tmp_path / "full", tmp_path / "run_full", seed=2, progress=_quiet)
    one = train(three, demo_dir, tmp_path / "one", tmp_path / "run", seed=2, progress=_quiet, stop_after=1)
    info = yaml.safe_load((tmp_path / "one" / "policy.yaml").read_text())["info"]
    assert (info["epochs"], info["epochs_trained"]) == (3, 1)
    assert any(not torch.equal(a, b) for a, b in zip(one.state_dict().values(), full.state_dict().values()))
    with pytest.raises(ValueError, match="cannot stop after epoch 4"):
        train(three, demo_dir, tmp_path / "x", tmp_path / "run", seed=2, progress=_quiet, stop_after=4)
    rest = _state(train(three, demo_dir, tmp_path / "rest", tmp_path / "run", seed=2, progress=_quiet))
    for key, value in _state(full).items():
        torch.testing.assert_close(value, rest[key], rtol=0, atol=0)  # the same schedule, resumed
    with pytest.raises(ValueError, match="holds 3"):
        train(three, demo_dir, tmp_path / "y", tmp_path / "run", seed=2, progress=_quiet, stop_after=2)


def test_open_loop_fit_compares_the_sample_mean_with_the_padded_expert_chunk(demo_dir: Path) -> None:
    policy = tiny_policy()
    episode = sorted(demo_dir.glob("episode_*.npz"))[0]
    with np.load(episode) as data:
        frames = [{key: data[key][t] for key in ("wrist_rgb", "third_rgb", "proprio")}
                  for t in range(len(data["actions"]))]
        actions = data["actions"]
    last = len(actions) - 1
    report = open_loop_fit(policy, [episode], batch=5, stride=last, seed=3)  # states 0 and the last one
    expected_errors, expected_spreads = [], []
    for t, target in ((0, actions[:policy.config.horizon]), (last, np.repeat(actions[-1:], policy.config.horizon, 0))):
        _, chunks = policy.act([frames[t]], 5, torch.Generator().manual_seed(3))
        expected_errors.append(np.abs(chunks.mean(0) - target).mean(0))
        expected_spreads.append(chunks.std(0).mean(0))
    assert report.states == 2
    np.testing.assert_allclose(report.error, np.mean(expected_errors, 0), rtol=1e-6)
    np.testing.assert_allclose(report.spread, np.mean(expected_spreads, 0), rtol=1e-6)
    np.testing.assert_allclose(report.magnitude, np.abs(actions).mean(0), rtol=1e-6)
    with pytest.raises(ValueError, match="stride"):
        open_loop_fit(policy, [episode], stride=0)
