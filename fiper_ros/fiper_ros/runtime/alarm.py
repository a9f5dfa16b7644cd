"""The fusion node's state machine: match the declared score streams per step, vote (eq. 7, generalised),
latch, and say UNKNOWN whenever a stream is missing, stale or uncalibrated.

The declared detectors are those of the calibration (:mod:`fiper_ros.core.calibration`): FIPER's pair, RND-OE
alone, or any set. A step alarms when at least the combine's votes of them exceed their thresholds
(:class:`fiper_ros.core.fusion.Combine`: all for AND, one for OR and max, K for kth:K). One detector alone is its
own decision and ``combine`` does not apply (the state's ``combine`` is empty and its reason says so); only the
declared streams are matched, checked for staleness and for liveliness.

Contract (docs/alarm-contract.md): one :class:`AlarmState` per policy step whose declared scores all
arrived; ALARM latches until :meth:`AlarmFuser.reset` or the next rollout START, and the latch wins over
everything that arrives after it (missing or infinite thresholds, stale streams, non-finite or
contradictory scores); UNKNOWN, never OK, while a stream is missing, older than ``deadline_ns``, carries
no finite threshold or score, or contradicts itself, and while the scores cannot be attributed to the
suite (:meth:`AlarmFuser.suspect`: an unexpected publisher on a score topic), for the rest of the rollout.

A step's exceedance is the detector's own decision (``Score.exceeded``, made in float64 by
:func:`fiper_ros.core.fusion.exceeds`), not a comparison of the float32 numbers the message carries:
rounding to float32 can turn ``eta > gamma`` into ``eta == gamma``, and the offline oracle decides in
float64. The float32 numbers still have to agree with it (:func:`decision`).

An ALARM says in one line what a person can act on (:func:`explanation`): which windowed scores exceeded,
by how much relative to their thresholds, and since which step each has exceeded without a break, e.g.
"RND-OE 1.9x threshold since step 10, ACE 1.05x since step 25: both exceeded (and)"; the steps after it
repeat that line behind "latched since step N: ".
"""
from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, replace

from fiper_ros.core.combine_mode import CombineMode
from fiper_ros.core.detectors import DETECTORS, check_once, info
from fiper_ros.core.fusion import Combine, exceeds, fuse_votes
from fiper_ros.interface.messages import NO_ROLLOUT, AlarmStateName
from fiper_ros.runtime.rollout_gate import RolloutGate
from fiper_ros.runtime.rollout_tracker import RolloutRecord
from fiper_ros.runtime.stats import PeriodEstimator

#: Longest requester or reason of a reset, in characters (what is logged stays one line of the log).
MAX_RESET_TEXT = 200
#: Ratios to a threshold from this on are said in whole numbers ("1000x", "1234x"); below it in 3 significant
#: digits ("1.05x", "12.3x", "999x"), which from here on would need an exponent.
WHOLE_RATIO = 999.5


def ratio_text(windowed: float, threshold: float) -> str:
    """How far ``windowed`` is from ``threshold``, for people: their ratio, ``"1.9x"`` (:data:`WHOLE_RATIO`), or,
    where a ratio says nothing (a threshold that is not a positive finite number, a non-finite score), both
    numbers: ``"0.5 > threshold 0"``."""
    if not (math.isfinite(windowed) and math.isfinite(threshold) and threshold > 0):
        return f"{windowed:.3g} > threshold {threshold:.3g}"
    ratio = windowed / threshold
    return f"{ratio:.0f}x" if ratio >= WHOLE_RATIO else f"{ratio:.3g}x"


def explanation(exceeded: list[tuple[str, float, float, int]], declared: int, how: str) -> str:
    """The one line of an ALARM: per exceeded detector (``(name, windowed, threshold, since step)``, in the
    declared order) its label, its ratio to the threshold and the step since which it exceeded, then who exceeded
    and how the detectors were combined (``how``: ``"(and)"``, ``"(max)"``, ... or the alone note; ``declared``:
    how many detectors are judged)."""
    parts = []
    for name, windowed, threshold, since in exceeded:
        ratio = ratio_text(windowed, threshold)
        word = " threshold" if not parts and ratio.endswith("x") else ""
        parts.append(f"{info(name).label} {ratio}{word} since step {since}")
    if declared == 1:
        who = ""
    elif declared == 2:
        who = "both " if len(exceeded) == 2 else "one "
    else:
        who = f"{len(exceeded)} of {declared} "
    return f"{', '.join(parts)}: {who}exceeded {how}"


def reset_refusal(allowed: bool, requester: str, reason: str) -> str:
    """Why a request to clear the latch (the fusion node's ``~/reset``) is refused; ``""`` if it is not.

    A reset is a deliberate act: refused when resets are switched off (``allow_reset`` false), and unless
    it names who asks and why, each in one printable line of at most :data:`MAX_RESET_TEXT` characters.
    """
    if not allowed:
        return "resets are switched off (allow_reset false): only the next rollout's START clears the latch"
    fields = (("requester", requester), ("reason", reason))
    empty = [name for name, text in fields if not text.strip()]
    if empty:
        return f"a reset names who asks and why: {' and '.join(empty)} empty"
    bad = [name for name, text in fields if len(text) > MAX_RESET_TEXT or not text.isprintable()]
    if bad:
        return f"{' and '.join(bad)} not one printable line of at most {MAX_RESET_TEXT} characters"
    return ""


@dataclass(frozen=True)
class DetectorScore:
    """One detector's windowed score for one step, as a Score message carries it."""

    detector: str
    rollout_id: int
    step: int
    windowed: float
    threshold: float
    stamp_ns: int
    complete: bool = True
    """False while the window holds a missing step: ``windowed`` is then a lower bound."""
    exceeded: bool = False
    """The detector's decision ``windowed > threshold`` at full precision (``Score.exceeded``)."""
    scored: bool = True
    """False when this step's own input was rejected (``Score.score`` NaN): ``windowed`` leaves it out."""


def decision(score: DetectorScore) -> bool | None:
    """The score's exceedance, or ``None`` when its numbers cannot be judged or contradict its flag.

    Rounding to float32 is monotone, so a float64 ``eta > gamma`` never becomes ``eta32 < gamma32`` and a
    float64 ``eta <= gamma`` never becomes ``eta32 > gamma32``: only ``eta32 == gamma32`` leaves the
    flag free. Non-finite numbers (NaN, or an infinite window or threshold) cannot be judged.
    """
    if not (math.isfinite(score.windowed) and math.isfinite(score.threshold)):
        return None
    if exceeds(score.windowed, score.threshold):
        return True if score.exceeded else None
    if exceeds(score.threshold, score.windowed):
        return None if score.exceeded else False
    return bool(score.exceeded)


@dataclass(frozen=True)
class AlarmState:
    """What the fusion node publishes on /fiper/alarm: the state and, per declared detector (in the declared
    order), its windowed score, threshold and decision at the step (NaN, NaN, False about no step)."""

    rollout_id: int
    step: int
    state: AlarmStateName
    latched: bool
    detectors: tuple[str, ...]
    exceeded: tuple[bool, ...]
    windowed: tuple[float, ...]
    thresholds: tuple[float, ...]
    votes: int
    """How many of the detectors must exceed at a step for an alarm."""
    combine: str
    """``"and"``, ``"or"``, ``"max"``, ``"kth:K"``; empty when one detector is judged alone (the combine does not
    apply)."""
    reason: str
    stamp_ns: int

    def of(self, detector: str) -> tuple[bool, float, float]:
        """``(exceeded, windowed, threshold)`` of ``detector`` (``(False, NaN, NaN)`` if it is not declared)."""
        if detector not in self.detectors:
            return False, math.nan, math.nan
        i = self.detectors.index(detector)
        return self.exceeded[i], self.windowed[i], self.thresholds[i]


class AlarmFuser:
    """Streaming votes of the declared detectors' scores matched per (rollout_id, step) (eq. 7, generalised), with
    latch and staleness."""

    def __init__(self, combine: str = CombineMode.AND, deadline_ns: int = 1_000_000_000, buffer_size: int = 64,
                 deadline_periods: float = 0.0, deadline_floor_ns: int = 0,
                 detectors: tuple[str, ...] = DETECTORS, start_wait_ns: int = 1_000_000_000) -> None:
        if deadline_periods < 0 or deadline_floor_ns < 0 or deadline_ns <= 0:
            raise ValueError("deadline_ns must be > 0, deadline_periods and deadline_floor_ns >= 0")
        for name in check_once(detectors):
            info(name)
        self.detectors = tuple(detectors)
        self.rule = Combine.parse(combine)
        self.votes = self.rule.votes(len(self.detectors))
        self.combine = str(self.rule)
        self.combined = self.combine if len(self.detectors) > 1 else ""
        """What the states say in ``combine``: the combine, or empty for one detector alone."""
        self._how = f"({self.combine})" if self.combined else f"({self.detectors[0]} alone: combine does not apply)"
        self.deadline_ns = deadline_ns
        """The staleness deadline until the rollout's policy period is measured (always, if
        ``deadline_periods`` is 0)."""
        self.deadline_periods = deadline_periods
        self.deadline_floor_ns = deadline_floor_ns
        self.buffer_size = buffer_size
        self.period = PeriodEstimator()
        self.gate: RolloutGate[DetectorScore] = RolloutGate(start_wait_ns=start_wait_ns, max_waiting_size=None)
        """The node's rollouts (the one rollout state of the fusion node) and the scores waiting for a START."""
        self._next_step = 0
        self.suspicion = ""
        """Why the score streams cannot be attributed to the suite now (``""``: they can)."""
        self._pending: OrderedDict[tuple[int, int], dict[str, DetectorScore]] = OrderedDict()
        self._last_seen: dict[str, int] = {}
        self.matched = 0
        self.evicted = 0
        self.unmatched_stale = 0
        self.reset()  # the latch and its companions: latched, alarm_step, last, unjudged, tainted

    # rollout lifecycle -------------------------------------------------------------------------------
    def start(self, rollout_id: int, now_ns: int, task: str = "", scenario: str = "", max_steps: int = 0
              ) -> list[DetectorScore] | None:
        """A START: ``None`` for a repeated START of the running rollout (its state and latch are kept); else clear
        the latch, the buffer and the streams' ages, and return the scores that waited for it (to :meth:`add`)."""
        waited = self.gate.start(rollout_id, task, scenario, max_steps)
        if waited is None:
            return None
        self.unmatched_stale += len(self._pending)
        self._pending.clear()
        self._next_step = 0
        self.reset()
        self.period.reset()
        self._last_seen = {d: now_ns for d in self.detectors}  # the deadline runs from the START
        return waited

    def end(self, rollout_id: int, outcome: str = "unknown") -> RolloutRecord | None:
        """The rollout ended: its streams are no longer expected (no staleness), but a step of it still on its
        way is judged (topics are not ordered: the END can overtake the last step). A latched ALARM (and
        :attr:`last`) stays until the next START or :meth:`reset`. Returns the rollout's record if it was active."""
        return self.gate.end(rollout_id, outcome)

    @property
    def rollout_id(self) -> int | None:
        """The rollout of the latest START (also after its END: its late steps are still judged)."""
        current = self.gate.current
        return None if current is None else current.rollout_id

    @property
    def active_rollout(self) -> int | None:
        """The rollout that is running (started, not ended), if any."""
        active = self.gate.active
        return None if active is None else active.rollout_id

    def reset(self) -> None:
        """Clear a latched ALARM (the ~/reset service); the next step is judged afresh, as after a START."""
        self.latched = False
        self.alarm_step: int | None = None
        """The step at which the latch fired, while it holds."""
        self.last: AlarmState | None = None
        """The latest fused state of this rollout (``None`` before its first step is fused)."""
        self.unjudged: tuple[int, int] | None = None
        """The first and last policy step of this rollout that never got a verdict here, if any."""
        self.exceeding_since: dict[str, int] = {}
        """Per detector whose latest fused step exceeded: the first step of that unbroken run of exceedances
        (a step never fused here breaks every run)."""
        self.explained = ""
        """The ALARM's :func:`explanation`, while the latch holds."""
        self.tainted = ""
        """Why scores of this rollout could not be attributed (``""``: they could, all along): set when a score
        of it is taken in doubt, or doubt arises while it runs (:meth:`suspect`)."""

    def suspect(self, reason: str) -> None:
        """Say why the score streams cannot be attributed to the suite now (``""``: they can again).

        While a reason is set no state is OK (:meth:`doubted`), and a rollout running meanwhile stays
        doubted until its end: a step fused from a foreign score may have hidden an alarm (the latch). A rollout
        started (or reset) in doubt is doubted from the first score it takes in doubt: one whose doubt cleared
        before any score (a respawned fusion node whose graph did not name a scorer yet) is judged as usual."""
        self.suspicion = reason
        if reason and self.active_rollout is not None and not self.tainted:
            self.tainted = reason

    def doubted(self, state: AlarmState) -> AlarmState:
        """``state`` as it may be published: an OK becomes UNKNOWN while the scores cannot be attributed,
        or could not during this rollout (ALARM and UNKNOWN stay: doubt never clears an alarm)."""
        if state.state != AlarmStateName.OK or not (self.suspicion or self.tainted):
            return state
        if self.suspicion:
            reason = f"scores cannot be attributed to the suite: {self.suspicion}"
        else:
            reason = f"scores of this rollout could not be attributed to the suite ({self.tainted}): an alarm " \
                     "cannot be ruled out"
        return replace(state, state=AlarmStateName.UNKNOWN, reason=reason)

    def deadline(self) -> int:
        """The staleness deadline now: ``deadline_periods`` measured policy periods of this rollout (at
        least ``deadline_floor_ns``), or ``deadline_ns`` while the period is unknown or ``deadline_periods`` 0."""
        return self.period.deadline_ns(self.deadline_periods, self.deadline_floor_ns, self.deadline_ns)

    # scores -----------------------------------------------------------------------------------------
    def add(self, score: DetectorScore, now_ns: int) -> AlarmState | None:
        """Take one detector's score; return the fused state once every declared score of the step is in."""
        if score.detector not in self.detectors:
            raise ValueError(f"detector {score.detector!r} is not fused here (detectors {', '.join(self.detectors)})")
        if score.rollout_id != self.rollout_id:
            return None
        if self.suspicion and not self.tainted:  # a score taken in doubt may be foreign: it may hide an alarm
            self.tainted = self.suspicion
        self._last_seen[score.detector] = now_ns
        key = (score.rollout_id, score.step)
        entry = self._pending.setdefault(key, {})
        entry[score.detector] = score
        if len(entry) < len(self.detectors):
            while len(self._pending) > self.buffer_size:
                self._pending.popitem(last=False)
                self.evicted += 1
            return None
        del self._pending[key]
        # Older steps still waiting for their partner will never be reported: count them.
        for old in [k for k in self._pending if k[1] < score.step]:
            del self._pending[old]
            self.unmatched_stale += 1
        self.matched += 1
        self.period.add(score.step, score.stamp_ns)  # the policy's own rhythm: arrivals bunch up when starved
        if score.step > self._next_step:  # steps that will never be fused: an alarm there cannot be ruled out
            first = self._next_step if self.unjudged is None else self.unjudged[0]
            self.unjudged = (first, score.step - 1)
            self.exceeding_since.clear()  # a run of exceedances is counted over judged steps only
        self._next_step = max(self._next_step, score.step + 1)
        self.last = self._fuse([entry[d] for d in self.detectors])
        return self.last

    def _fuse(self, scores: list[DetectorScore]) -> AlarmState:
        """The state of one step from the declared detectors' scores (in :attr:`detectors` order)."""
        decisions = [decision(s) for s in scores]
        exceeded = [bool(d) for d in decisions]
        for score, exceeds_now in zip(scores, exceeded):  # an undecided step breaks the run, as a step below does
            if exceeds_now:
                self.exceeding_since.setdefault(score.detector, score.step)
            else:
                self.exceeding_since.pop(score.detector, None)
        first = scores[0]
        common = dict(
            rollout_id=first.rollout_id, step=first.step, detectors=self.detectors, exceeded=tuple(exceeded),
            windowed=tuple(s.windowed for s in scores), thresholds=tuple(s.threshold for s in scores),
            votes=self.votes, combine=self.combined, stamp_ns=max(s.stamp_ns for s in scores),
        )
        if self.latched:  # the latch wins over whatever this step brings
            return AlarmState(state=AlarmStateName.ALARM, latched=True,
                              reason=f"latched since step {self.alarm_step}: {self.explained}", **common)
        uncalibrated = [s.detector for s in scores if not math.isfinite(s.threshold)]
        if uncalibrated:
            return AlarmState(state=AlarmStateName.UNKNOWN, latched=False,
                              reason=f"no threshold: {', '.join(uncalibrated)}", **common)
        undecided = [s.detector for s, d in zip(scores, decisions) if d is None]
        if undecided:
            return AlarmState(state=AlarmStateName.UNKNOWN, latched=False,
                              reason=f"score not finite or contradicting its exceeded flag: {', '.join(undecided)}",
                              **common)
        # Scores are >= 0, so an incomplete window's sum is a lower bound: its "exceeded" is certain,
        # its "not exceeded" is not. An alarm therefore stands; an OK needs complete windows.
        if fuse_votes(exceeded, self.votes):
            self.latched, self.alarm_step = True, first.step
            self.explained = explanation([(s.detector, s.windowed, s.threshold, self.exceeding_since[s.detector])
                                          for s, e in zip(scores, exceeded) if e], len(scores), self._how)
            return AlarmState(state=AlarmStateName.ALARM, latched=True, reason=self.explained, **common)
        if self.unjudged is not None:  # the latch may have fired at a step never judged here
            first, last = self.unjudged
            return AlarmState(state=AlarmStateName.UNKNOWN, latched=False,
                              reason=f"not every step of {first}..{last} was judged (a gap, or this node started "
                              "after them): an alarm there cannot be ruled out", **common)
        rejected = [s.detector for s in scores if not s.scored]
        if rejected:  # a step whose input was rejected is never OK, whatever the other detector says
            return AlarmState(state=AlarmStateName.UNKNOWN, latched=False,
                              reason=f"input of this step rejected: {', '.join(rejected)}", **common)
        # The alarm is ruled out when fewer detectors than the votes may still exceed: AND needs one certainly below,
        # OR and max (and one detector alone) all of them.
        certainly_below = [s.complete and not e for s, e in zip(scores, exceeded)]
        if len(scores) - sum(certainly_below) >= self.votes:
            incomplete = [s.detector for s in scores if not s.complete]
            return AlarmState(state=AlarmStateName.UNKNOWN, latched=False,
                              reason=f"window holds a missing step: {', '.join(incomplete)}", **common)
        return AlarmState(state=AlarmStateName.OK, latched=False,
                          reason="below thresholds" if self.combined else f"below threshold {self._how}", **common)

    # time -------------------------------------------------------------------------------------------
    def stale_streams(self, now_ns: int) -> list[str]:
        """Declared detectors of the active rollout whose last score is older than the deadline."""
        if self.active_rollout is None:
            return []
        deadline = self.deadline()
        return [d for d in self.detectors if now_ns - self._last_seen[d] > deadline]

    def check(self, now_ns: int, lost: frozenset[str] = frozenset()) -> AlarmState | None:
        """UNKNOWN state if a declared stream is stale or ``lost`` (liveliness), else ``None``."""
        lost_declared = set(lost) & set(self.detectors) if self.active_rollout is not None else set()
        bad = sorted(set(self.stale_streams(now_ns)) | lost_declared)
        if not bad:
            return None
        reason = f"stream(s) {', '.join(bad)} missing or older than {self.deadline() / 1e9:.3g} s"
        if self.last is None:
            return self._without_step(now_ns, reason)
        state = AlarmStateName.ALARM if self.latched else AlarmStateName.UNKNOWN
        return replace(self.last, state=state, reason=reason, stamp_ns=now_ns)

    def repeat_ns(self, heartbeat_ns: int) -> int:
        """Silence after which the current state is published again: ``heartbeat_ns``, or one measured policy
        period during a rollout if that is shorter, so that a supervisor hears the suite every period."""
        period = self.period.period_ns() if self.active_rollout is not None else None
        return heartbeat_ns if period is None else max(1, min(heartbeat_ns, period))

    def heartbeat(self, now_ns: int, heartbeat_ns: int, silent_since_ns: int, published: tuple[int, str, str] | None,
                  lost: frozenset[str] = frozenset()) -> AlarmState | None:
        """What a periodic check publishes (as a heartbeat: no new step's decision), if anything.

        A stream that went stale or ``lost``, or doubt about the score streams, is said at once: its state (an
        UNKNOWN, or the latched ALARM, :meth:`check`; doubt :meth:`doubted`) whenever it differs from what was
        ``published`` last (``(rollout_id, state, reason)``); else the current state is repeated once the node was
        silent for :meth:`repeat_ns` since ``silent_since_ns`` (so silence itself means the monitor is gone).
        ``None``: nothing to publish now."""
        quiet = now_ns - silent_since_ns >= self.repeat_ns(heartbeat_ns)
        state = self.check(now_ns, lost)
        if state is None and self.suspicion:
            state = self.current(now_ns)
        if state is not None:
            state = self.doubted(state)
            return state if quiet or published != (state.rollout_id, state.state, state.reason) else None
        return self.current(now_ns) if quiet else None

    def current(self, now_ns: int) -> AlarmState:
        """The state to repeat when nothing new happened: the latest fused state while its rollout runs or its
        ALARM latches (also after the END), else an UNKNOWN about no step."""
        if self.last is not None and (self.active_rollout is not None or self.latched):
            return self.last
        return self._without_step(now_ns, "no active rollout" if self.active_rollout is None
                                  else "waiting for the first scores of the rollout")

    def _without_step(self, now_ns: int, reason: str) -> AlarmState:
        """UNKNOWN about no fused step (step 0, no scores). Never latched: the latch fires at a fused step, and
        :attr:`last` holds that step's state until the latch is cleared."""
        count = len(self.detectors)
        return AlarmState(
            rollout_id=self.active_rollout or NO_ROLLOUT, step=0, state=AlarmStateName.UNKNOWN, latched=False,
            detectors=self.detectors, exceeded=(False,) * count, windowed=(math.nan,) * count,
            thresholds=(math.nan,) * count, votes=self.votes, combine=self.combined, reason=reason, stamp_ns=now_ns,
        )
