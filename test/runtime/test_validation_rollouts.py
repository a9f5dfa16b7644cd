"""Input validation and rollout tracking of the node shells (no DDS)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fiper_ros.runtime import validation
from fiper_ros.runtime.rollout_tracker import RolloutTracker
from fiper_ros.runtime.validation import InputRejected


def _reason(call) -> str:  # noqa: ANN001
    with pytest.raises(InputRejected) as info:
        call()
    return info.value.reason


def test_embedding_accepts_a_well_formed_vector() -> None:
    out = validation.embedding(np.arange(4, dtype=np.float32), [4], 4)
    assert out.dtype == np.float32 and out.tolist() == [0, 1, 2, 3]


@pytest.mark.parametrize(
    ("data", "shape", "dim", "reason"),
    [
        ([1.0, 2.0, 3.0], [4], 3, validation.SHAPE),
        ([1.0, 2.0, 3.0], [3], 4, validation.CALIBRATION_MISMATCH),
        ([1.0, float("nan"), 3.0], [3], 3, validation.NON_FINITE),
        ([1.0, float("inf"), 3.0], [3], 3, validation.NON_FINITE),
        ([1.0, 2.0, 3.0], [3], None, validation.NO_CALIBRATION),
        ([], [], 3, validation.SHAPE),
        ([1.0, 2.0], [2, 0], 2, validation.SHAPE),
    ],
)
def test_embedding_rejections(data: list[float], shape: list[int], dim: int | None, reason: str) -> None:
    assert _reason(lambda: validation.embedding(data, shape, dim)) == reason


def test_a_declared_shape_whose_product_overflows_int64_is_rejected() -> None:
    # Found by test/nodes/test_fuzz.py: np.prod wrapped this shape's product (about 1.2e21) to exactly 16 in
    # int64, so 16 values with this declared shape were scored as a valid embedding.
    shape = [16, 3702849463, 793907557, 251]
    assert int(np.prod(np.asarray(shape, dtype=np.uint32))) == 16
    assert _reason(lambda: validation.embedding(np.zeros(16, np.float32), shape, 16)) == validation.SHAPE


def test_oversize_is_rejected_before_anything_else() -> None:
    assert _reason(lambda: validation.embedding(np.zeros(11), [11], 11, max_elements=10)) == validation.OVERSIZE
    assert _reason(lambda: validation.action_batch(np.zeros(12), 2, 2, 3, 1, max_elements=10)) == validation.OVERSIZE


def test_action_batch_reshapes_row_major() -> None:
    out = validation.action_batch(np.arange(12, dtype=np.float32), 2, 3, 2, 1)
    assert out.shape == (2, 3, 2) and out[1, 0, 1] == 7


@pytest.mark.parametrize(
    ("n", "b", "h", "d", "exec_steps", "reason"),
    [
        (11, 2, 3, 2, 1, validation.SHAPE),
        (12, 2, 3, 2, 0, validation.SHAPE),
        (12, 2, 3, 2, 4, validation.SHAPE),
        (0, 0, 3, 2, 1, validation.SHAPE),
    ],
)
def test_action_batch_rejections(n: int, b: int, h: int, d: int, exec_steps: int, reason: str) -> None:
    assert _reason(lambda: validation.action_batch(np.zeros(n), b, h, d, exec_steps)) == reason


def test_action_batch_rejects_nan() -> None:
    data = np.zeros(12)
    data[5] = np.nan
    assert _reason(lambda: validation.action_batch(data, 2, 3, 2, 1)) == validation.NON_FINITE


def test_tracker_orders_steps_within_the_active_rollout() -> None:
    tracker = RolloutTracker()
    assert _reason(lambda: tracker.admit(1, 0)) == validation.UNKNOWN_ROLLOUT
    tracker.start(1)
    record, started = tracker.admit(1, 0)
    assert not started and record.steps == 1
    assert _reason(lambda: tracker.admit(1, 0)) == validation.DUPLICATE_STEP
    tracker.admit(1, 3)
    assert record.gaps == 2
    assert _reason(lambda: tracker.admit(1, 2)) == validation.OUT_OF_ORDER_STEP
    assert _reason(lambda: tracker.admit(1, -1)) == validation.NEGATIVE_STEP
    assert _reason(lambda: tracker.admit(2, 4)) == validation.UNKNOWN_ROLLOUT
    ended = tracker.end(1, "failure")
    assert ended is record and "2 steps, 2 missing" in record.summary() and "outcome failure" in record.summary()
    assert tracker.active is None and tracker.end(1, "success") is None
    # The END can overtake the rollout's last step (topics are not ordered): that step is still admitted,
    # in order, until the next START.
    late, _ = tracker.admit(1, 4)
    assert late is record and record.steps == 3
    assert _reason(lambda: tracker.admit(1, 4)) == validation.DUPLICATE_STEP
    tracker.start(2)
    assert _reason(lambda: tracker.admit(1, 5)) == validation.UNKNOWN_ROLLOUT


def test_tracker_auto_start_takes_a_new_rollout_id() -> None:
    tracker = RolloutTracker(auto_start=True)
    record, started = tracker.admit(9, 0)
    assert started and record.rollout_id == 9
    record2, started2 = tracker.admit(10, 0)
    assert started2 and record2.rollout_id == 10 and record2 is not record


def test_rgb8_images_are_checked() -> None:
    pixels = np.arange(4 * 5 * 3, dtype=np.uint8)
    image = validation.rgb8_image(pixels.tobytes(), 4, 5, "rgb8", 15, (4, 5), "wrist_rgb")
    assert image.shape == (4, 5, 3) and image.dtype == np.uint8 and image[1, 0, 0] == 15
    padded = np.zeros((4, 16), np.uint8)
    padded[:, :15] = pixels.reshape(4, 15)
    np.testing.assert_array_equal(validation.rgb8_image(padded.tobytes(), 4, 5, "rgb8", 16, (4, 5), "x"), image)
    def reason(data: bytes, encoding: str = "rgb8", step: int = 15, expected: tuple[int, int] = (4, 5)) -> str:
        return _reason(lambda: validation.rgb8_image(data, 4, 5, encoding, step, expected, "x"))

    assert reason(pixels.tobytes(), encoding="bgr8") == validation.ENCODING
    assert reason(pixels.tobytes(), expected=(5, 5)) == validation.SHAPE
    assert reason(pixels[:-1].tobytes()) == validation.SHAPE
    assert reason(pixels.tobytes(), step=12) == validation.SHAPE


def test_vectors_are_checked() -> None:
    assert validation.vector([1.0, 2.0], 2, "proprio").dtype == np.float32
    assert _reason(lambda: validation.vector([1.0, 2.0, 3.0], 2, "proprio")) == validation.SHAPE
    assert _reason(lambda: validation.vector([1.0, float("nan")], 2, "proprio")) == validation.NON_FINITE


def test_a_step_jump_beyond_max_step_gap_is_rejected_and_changes_nothing() -> None:
    # Issue #18: one message with step 4294967295 sent the RND-OE node into 4e9 window pushes.
    tracker = RolloutTracker(max_step_gap=3)
    tracker.start(1)
    tracker.admit(1, 0)
    assert _reason(lambda: tracker.admit(1, 2**32 - 1)) == validation.STEP_GAP
    assert _reason(lambda: tracker.admit(1, 5)) == validation.STEP_GAP   # 4 missing steps > 3
    record, _ = tracker.admit(1, 4)                                       # 3 missing: accepted
    assert record.last_step == 4 and record.gaps == 3 and record.steps == 2
    auto = RolloutTracker(auto_start=True, max_step_gap=3)
    assert _reason(lambda: auto.admit(9, 4)) == validation.STEP_GAP and auto.current is None
    assert auto.admit(9, 3)[1]


def test_a_step_beyond_the_rollouts_max_steps_is_rejected() -> None:
    tracker = RolloutTracker()
    tracker.start(1, max_steps=5)
    tracker.admit(1, 4)
    assert _reason(lambda: tracker.admit(1, 5)) == validation.BEYOND_MAX_STEPS
    tracker.start(2)  # max_steps 0: not known, no bound but the gap
    assert tracker.admit(2, 50)[0].last_step == 50


def _two_checks(values: np.ndarray, max_abs: float) -> str:
    """The verdict of the checks as they were before issue #24: finiteness, then the bound, each on its own."""
    if not np.isfinite(values).all():
        return validation.NON_FINITE
    if values.size and float(np.max(np.abs(values))) > max_abs:
        return validation.OUT_OF_RANGE
    return "ok"


_VALUES = st.lists(st.one_of(st.floats(width=32), st.sampled_from([math.nan, math.inf, -math.inf, 1e6, -1e6])),
                   max_size=12)


@settings(max_examples=400, deadline=None, derandomize=True, database=None)
@given(_VALUES, st.sampled_from([1.0, 1e6, 3.4e38, math.inf]), st.sampled_from([np.float32, np.float64]))
def test_the_one_pass_check_says_what_the_two_checks_said(values: list[float], max_abs: float, dtype: type) -> None:
    array = np.asarray(values, dtype=dtype)
    try:
        validation._checked(array, max_abs, "values")
        verdict = "ok"
    except InputRejected as error:
        verdict = error.reason
    assert verdict == _two_checks(array, max_abs)
