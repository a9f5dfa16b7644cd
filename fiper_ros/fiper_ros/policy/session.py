"""A policy acting in a robot driver's rollouts, without ROS: the logic of the ROS ``policy_node``.

The driver (the sim bridge, docs/sim.md) announces a rollout with a RolloutEvent START stamped like
the rollout's first observation, publishes one complete observation (a "tick") per policy step and
waits for the command computed from it, and announces the END. For each complete tick the session
decides:

- **act**: the tick is stamped at or after the running rollout's START. It joins the rollout's last
  ``T_h`` ticks; :meth:`PolicySession.begin` takes the step and :meth:`PolicySession.compute` samples
  the batch with the rollout's noise stream
  (:func:`~fiper_ros.policy.noise.sampling_generator` of the seed in the rollout id's low 32 bits, as
  the in-process ``run_episode(seed)`` does) and numbers the step 0, 1, 2, ... within the rollout;
- **late** (ignored, counted): the tick belongs to the rollout that ended last (stamped within its
  START..END), e.g. one that overtook that rollout's END;
- **wait**: no rollout runs. Events and observations travel on different topics, so a rollout's
  first tick may overtake its START: the newest such tick waits up to ``start_wait_ns`` for it;
- **unknown rollout** (rejected): anything else, including a waiting tick whose START never came.

``T_h`` > 1: the history must hold consecutive control steps, as in training and the in-process
``run_episode``, not one tick per policy step. Each command therefore asks the driver for
:attr:`PolicySession.history_frames` more observations (ActionCommand ``observation_history``): those
of the control steps just before the next tick, which arrive before it on the same topics. They join
the history without a step; the observation after them is the tick acted on.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from ..runtime.validation import UNKNOWN_ROLLOUT, InputRejected
from .noise import sampling_generator
from .policy import Observation, Policy

#: How long a tick may wait for its rollout's START by default.
DEFAULT_START_WAIT_NS = 1_000_000_000


@dataclass
class PolicyRollout:
    """A rollout the policy acts (or acted) in."""

    rollout_id: int
    start_stamp: int
    history: deque[Observation]
    generator: torch.Generator
    task: str = ""
    scenario: str = ""
    #: Policy steps acted so far: the number of the next step.
    steps: int = 0
    #: Stamp of the newest observation in ``history``.
    last_stamp: int = 0
    #: Observations still to come before the next tick (asked for with the last command).
    history_due: int = 0
    end_stamp: int | None = None
    outcome: str = "unknown"

    def summary(self) -> str:
        """One line for the log at the rollout's END."""
        where = f" {self.task}/{self.scenario}" if self.task or self.scenario else ""
        return f"rollout {self.rollout_id}{where}: {self.steps} policy steps, outcome {self.outcome}"


@dataclass(frozen=True)
class PolicyStep:
    """A policy step taken from the running rollout, to be computed."""

    rollout_id: int
    step: int
    #: Stamp of the newest tick in ``history``.
    stamp: int
    history: tuple[Observation, ...]
    #: The rollout's noise stream (steps of one rollout are computed in order).
    generator: torch.Generator


@dataclass(frozen=True)
class PolicyAction:
    """What the policy computed from one tick."""

    rollout_id: int
    step: int
    #: Stamp of the tick the action was computed from.
    stamp: int
    #: ``O^e``, float32 ``[E]``.
    embedding: np.ndarray
    #: The sampled batch, float32 ``[B, H, D]``.
    chunks: np.ndarray
    #: What the robot executes: the first ``h`` actions of sample 0, ``[h, D]``.
    command: np.ndarray


@dataclass(frozen=True)
class _WaitingTick:
    """A tick that waits for its rollout's START, since ``since_ns`` (steady time)."""

    stamp: int
    observation: Observation
    since_ns: int


class PolicySession:
    """Follows START / END and turns the running rollout's ticks into policy steps.

    Args:
        policy: The loaded policy.
        batch: Chunks sampled per step (``None``: the config's ``B``).
        reject: Called with every rejected tick (the node counts and logs them).
        start_wait_ns: How long a tick waits for its rollout's START (steady time).
    """

    def __init__(self, policy: Policy, batch: int | None, reject: Callable[[InputRejected], None],
                 start_wait_ns: int = DEFAULT_START_WAIT_NS) -> None:
        self.policy = policy
        self.batch = batch
        self.reject = reject
        self.start_wait_ns = start_wait_ns
        self.running: PolicyRollout | None = None
        self.last_ended: PolicyRollout | None = None
        #: STARTs of new rollouts seen.
        self.rollouts_seen = 0
        #: Ticks of an ended rollout, ignored.
        self.late = 0
        self._waiting: _WaitingTick | None = None

    @property
    def history_frames(self) -> int:
        """Control-step observations a command asks for before its tick: ``T_h - 1``, at most ``h - 1``
        (those of the command's own control steps)."""
        config = self.policy.config
        return min(config.obs_horizon, config.exec_steps) - 1

    @property
    def waiting(self) -> bool:
        """Whether a tick waits for its rollout's START."""
        return self._waiting is not None

    def start(self, rollout_id: int, stamp: int, task: str = "", scenario: str = "") -> bool:
        """A START: the rollout runs from ``stamp`` on (fresh history, step 0, fresh noise stream).

        A repeated START of the running rollout changes nothing; a START while another rollout runs
        (its END was lost) ends that one at ``stamp``, outcome unknown. Returns whether to :meth:`act`
        now (a tick that overtook this START was waiting for it).
        """
        previous = self.running
        if previous is not None:
            if previous.rollout_id == rollout_id:
                return False
            previous.end_stamp = stamp
            self.last_ended = previous
        self.running = PolicyRollout(rollout_id, stamp, deque(maxlen=self.policy.config.obs_horizon),
                                     sampling_generator(rollout_id & 0xFFFFFFFF), task, scenario)
        self.rollouts_seen += 1
        waiting, self._waiting = self._waiting, None
        if waiting is None:
            return False
        return self._admit(waiting.stamp, waiting.observation)

    def end(self, rollout_id: int, stamp: int, outcome: str) -> PolicyRollout | None:
        """An END: stop acting in ``rollout_id``; returns it if it was the running rollout."""
        ended = self.running
        if ended is None or ended.rollout_id != rollout_id:
            return None
        ended.end_stamp = stamp
        ended.outcome = outcome
        self.running, self.last_ended = None, ended
        return ended

    def observe(self, stamp: int, observation: Observation, now_ns: int) -> bool:
        """A complete tick; returns whether to :meth:`act` on it now (see the module docstring)."""
        self.expire(now_ns)
        if self.running is not None:
            return self._admit(stamp, observation)
        if self._is_late(stamp):
            self.late += 1
            return False
        waiting = self._waiting
        if waiting is not None and waiting.stamp > stamp:
            self._discard(stamp)
            return False
        if waiting is not None:
            self._discard(waiting.stamp)
        self._waiting = _WaitingTick(stamp, observation, now_ns)
        return False

    def expire(self, now_ns: int) -> None:
        """Reject a tick that waited longer than ``start_wait_ns`` for its START."""
        if self._waiting is not None and now_ns - self._waiting.since_ns > self.start_wait_ns:
            waiting, self._waiting = self._waiting, None
            self._discard(waiting.stamp)

    def begin(self) -> PolicyStep:
        """Take the next step of the running rollout (after ``start`` / ``observe`` said to act): what
        :meth:`compute` needs, so that START / END may be followed while it runs."""
        rollout = self.running
        if rollout is None or not rollout.history:
            raise RuntimeError("a policy step needs a running rollout with an observation")
        step = PolicyStep(rollout.rollout_id, rollout.steps, rollout.last_stamp, tuple(rollout.history),
                          rollout.generator)
        rollout.steps += 1
        rollout.history_due = self.history_frames
        return step

    def compute(self, step: PolicyStep) -> PolicyAction:
        """Run the policy on ``step``'s history with its rollout's noise stream."""
        embedding, chunks = self.policy.act(list(step.history), self.batch, step.generator)
        return PolicyAction(step.rollout_id, step.step, step.stamp, embedding, chunks,
                            chunks[0, : self.policy.config.exec_steps])

    def is_running(self, rollout_id: int) -> bool:
        """Whether ``rollout_id`` is the running rollout (a step of one that ended meanwhile is not published)."""
        return self.running is not None and self.running.rollout_id == rollout_id

    def _admit(self, stamp: int, observation: Observation) -> bool:
        rollout = self.running
        assert rollout is not None
        if stamp < rollout.start_stamp:
            self._discard(stamp)
            return False
        rollout.history.append(observation)
        rollout.last_stamp = stamp
        if rollout.history_due > 0:
            rollout.history_due -= 1
            return False
        return True

    def _is_late(self, stamp: int) -> bool:
        ended = self.last_ended
        return ended is not None and ended.end_stamp is not None and ended.start_stamp <= stamp <= ended.end_stamp

    def _discard(self, stamp: int) -> None:
        if self._is_late(stamp):
            self.late += 1
            return
        running = "none" if self.running is None else str(self.running.rollout_id)
        self.reject(InputRejected(UNKNOWN_ROLLOUT, f"observation stamped {stamp} ns belongs to no known rollout "
                                                   f"(running: {running})"))
