"""The step order of a detector's streaming form: policy steps ``0, 1, 2, ...`` of one rollout, lost ones
declared.

A detector's streaming form (:class:`StepStream` subclass) scores one policy step at a time and gives the
scores of its whole-rollout form bit for bit. It takes the steps in order after every :meth:`StepStream.reset`;
a gap or a repeat raises :class:`StepOrderError`, unless the caller declared the lost steps with
:meth:`StepStream.skip_to`. :attr:`StepStream.history` says how many earlier steps a score reads: the scores of
the ``history`` steps after a lost one lack their input (the caller marks them incomplete).
"""

from __future__ import annotations

from typing import ClassVar

from fiper_ros.core.errors import CoreError


class StepOrderError(CoreError):
    """A policy step out of order (a gap not declared with ``skip_to``, a repeat, a step of another rollout)."""


class StepStream:
    """Step bookkeeping of a detector's streaming form: a subclass's ``update`` checks its input and the step
    (:meth:`_expect`), scores, keeps what later steps need and calls :meth:`_advance`; :meth:`_forget` drops what
    it keeps of earlier steps."""

    #: How many earlier policy steps a score reads (0: the step's own input only).
    history: ClassVar[int] = 0

    def __init__(self) -> None:
        self._next = 0

    @property
    def next_step(self) -> int:
        """The policy step ``update`` expects next."""
        return self._next

    def reset(self) -> None:
        """Start a new rollout at step 0, with nothing of the previous one kept."""
        self._next = 0
        self._forget()

    def skip_to(self, step: int) -> None:
        """Declare the steps from :attr:`next_step` up to ``step - 1`` lost (their input missing or rejected):
        the next ``update`` is ``step``, and nothing of a step before the gap is kept. O(1) however large the
        gap; a ``step`` not after :attr:`next_step` changes nothing."""
        if step > self._next:
            self._next = int(step)
            self._forget()

    def _expect(self, step: int) -> None:
        """Refuse a ``step`` other than the expected one (before the step is scored)."""
        if step != self._next:
            raise StepOrderError(f"expected policy step {self._next}, got {step} (skip_to() declares lost steps, "
                                 "reset() starts a new rollout)")

    def _advance(self) -> None:
        """The expected step was scored: expect the next one. Called last, so that a step whose input is
        rejected leaves the stream as it was."""
        self._next += 1

    def _forget(self) -> None:
        """Drop what is kept of earlier steps (nothing here)."""
