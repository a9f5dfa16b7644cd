"""Checks of incoming arrays: a bad message is rejected with a reason, never passed on silently."""
from __future__ import annotations

import array
import math
from collections.abc import Sequence

import numpy as np

from fiper_ros.errors import FiperError

#: Rejection reasons, the keys of the nodes' "rejected" diagnostics.
SHAPE = "shape"
NON_FINITE = "non_finite"
OVERSIZE = "oversize"
CALIBRATION_MISMATCH = "calibration_mismatch"
NO_CALIBRATION = "no_calibration"
UNKNOWN_ROLLOUT = "unknown_rollout"
DUPLICATE_STEP = "duplicate_step"
OUT_OF_ORDER_STEP = "out_of_order_step"
NEGATIVE_STEP = "negative_step"
ACTION_SPACE = "action_space"
NO_JOINT_STATE = "no_joint_state"
INTERNAL = "internal_error"
ENCODING = "encoding"
#: A robot command while the previous one still executes (the sim bridge).
BUSY = "busy"
OUT_OF_RANGE = "out_of_range"
NON_FINITE_SCORE = "non_finite_score"
UNKNOWN_DETECTOR = "unknown_detector"
SIGNAL_MISSING = "signal_missing"
STEP_GAP = "step_gap"
BEYOND_MAX_STEPS = "beyond_max_steps"
TASK_MISMATCH = "task_mismatch"
#: Bytes on a topic that are not a message of its type (fiper_ros.interface.cdr could not read them).
MALFORMED = "malformed"
REASONS = (
    SHAPE, NON_FINITE, OVERSIZE, CALIBRATION_MISMATCH, NO_CALIBRATION, UNKNOWN_ROLLOUT, BUSY,
    DUPLICATE_STEP, OUT_OF_ORDER_STEP, NEGATIVE_STEP, ACTION_SPACE, NO_JOINT_STATE, INTERNAL, ENCODING,
    OUT_OF_RANGE, NON_FINITE_SCORE, UNKNOWN_DETECTOR, STEP_GAP, BEYOND_MAX_STEPS, TASK_MISMATCH, MALFORMED,
    SIGNAL_MISSING,
)
#: The one image encoding the policies take (sensor_msgs/Image ``encoding``).
RGB8 = "rgb8"

#: Default cap on the number of floats in one message (256 x 64 x 64 actions, or a 4M embedding).
DEFAULT_MAX_ELEMENTS = 1 << 22
#: Default cap on the steps a rollout may jump forward at once (a gap of lost or skipped steps).
DEFAULT_MAX_STEP_GAP = 100
#: Default cap on the values waiting for their rollout's START (8 messages of the largest size).
DEFAULT_MAX_PENDING_ELEMENTS = 8 * DEFAULT_MAX_ELEMENTS
#: Default cap on the magnitude of an embedding or action value. Policies' embeddings and actions are of
#: order 1-100; far larger values are a fault, and the bound keeps every score finite in float32.
DEFAULT_MAX_ABS_VALUE = 1e6


class InputRejected(FiperError):
    """A message that must not be scored; ``reason`` is one of :data:`REASONS`."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


def _finite(values: np.ndarray, what: str) -> np.ndarray:
    if not np.isfinite(values).all():
        bad = int(values.size - np.count_nonzero(np.isfinite(values)))
        raise InputRejected(NON_FINITE, f"{what} has {bad} NaN/inf value(s)")
    return values


def _bounded(values: np.ndarray, max_abs_value: float, what: str) -> np.ndarray:
    """``values`` (finite) if every magnitude is at most ``max_abs_value``, else :class:`InputRejected`."""
    largest = float(np.max(np.abs(values))) if values.size else 0.0
    if largest > max_abs_value:
        raise InputRejected(OUT_OF_RANGE, f"{what} has a value of magnitude {largest:g} > max_abs_value={max_abs_value:g}")
    return values


def _checked(values: np.ndarray, max_abs_value: float, what: str) -> np.ndarray:
    """``values`` if every one is finite and of magnitude at most ``max_abs_value``, else :class:`InputRejected`
    (``non_finite`` before ``out_of_range``). Two reductions decide a valid array (a NaN fails both comparisons,
    an infinity one); only a rejected one is looked at again to say why (the two checks took four
    passes and two temporary arrays per message)."""
    if values.size and not (math.isfinite(max_abs_value) and -max_abs_value <= values.min()
                            and values.max() <= max_abs_value):
        _bounded(_finite(values, what), max_abs_value, what)
    return values


def _size(n: int, max_elements: int, what: str) -> None:
    if n > max_elements:
        raise InputRejected(OVERSIZE, f"{what} has {n} values, more than max_elements={max_elements}")


def embedding(data: Sequence[float] | np.ndarray, shape: Sequence[int], expected_dim: int | None,
              max_elements: int = DEFAULT_MAX_ELEMENTS, max_abs_value: float = DEFAULT_MAX_ABS_VALUE) -> np.ndarray:
    """Return the embedding as a flat float array, or raise :class:`InputRejected`.

    ``shape`` is the declared shape (empty: flat); ``expected_dim`` the calibration's embedding size
    (``None``: no calibration loaded, which is itself a rejection).
    """
    values = np.asarray(data, dtype=np.float32)
    _size(values.size, max_elements, "embedding")
    declared = math.prod(int(d) for d in shape) if len(shape) else values.size  # exact: np.prod wraps in int64
    if values.ndim != 1 or declared != values.size or any(int(d) <= 0 for d in shape):
        raise InputRejected(SHAPE, f"embedding has {values.size} values but declares shape {list(shape)}")
    if values.size == 0:
        raise InputRejected(SHAPE, "embedding is empty")
    if expected_dim is None:
        raise InputRejected(NO_CALIBRATION, "no calibration loaded")
    if values.size != expected_dim:
        raise InputRejected(CALIBRATION_MISMATCH, f"embedding dim {values.size} != calibration's {expected_dim}")
    return _checked(values, max_abs_value, "embedding")


def action_batch(data: Sequence[float] | np.ndarray, batch_size: int, horizon: int, action_dim: int,
                 exec_steps: int, max_elements: int = DEFAULT_MAX_ELEMENTS,
                 max_abs_value: float = DEFAULT_MAX_ABS_VALUE) -> np.ndarray:
    """Return the batch as a float array ``[B, H, D]``, or raise :class:`InputRejected`.

    Checks only the message's own consistency; compatibility with a calibration is the caller's
    check (it may map joint-space actions to end-effector positions first).
    """
    values = np.asarray(data, dtype=np.float32)
    _size(values.size, max_elements, "action batch")
    if min(batch_size, horizon, action_dim) <= 0:
        raise InputRejected(SHAPE, f"declared B x H x D = {batch_size} x {horizon} x {action_dim} has a zero size")
    if values.size != batch_size * horizon * action_dim:
        raise InputRejected(
            SHAPE, f"{values.size} values for declared B x H x D = {batch_size} x {horizon} x {action_dim}"
        )
    if not 0 < exec_steps <= horizon:
        raise InputRejected(SHAPE, f"exec_steps {exec_steps} outside 1..H={horizon}")
    return _checked(values.reshape(batch_size, horizon, action_dim), max_abs_value,
                    "action batch")


def vector(data: Sequence[float] | np.ndarray, size: int, what: str, max_abs_value: float = DEFAULT_MAX_ABS_VALUE,
           dtype: type[np.floating] = np.float32) -> np.ndarray:
    """Return ``data`` as a ``dtype`` vector of exactly ``size`` finite values of magnitude at most
    ``max_abs_value``, or raise :class:`InputRejected`."""
    values = np.asarray(data, dtype=dtype)
    if values.shape != (size,):
        raise InputRejected(SHAPE, f"{what} has {values.size} values, expected {size}")
    return _checked(values, max_abs_value, what)


def signal(names: Sequence[str], values: Sequence[float] | np.ndarray, name: str,
           max_elements: int = DEFAULT_MAX_ELEMENTS, max_abs_value: float = DEFAULT_MAX_ABS_VALUE) -> float:
    """The value of signal ``name`` among a step's logged ``names`` / ``values``, or raise :class:`InputRejected`:
    more values than ``max_elements``, names and values that do not pair up, the signal missing, a value that is
    not finite or of magnitude above ``max_abs_value``."""
    _size(max(len(names), len(values)), max_elements, "step signals")
    if len(names) != len(values):
        raise InputRejected(SHAPE, f"step signals have {len(names)} names and {len(values)} values")
    try:
        index = list(names).index(name)
    except ValueError:
        shown = ", ".join(sorted(map(str, names))[:8]) or "none"
        raise InputRejected(SIGNAL_MISSING, f"step signals lack {name!r} (they have {shown})") from None
    return float(_checked(np.asarray([values[index]], dtype=np.float64), max_abs_value, f"signal {name}")[0])


def rgb8_image(data: bytes | array.array, height: int, width: int, encoding: str, step: int,
               expected: tuple[int, int], what: str) -> np.ndarray:
    """Return an ``rgb8`` image as a uint8 array ``[height, width, 3]`` (rows may be padded to ``step``).

    Raises :class:`InputRejected`: ``encoding`` for any other encoding, ``shape`` when the size is not
    ``expected`` (height, width) or ``data`` / ``step`` disagree with it.
    """
    if encoding != RGB8:
        raise InputRejected(ENCODING, f"{what} has encoding {encoding!r}, expected {RGB8!r}")
    if (height, width) != expected:
        raise InputRejected(SHAPE, f"{what} is {height}x{width}, expected {expected[0]}x{expected[1]}")
    if step < 3 * width or len(data) != height * step:
        raise InputRejected(SHAPE, f"{what} has {len(data)} bytes with step {step} for {height}x{width} rgb8")
    rows = np.frombuffer(data, dtype=np.uint8).reshape(height, step)
    return rows[:, : 3 * width].reshape(height, width, 3)
