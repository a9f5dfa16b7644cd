"""The shipped models and in-process closed-loop rollouts in the MuJoCo tasks."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from helpers.policy_fixtures import tiny_config
from sim_bridge.closed_loop import run_episode
from sim_bridge.multimodality import block_choice, initial_batch
from sim_bridge.policy_evaluation import EvaluationResult, save_rollouts
from sim_bridge.robot import URDF_PATH
from sim_bridge.tasks import TASKS as SIM_TASKS

from fiper_ros.core.calibration import load_calibration
from fiper_ros.core.kinematics import PinocchioFK
from fiper_ros.core.monitor import predict_rollout
from fiper_ros.core.rollout import RolloutSet
from fiper_ros.policy.normalizer import RangeNormalizer
from fiper_ros.policy.policy import Policy

MODELS = Path(__file__).resolve().parents[2] / "models"


@pytest.fixture(scope="module")
def sorting_policy() -> Policy:
    """The committed Sorting model (the demo task: it must exist)."""
    return Policy.load(MODELS / "sorting")


def test_shipped_sorting_model_is_finite_and_multimodal(sorting_policy: Policy) -> None:
    config = sorting_policy.config
    assert (config.embed_dim, config.horizon, config.exec_steps, config.sample_batch) == (128, 8, 4, 32)
    assert (MODELS / "sorting" / "policy.pt").stat().st_size <= 10 * 2**20
    modes = []
    for seed in (1000, 1001, 1002):
        state, chunks = initial_batch(sorting_policy, seed)
        assert chunks.shape == (32, 8, 2) and np.all(np.isfinite(chunks))
        assert np.std(chunks[:, -1], axis=0).max() > 0.01  # the samples are not one collapsed path
        choice = block_choice(state, chunks)
        modes.append(min(np.sum(choice == 0), np.sum(choice == 1)))
    # where the demonstrations are bimodal (either block first), the batch covers both blocks
    assert sum(m >= 2 for m in modes) >= 2, modes


def test_shipped_pusht_model_pushes_the_t_from_its_first_observation() -> None:
    policy = Policy.load(MODELS / "pusht")
    config = policy.config
    assert (config.head, config.embed_dim, config.horizon, config.exec_steps, config.sample_batch) == \
        ("diffusion", 64, 16, 8, 256)
    assert (MODELS / "pusht" / "policy.pt").stat().st_size <= 10 * 2**20
    for seed in (1000, 1001):
        state, chunks = initial_batch(policy, seed)
        assert chunks.shape == (256, 16, 2) and np.all(np.isfinite(chunks))
        assert np.std(chunks[:, -1], axis=0).max() > 0.005  # the samples are not one collapsed path
        # the median chunk ends nearer the T than the TCP starts: the pusher approaches it
        t_xy, tcp = np.asarray(state["t_pose"])[:2], np.asarray(state["tcp"])[:2]
        assert np.linalg.norm(np.median(chunks[:, -1], axis=0) - t_xy) < np.linalg.norm(tcp - t_xy)


def test_shipped_stacking_model_turns_its_hand_and_places_the_red_block() -> None:
    """ID seed 1003: the red block stands at 42 degrees, the largest hand turn (docs/policies.md)."""
    policy = Policy.load(MODELS / "stacking")
    config = policy.config
    assert (config.head, config.action_space, config.horizon, config.exec_steps, config.sample_batch) == \
        ("flow", "joint_velocity", 8, 4, 32)
    assert (MODELS / "stacking" / "policy.pt").stat().st_size <= 10 * 2**20
    episode = run_episode(policy, "id", 1003)
    assert episode.success and episode.policy_steps < 40, episode
    # FIPER on it with the shipped calibration: joint velocities -> Panda FK -> ACE
    assert episode.rollout is not None
    calibration = load_calibration(MODELS / "stacking" / "calibration")
    prediction = predict_rollout(episode.rollout, calibration, PinocchioFK(URDF_PATH, "panda_hand"))
    assert prediction.detectors["ace"].scores.shape == (episode.policy_steps,) and np.all(np.isfinite(prediction.detectors["ace"].scores))
    assert np.all(prediction.detectors["ace"].scores >= 0) and np.median(prediction.detectors["ace"].scores) > 1.0  # bits: the 32 spread
    assert prediction.first_alarm_step is None  # a success, and the shipped calibration stays quiet on it


@pytest.mark.parametrize("task", ["sorting", "stacking", "pusht"])
def test_every_shipped_calibration_fits_its_policy(task: str) -> None:
    config = Policy.load(MODELS / task).config
    calibration = load_calibration(MODELS / task / "calibration")
    calibration.check_compatible(embedding_dim=config.embed_dim, action_dim=config.action_dim, horizon=config.horizon)
    assert (calibration.layout.action_space, calibration.layout.exec_steps) == (config.action_space, config.exec_steps)
    if config.action_space == "joint_velocity":
        assert calibration.settings.control_dt == pytest.approx(1.0 / SIM_TASKS[task].control_hz)


def test_closed_loop_rollout_is_recorded(sorting_policy: Policy, tmp_path: Path) -> None:
    episode = run_episode(sorting_policy, "id", 1000, max_policy_steps=3)
    rollout = episode.rollout
    assert episode.policy_steps == 3 and episode.control_steps == 12 and not episode.success
    assert rollout is not None and rollout.embeddings.shape == (3, 128) and rollout.actions.shape == (3, 32, 8, 2)
    assert rollout.exec_steps == 4 and rollout.action_space == "ee_position" and rollout.scenario == "id"
    save_rollouts([EvaluationResult("sorting", "id", [episode])], tmp_path / "r.npz", split="calibration")
    loaded = RolloutSet.load_npz(tmp_path / "r.npz").calibration[0]
    np.testing.assert_array_equal(loaded.actions, rollout.actions)


def test_joint_velocity_rollouts_store_joint_positions() -> None:
    config = tiny_config("stacking")
    torch.manual_seed(0)
    policy = Policy(config, RangeNormalizer(-0.05 * np.ones(8), 0.05 * np.ones(8)),
                    RangeNormalizer(-np.ones(11), np.ones(11))).eval()
    episode = run_episode(policy, "id", 5, max_policy_steps=2)
    rollout = episode.rollout
    assert rollout is not None and rollout.action_space == "joint_velocity"
    assert rollout.actions.shape == (2, config.sample_batch, 8, 8)
    joints = rollout.metadata["joint_positions"]
    assert joints.shape == (2, 7) and not np.allclose(joints[0], joints[1])  # the arm moved between steps
