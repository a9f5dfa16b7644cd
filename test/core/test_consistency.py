"""Single-sample action consistency (core/consistency.py): a tiny rollout by hand, only sample 0 read, the scale and
its floor, the overlap refusal, channel selection, the streaming form bit for bit (across reset and lost steps),
its files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fiper_ros.core.consistency import ActionConsistency, ConsistencyError, ConsistencySettings
from fiper_ros.core.rollout import Rollout
from fiper_ros.core.step_stream import StepOrderError


def rollout(sample0: np.ndarray, exec_steps: int = 1, success: bool | None = True, samples: int = 2,
            seed: int = 0) -> Rollout:
    """A rollout whose sample 0 is ``sample0 [T, H, D]``; the other samples are noise."""
    sample0 = np.asarray(sample0, dtype=np.float64)
    others = np.random.default_rng(seed).normal(size=(sample0.shape[0], samples - 1, *sample0.shape[1:]))
    actions = np.concatenate([sample0[:, None], 100.0 * others], axis=1)
    return Rollout(f"r{seed}", "toy", "id", np.zeros((sample0.shape[0], 1)), actions, exec_steps, success)


#: Fit data (H 3, D 2): sample 0's channel 0 takes 0 and 2 equally often (standard deviation 1), channel 1 takes 0
#: and 4 (standard deviation 2); mean scale 1.5, floor 0.15: scale (1, 2).
FIT = rollout(np.array([[[0, 0], [2, 4], [0, 0]], [[2, 4], [0, 0], [2, 4]]]))

#: The executed chunks of a test rollout (T 3, H 3, D 2, h 1).
CHUNKS = np.array([[[0, 0], [1, 2], [2, 4]],
                   [[1, 2], [3, 2], [5, 6]],
                   [[5, 6], [5, 10], [0, 0]]], dtype=np.float64)
# s(1): chunk 1 steps 0, 1 against chunk 0 steps 1, 2: differences (0, 0) and (1, -2), scaled (0, 0) and (1, -1):
#       (0 + 0 + 1 + 1) / 4 = 0.5
# s(2): chunk 2 steps 0, 1 against chunk 1 steps 1, 2: (2, 4) and (0, 4), scaled (2, 2) and (0, 2): (4+4+0+4)/4 = 3
BY_HAND = [0.0, 0.5, 3.0]


@pytest.fixture(scope="module")
def detector() -> ActionConsistency:
    return ActionConsistency.fit([FIT, rollout(np.full((2, 3, 2), 50.0), success=False)])


def test_the_scale_by_hand(detector: ActionConsistency) -> None:
    np.testing.assert_array_equal(detector.scale, [1.0, 2.0])  # the failure is not fitted on
    assert (detector.exec_steps, detector.horizon, detector.action_dim) == (1, 3, 2)


def test_a_tiny_rollout_by_hand(detector: ActionConsistency) -> None:
    actions = rollout(CHUNKS, seed=1).actions
    assert actions is not None and actions.shape == (3, 2, 3, 2)
    np.testing.assert_array_equal(detector.scores(actions), BY_HAND)


def test_only_sample_0_is_read(detector: ActionConsistency) -> None:
    one = rollout(CHUNKS, seed=1).actions
    other = rollout(CHUNKS, seed=2, samples=5).actions
    single = rollout(CHUNKS, samples=1).actions
    assert one is not None and other is not None and single is not None
    assert np.array_equal(detector.scores(one), detector.scores(other))
    assert np.array_equal(detector.scores(one), detector.scores(single))  # B = 1: a single-sample policy
    changed = one.copy()
    changed[1, 0, 2, 0] += 1.0  # sample 0 of step 1, its last (overlapping) action
    assert detector.scores(changed)[2] != BY_HAND[2]


def test_a_longer_execution_compares_a_shorter_overlap() -> None:
    # h = 2, H = 3: one overlapping step, chunk_t[0, 0] against chunk_{t-1}[0, 2]
    detector = ActionConsistency.fit([rollout(FIT.actions[:, 0], exec_steps=2)])  # type: ignore[index]
    # s(1): (1, 2) - (2, 4) = (-1, -2), scaled (-1, -1): (1 + 1) / 2 = 1; s(2): (5, 6) - (5, 6) = 0
    np.testing.assert_array_equal(detector.scores(rollout(CHUNKS).actions), [0.0, 1.0, 0.0])


def test_a_constant_channel_gets_the_floor() -> None:
    fit = FIT.actions[:, 0].copy()  # type: ignore[index]
    fit[..., 1] = 7.0  # channel 1 constant over the successes: standard deviations (1, 0), mean 0.5
    detector = ActionConsistency.fit([rollout(fit)])
    np.testing.assert_array_equal(detector.scale, [1.0, 0.1 * 0.5])
    probe = np.zeros((2, 1, 3, 2))
    probe[1, 0, 0, 1] = 0.05  # one floor's worth in channel 1 at the first overlapping step
    # s(1) = (0^2 + 1^2 + 0^2 + 0^2) / 4
    np.testing.assert_array_equal(detector.scores(probe), [0.0, 0.25])
    looser = ActionConsistency.fit([rollout(fit)], ConsistencySettings(scale_floor=0.5))
    np.testing.assert_array_equal(looser.scale, [1.0, 0.25])


def test_all_channels_constant_is_refused() -> None:
    with pytest.raises(ConsistencyError, match=r"every selected action channel \(0:2\) is constant"):
        ActionConsistency.fit([rollout(np.full((4, 3, 2), 3.0))])


@pytest.mark.parametrize("exec_steps", [3])
def test_no_overlap_is_refused_in_one_line(exec_steps: int) -> None:
    with pytest.raises(ConsistencyError, match=r"^action consistency needs 1 <= h < H for an overlap, got h=3, H=3$"):
        ActionConsistency.fit([rollout(CHUNKS, exec_steps=exec_steps)])


def test_a_channel_selection() -> None:
    detector = ActionConsistency.fit([FIT], ConsistencySettings(action_dims=(1, 2)))
    np.testing.assert_array_equal(detector.scale, [2.0])
    # channel 1 alone: s(1) = (0 + (-2/2)^2) / 2 = 0.5, s(2) = ((4/2)^2 + (4/2)^2) / 2 = 4
    np.testing.assert_array_equal(detector.scores(rollout(CHUNKS).actions), [0.0, 0.5, 4.0])
    with pytest.raises(ConsistencyError, match=r"action_dims \(1, 3\) exceed the 2 action channels"):
        ActionConsistency.fit([FIT], ConsistencySettings(action_dims=(1, 3)))
    with pytest.raises(ConsistencyError, match="0 <= start < stop"):
        ConsistencySettings(action_dims=(1, 1))


@st.composite
def _fit_and_rollouts(draw: st.DrawFn) -> tuple[ActionConsistency, list[np.ndarray]]:
    horizon, dims = draw(st.integers(2, 6)), draw(st.integers(1, 4))
    exec_steps = draw(st.integers(1, horizon - 1))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    start = draw(st.integers(0, dims - 1))
    chosen = ConsistencySettings(action_dims=(start, draw(st.integers(start + 1, dims))),
                                 scale_floor=draw(st.sampled_from([0.01, 0.1, 1.0])))
    fit = [rollout(rng.normal(size=(int(rng.integers(1, 8)), horizon, dims)), exec_steps) for _ in range(2)]
    detector = ActionConsistency.fit(fit, chosen)
    dtype = draw(st.sampled_from([np.float32, np.float64]))
    rollouts = [(draw(st.sampled_from([1e-3, 1.0, 1e6])) * rng.normal(
        size=(int(rng.integers(1, 20)), int(rng.integers(1, 4)), horizon, dims))).astype(dtype) for _ in range(2)]
    return detector, rollouts


@settings(max_examples=150, deadline=None, derandomize=True, database=None)
@given(_fit_and_rollouts())
def test_the_streaming_form_gives_the_whole_rollout_scores_to_the_bit(
        case: tuple[ActionConsistency, list[np.ndarray]]) -> None:
    detector, rollouts = case
    stream = detector.stream()
    for actions in rollouts:  # the second after reset(): nothing of the first is kept
        stream.reset()
        streamed = np.array([stream.update(t, batch) for t, batch in enumerate(actions)])
        assert np.array_equal(streamed, detector.scores(actions))
        assert streamed[0] == 0.0 and (streamed >= 0).all()


def test_after_a_lost_step_the_stream_has_no_previous_chunk(detector: ActionConsistency) -> None:
    actions = rollout(CHUNKS).actions
    assert actions is not None
    stream = detector.stream()
    assert stream.history == ActionConsistency.history == 1
    assert stream.update(0, actions[0]) == 0.0
    stream.skip_to(2)  # step 1 lost: no previous chunk for step 2
    assert stream.update(2, actions[2]) == 0.0
    with pytest.raises(StepOrderError, match="expected policy step 3, got 2"):
        stream.update(2, actions[2])
    stream.reset()
    assert [stream.update(t, a) for t, a in enumerate(actions)] == BY_HAND


def test_a_rejected_batch_leaves_the_stream_as_it_was(detector: ActionConsistency) -> None:
    actions = rollout(CHUNKS).actions
    assert actions is not None
    stream = detector.stream()
    stream.update(0, actions[0])
    bad = actions[1].copy()
    bad[1, 0, 0] = np.nan  # also in a sample that is not executed: the producer is broken
    with pytest.raises(ConsistencyError, match="NaN/inf"):
        stream.update(1, bad)
    assert stream.next_step == 1
    assert stream.update(1, actions[1]) == BY_HAND[1]  # the previous chunk is still step 0's


@pytest.mark.parametrize(("actions", "message"), [
    (np.zeros((2, 3)), r"^actions must have shape \(B, 3, 2\) with no empty axis, got \(2, 3\)$"),
    (np.zeros((0, 3, 2)), r"no empty axis, got \(0, 3, 2\)"),
    (np.zeros((2, 4, 2)), r"got \(2, 4, 2\)"),
    (np.zeros((2, 3, 3)), r"got \(2, 3, 3\)"),
    (np.full((1, 3, 2), np.inf), "NaN/inf"),
    (np.full((1, 3, 2), "x"), "not numbers"),
])
def test_malformed_batches_are_refused_in_one_line(detector: ActionConsistency, actions: np.ndarray,
                                                   message: str) -> None:
    with pytest.raises(ConsistencyError, match=message) as error:
        detector.stream().update(0, actions)
    assert "\n" not in str(error.value)
    with pytest.raises(ConsistencyError, match=r"shape \(T, B, 3, 2\) with no empty axis"):
        detector.scores(np.zeros((0, 1, 3, 2)))


def test_fits_without_successes_or_actions_are_refused() -> None:
    with pytest.raises(ConsistencyError, match="none given"):
        ActionConsistency.fit([rollout(CHUNKS, success=False)])
    no_actions = Rollout("n", "toy", "id", np.zeros((2, 1)), None, 1, True)
    with pytest.raises(ConsistencyError, match="needs action batches"):
        ActionConsistency.fit([FIT, no_actions])
    with pytest.raises(ConsistencyError, match="different layouts"):
        ActionConsistency.fit([FIT, rollout(CHUNKS, exec_steps=2)])
    with pytest.raises(ConsistencyError, match=r"scale_floor must be in \(0, 1\]"):
        ConsistencySettings(scale_floor=0.0)


def test_overflow_is_refused() -> None:
    detector = ActionConsistency.fit([rollout(FIT.actions[:, 0] * 1e-30)])  # type: ignore[index]
    probe = np.zeros((2, 1, 3, 2))
    probe[1, 0, 0, 0] = 1e300  # finite float64 input, (1e300 / 1e-30)^2 is not
    with pytest.raises(ConsistencyError, match="overflows float64"):
        detector.scores(probe)


def test_save_and_load_keep_the_model_and_its_scores(tmp_path: Path) -> None:
    detector = ActionConsistency.fit([FIT], ConsistencySettings(action_dims=(0, 2), scale_floor=0.2))
    detector.save(tmp_path)
    loaded = ActionConsistency.load(tmp_path)
    assert loaded.digest() == detector.digest()
    assert loaded.settings == detector.settings
    probe = np.random.default_rng(0).normal(size=(9, 2, 3, 2))
    assert np.array_equal(loaded.scores(probe), detector.scores(probe))
    assert ActionConsistency.fit([FIT]).digest() != detector.digest()  # the settings are in the digest
    with pytest.raises(ConsistencyError, match="missing"):
        ActionConsistency.load(tmp_path / "nowhere")
