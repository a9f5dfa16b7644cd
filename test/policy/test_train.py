"""Training on (synthetic) demonstrations: the loss falls, runs are deterministic per seed, resume is exact
(also after a stop at an earlier epoch of the schedule);
the open-loop fit check against the demonstrations."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
import yaml
from helpers.policy_fixtures import tiny_config, write_demos

from fiper_ros.commands import policy as policy_command
from fiper_ros.policy import PolicyError
from fiper_ros.policy.dataset import DemoDataset
from fiper_ros.policy.fit import open_loop_fit
from fiper_ros.policy.normalizer import RangeNormalizer
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
    with pytest.raises(PolicyError, match="cannot stop after epoch 4"):
        train(three, demo_dir, tmp_path / "x", tmp_path / "run", seed=2, progress=_quiet, stop_after=4)
    rest = _state(train(three, demo_dir, tmp_path / "rest", tmp_path / "run", seed=2, progress=_quiet))
    for key, value in _state(full).items():
        torch.testing.assert_close(value, rest[key], rtol=0, atol=0)  # the same schedule, resumed
    with pytest.raises(PolicyError, match="holds 3"):
        train(three, demo_dir, tmp_path / "y", tmp_path / "run", seed=2, progress=_quiet, stop_after=2)


def test_training_input_it_refuses_is_a_policy_error(tmp_path: Path, demo_dir: Path) -> None:
    """No demonstrations, none successful, or of other dimensions than the config's: the user's to fix (each was a
    FileNotFoundError or a ValueError)."""
    config = tiny_config()
    sizes = (config.obs_horizon, config.horizon, config.image_size)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(PolicyError, match=f"^no episode_\\*\\.npz demonstrations in {empty}$"):
        DemoDataset(empty, *sizes)
    failed = tmp_path / "failed"
    failed.mkdir()
    with np.load(demo_dir / "episode_000000.npz") as data:
        np.savez(failed / "episode_000000.npz", **{**data, "success": False})
    with pytest.raises(PolicyError, match=f"^no successful demonstrations in {failed}$"):
        DemoDataset(failed, *sizes)
    wider = tiny_config(action_dim=config.action_dim + 1)
    with pytest.raises(PolicyError, match=f"^demos have action/proprio dims {config.action_dim}/{config.proprio_dim}, "
                                          f"config expects {wider.action_dim}/{config.proprio_dim}$"):
        train(wider, demo_dir, tmp_path / "model", tmp_path / "run", progress=_quiet)


def test_the_policy_command_prints_a_user_error_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``python -m fiper_ros.commands.policy`` reports as ``fiper`` does: one line, exit 2 (was a traceback)."""
    threads = str(torch.get_num_threads())
    assert policy_command.main(["--threads", threads, "train", "--task", "sorting", "--demos", str(tmp_path),
                                "--out", str(tmp_path / "model"), "--run-dir", str(tmp_path / "run")]) == 2
    assert capsys.readouterr().err == f"fiper policy: no episode_*.npz demonstrations in {tmp_path}\n"


def test_a_demonstration_of_other_images_is_refused_in_one_line(tmp_path: Path, demo_dir: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """Camera frames that are not uint8 ``[T, H, W, 3]`` in a demonstration file: one line naming the file and the
    camera, exit 2 (was a ValueError's traceback)."""
    demos = tmp_path / "gray"
    demos.mkdir()
    episode = demos / "episode_000000.npz"
    with np.load(demo_dir / "episode_000000.npz") as data:
        gray = data["wrist_rgb"][..., 0]
        np.savez(episode, **{**data, "wrist_rgb": gray})
    assert policy_command.main(["--threads", str(torch.get_num_threads()), "train", "--task", "sorting", "--demos",
                                str(demos), "--out", str(tmp_path / "model"), "--run-dir", str(tmp_path / "run")]) == 2
    assert capsys.readouterr().err == (f"fiper policy: {episode}: wrist_rgb: expected uint8 images [N, H, W, 3], got "
                                       f"uint8 {gray.shape}\n")


def test_open_loop_fit_compares_the_sample_mean_with_the_padded_expert_chunk(tmp_path: Path) -> None:
    config = tiny_config()  # H = 8, D = 2, T_h = 1
    assert (config.horizon, config.action_dim, config.obs_horizon) == (8, 2, 1)
    # A zero action range (clamped to 0.01): every sampled action is 0 + 0.005 x, |x| a few units, so each
    # |chunk mean - expert action| is |expert action| to within 0.05, whatever the untrained network does.
    torch.manual_seed(0)
    policy = Policy(config, RangeNormalizer(np.zeros(2), np.zeros(2)),
                    RangeNormalizer(-np.ones(config.proprio_dim), np.ones(config.proprio_dim))).eval()
    actions = np.array([[10.0, -20.0], [30.0, 40.0], [-50.0, 60.0]], dtype=np.float32)
    rng = np.random.default_rng(0)
    episode = tmp_path / "episode_000000.npz"
    np.savez(episode, actions=actions, proprio=rng.normal(size=(3, config.proprio_dim)).astype(np.float32),
             **{key: rng.integers(0, 255, (3, 96, 96, 3), dtype=np.uint8) for key in ("wrist_rgb", "third_rgb")})
    report = open_loop_fit(policy, [episode], batch=5, stride=2, seed=3)  # states 0 and 2
    # state 0: the chunk a0, a1, a2, a2, a2, a2, a2, a2 (padded with the last action):
    #   mean |.| = (10 + 30 + 6 * 50) / 8 = 42.5 and (20 + 40 + 6 * 60) / 8 = 52.5
    # state 2: a2 eight times: 50 and 60.  error = the mean over both states: 46.25 and 56.25
    assert report.states == 2
    np.testing.assert_allclose(report.error, [46.25, 56.25], atol=0.05)
    assert np.all(report.spread > 0) and np.all(report.spread < 0.05)  # spread over the 5 samples, in units of 0.005
    np.testing.assert_allclose(report.magnitude, [(10 + 30 + 50) / 3, (20 + 40 + 60) / 3], rtol=1e-6)
    with pytest.raises(PolicyError, match="^stride must be >= 1, got 0$"):
        open_loop_fit(policy, [episode], stride=0)
