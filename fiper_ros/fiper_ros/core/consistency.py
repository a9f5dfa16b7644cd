"""Single-sample action consistency: how much the executed chunk changes its plan from one policy step to the next.

For a policy that samples one chunk per step (or any number: only the executed one is read), the robot executes
the first ``h`` actions of sample 0 of the batch ``A_t [B, H, D]`` (``fiper_ros.policy.session``). Consecutive
executed chunks overlap in ``H - h`` environment steps: ``A_t[0, i]`` and ``A_{t-1}[0, i + h]`` plan the same
step, ``i = 0 .. H-h-1``. A policy that stays on its plan agrees with itself there; one that hesitates, switches
modes or is out of distribution does not. Unlike STAC (:mod:`fiper_ros.baselines.stac`), which compares the
distributions of ``B`` samples, this needs no batch.

Score at policy step ``t >= 1`` (the selected action channels ``d``, ``h = exec_steps``)::

    s(t) = mean over i = 0..H-h-1 and d of ((A_t[0, i, d] - A_{t-1}[0, i + h, d]) / scale_d)^2

and ``s(0) = 0`` (no previous chunk). ``scale_d`` is the standard deviation of channel ``d`` over every action of
sample 0 (all ``H`` steps of every step's chunk) of the successful fit rollouts: the channels' units do not weigh
in. It is floored at ``scale_floor`` (default 0.1) times the mean of the channels' standard deviations: a channel
that is (nearly) constant over the successes (a gripper held closed) would otherwise turn a deviation of rounding
size into a large score, or divide by zero; the floor limits any channel's weight to ``1 / scale_floor^2`` times
that of a channel of mean scale. Fit data whose selected channels are all constant is refused (no scale). Like
``s_ACE`` the score is aggregated over a window (eqs. 2, 5) and compared with a conformal threshold.

The whole-rollout form (:meth:`ActionConsistency.scores`) and the streaming form (:class:`ConsistencyStream`)
score with the same function, bit for bit. The streaming form reads one previous step (:attr:`history` 1):
after a lost step (``skip_to``) or a ``reset`` it has no previous chunk and its next score is 0, which the caller
marks incomplete. Per-step cost ``O(H D)`` (plus the finiteness check of the ``B H D`` batch). Stored as
``consistency.json`` + ``consistency.npz`` (:mod:`fiper_ros.core.detector_model`), read with numpy only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, ClassVar

import numpy as np

from fiper_ros.core.detector_model import StoredModel, check_input
from fiper_ros.core.errors import CoreError
from fiper_ros.core.rollout import Rollout, successful
from fiper_ros.core.step_stream import StepStream


class ConsistencyError(CoreError):
    """Bad input to the consistency detector (shape, NaN/inf, no overlap), bad settings or no successes."""


@dataclass(frozen=True)
class ConsistencySettings:
    """Settings of the action-consistency detector.

    Attributes:
        action_dims: ``(start, stop)`` of the action channels compared, as ACE's (``None``: all channels).
        scale_floor: Each channel's scale is at least this fraction of the mean scale, in (0, 1].
    """

    action_dims: tuple[int, int] | None = None
    scale_floor: float = 0.1

    def __post_init__(self) -> None:
        if self.action_dims is not None:
            start, stop = self.action_dims
            if not 0 <= start < stop:
                raise ConsistencyError(f"action_dims (start, stop) must have 0 <= start < stop, got {self.action_dims}")
        if not 0.0 < self.scale_floor <= 1.0:
            raise ConsistencyError(f"scale_floor must be in (0, 1], got {self.scale_floor}")

    def to_dict(self) -> dict[str, Any]:
        """Plain data (a list for ``action_dims``)."""
        return {**asdict(self), "action_dims": None if self.action_dims is None else list(self.action_dims)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ConsistencySettings:
        """Inverse of :meth:`to_dict`."""
        dims = data.get("action_dims")
        return cls(**{**data, "action_dims": None if dims is None else tuple(dims)})


def check_overlap(exec_steps: int, horizon: int) -> None:
    """Refuse a layout in which consecutive executed chunks do not overlap: the detector needs ``1 <= h < H``."""
    if not 1 <= exec_steps < horizon:
        raise ConsistencyError(f"action consistency needs 1 <= h < H for an overlap, got h={exec_steps}, H={horizon}")


class ActionConsistency(StoredModel):
    """A fitted action-consistency detector (see the module docstring): the layout ``h``, ``H``, ``D`` and the
    per-channel ``scale``. Made by :meth:`fit` or :meth:`load` (``consistency.json`` + ``consistency.npz``, written
    by :meth:`save`); immutable."""

    name: ClassVar[str] = "consistency"
    format_version: ClassVar[int] = 1
    error: ClassVar[type[ValueError]] = ConsistencyError
    #: A score reads one previous policy step (its executed chunk).
    history: ClassVar[int] = 1

    def __init__(self, settings: ConsistencySettings, exec_steps: int, horizon: int, action_dim: int,
                 scale: np.ndarray) -> None:
        check_overlap(exec_steps, horizon)
        start, stop = settings.action_dims or (0, action_dim)
        if stop > action_dim:
            raise ConsistencyError(f"action_dims {settings.action_dims} exceed the {action_dim} action channels")
        scale = np.asarray(scale, dtype=np.float64)
        if scale.shape != (stop - start,) or not (np.isfinite(scale).all() and (scale > 0).all()):
            raise ConsistencyError(f"scale must be {stop - start} finite positive values, got {scale}")
        self.settings = settings
        self.exec_steps, self.horizon, self.action_dim = int(exec_steps), int(horizon), int(action_dim)
        self.scale = scale
        self._channels = slice(start, stop)

    @classmethod
    def fit(cls, rollouts: Sequence[Rollout], settings: ConsistencySettings | None = None) -> ActionConsistency:
        """Fit on the rollouts with ``success is True`` (others are ignored; at least one, all with action batches
        of one layout ``h``, ``H``, ``D``): the per-channel scale of their sample-0 actions. Deterministic."""
        settings = settings or ConsistencySettings()
        good = successful(list(rollouts))
        if not good:
            raise ConsistencyError("the consistency detector is fitted on successful rollouts: none given")
        if any(r.actions is None for r in good):
            raise ConsistencyError("the consistency detector needs action batches: a success has none")
        layouts = {(r.exec_steps, *r.actions.shape[2:]) for r in good}  # type: ignore[union-attr]
        if len(layouts) != 1:
            raise ConsistencyError(f"the successes have different layouts (h, H, D): {sorted(layouts)}")
        exec_steps, horizon, action_dim = layouts.pop()
        check_overlap(exec_steps, horizon)
        start, stop = settings.action_dims or (0, action_dim)
        if stop > action_dim:
            raise ConsistencyError(f"action_dims {settings.action_dims} exceed the {action_dim} action channels")
        executed = np.concatenate([r.actions[:, 0, :, start:stop].reshape(-1, stop - start)  # type: ignore[index]
                                   for r in good]).astype(np.float64)
        spread = executed.std(axis=0)
        mean_scale = float(spread.mean())
        if not mean_scale > 0.0 or not math.isfinite(mean_scale):
            raise ConsistencyError(f"every selected action channel ({start}:{stop}) is constant over the successes "
                                   "(or beyond float64): no scale to compare with")
        return cls(settings, exec_steps, horizon, action_dim, np.maximum(spread, settings.scale_floor * mean_scale))

    def _executed(self, batch: np.ndarray) -> np.ndarray:
        """The executed chunk of a checked batch ``[B, H, D]``: sample 0, the selected channels, float64."""
        return np.asarray(batch[0, :, self._channels], dtype=np.float64)

    def _score(self, previous: np.ndarray | None, current: np.ndarray) -> float:
        """``s(t)`` of the executed chunks of steps ``t - 1`` and ``t`` (0 without a previous one): the one
        scoring function of both forms."""
        if previous is None:
            return 0.0
        overlap = self.horizon - self.exec_steps
        with np.errstate(over="ignore", invalid="ignore"):
            score = float(np.mean(np.square((current[:overlap] - previous[self.exec_steps:]) / self.scale)))
        if not math.isfinite(score):
            raise ConsistencyError("the chunks' difference overflows float64")
        return score

    def _check(self, actions: np.ndarray, lead: tuple[str, ...]) -> np.ndarray:
        return check_input(actions, (*lead, "B", self.horizon, self.action_dim), "actions", ConsistencyError)

    def scores(self, actions: np.ndarray) -> np.ndarray:
        """``s(t)`` ``[T]`` (float64; ``s(0) = 0``) of a whole rollout's action batches ``[T, B, H, D]``."""
        actions = self._check(actions, ("T",))
        scores = np.empty(actions.shape[0], dtype=np.float64)
        previous = None
        for t, batch in enumerate(actions):
            current = self._executed(batch)
            scores[t] = self._score(previous, current)
            previous = current
        return scores

    def stream(self) -> ConsistencyStream:
        """A streaming form of this detector, at step 0."""
        return ConsistencyStream(self)

    def describe(self) -> dict[str, Any]:
        """Settings and the action layout (the JSON description of the model)."""
        return {"settings": self.settings.to_dict(), "exec_steps": self.exec_steps, "horizon": self.horizon,
                "action_dim": self.action_dim}

    def arrays(self) -> dict[str, np.ndarray]:
        """The fitted array: ``scale [D_selected]``."""
        return {"scale": self.scale}

    @classmethod
    def from_stored(cls, description: dict[str, Any], arrays: dict[str, np.ndarray]) -> ActionConsistency:
        """The detector of a :meth:`describe` output and its :meth:`arrays` (:meth:`load` reads them)."""
        return cls(ConsistencySettings.from_dict(description["settings"]), description["exec_steps"],
                   description["horizon"], description["action_dim"], arrays["scale"])


class ConsistencyStream(StepStream):
    """The streaming form: :meth:`update` scores policy steps ``0, 1, 2, ...`` of one rollout, keeping the last
    executed chunk; after :meth:`reset` or a lost step (:meth:`skip_to`) it has none and the next score is 0
    (:attr:`history` 1: the caller marks that score incomplete)."""

    history: ClassVar[int] = ActionConsistency.history

    def __init__(self, detector: ActionConsistency) -> None:
        super().__init__()
        self.detector = detector
        self._previous: np.ndarray | None = None

    def update(self, step: int, actions: np.ndarray) -> float:
        """``s(step)`` of the action batch ``[B, H, D]`` of policy step ``step`` (the expected one)."""
        detector = self.detector
        current = detector._executed(detector._check(actions, ()))  # noqa: SLF001 - the functions of both forms
        self._expect(step)
        score = detector._score(self._previous, current)  # noqa: SLF001
        self._previous = current.copy()
        self._advance()
        return score

    def _forget(self) -> None:
        self._previous = None
