"""Fusion node: matches ``scores/rnd_oe`` and ``scores/ace`` per (rollout_id, step), fuses them
(eq. 7, AND by default) and publishes FailureAlarm on ``alarm`` (/fiper/alarm) every policy step.
With ``calibration_dir`` it fuses the detectors that calibration declares: for an observation-only one
(RND-OE alone) it follows ``scores/rnd_oe`` only and its alarm is RND-OE's exceedance.

The contract for supervisors is in docs/alarm-contract.md: RELIABLE + TRANSIENT_LOCAL + KEEP_LAST(1);
ALARM latches until ``~/reset`` (``fiper_msgs/ResetAlarm``: who and why, logged and counted; refused with
``allow_reset`` false) or the next START; UNKNOWN, never OK, while a score stream is missing, stale (older
than ``deadline_s``), not alive, or uncalibrated, and while a score topic has a publisher the suite does not
expect (the rest of that rollout); and a heartbeat repeats the current state every ``heartbeat_s`` so that
silence itself means the monitor is gone.
"""
from __future__ import annotations

import math
import sys
from collections import Counter
from dataclasses import replace
from typing import Any

from rclpy.qos_overriding_options import QoSOverridingOptions

from fiper_msgs.msg import FailureAlarm, RolloutEvent, Score
from fiper_msgs.srv import ResetAlarm
from fiper_ros.core.calibration_file import declared_detectors
from fiper_ros.data_paths import resolve_data_path
from fiper_ros.interface import qos
from fiper_ros.interface.cdr import codec
from fiper_ros.interface.conversions import header_view, stamp_ns
from fiper_ros.interface.messages import ALARM, NO_ROLLOUT, OK, UNKNOWN, outcome_name
from fiper_ros.interface.topics import ALARM as ALARM_TOPIC, EVENTS, RESET_ALARM, relative, score_topic
from fiper_ros.nodes.base import FiperNode, describe
from fiper_ros.nodes.main import EXECUTOR_EVENTS, run_node
from fiper_ros.runtime.alarm import DETECTORS, AlarmFuser, AlarmState, DetectorScore, reset_refusal
from fiper_ros.runtime.pending import StartGate
from fiper_ros.runtime.publishers import Expected
from fiper_ros.runtime.rollout_tracker import RolloutTracker
from fiper_ros.runtime.validation import UNKNOWN_DETECTOR, UNKNOWN_ROLLOUT, InputRejected

STATES = {OK: FailureAlarm.STATE_OK, ALARM: FailureAlarm.STATE_ALARM, UNKNOWN: FailureAlarm.STATE_UNKNOWN}
#: The FailureAlarm on the wire: the node publishes its bytes (issue #24).
ALARM_WIRE = codec(FailureAlarm)


class FusionNode(FiperNode):
    """Publishes the fused failure prediction on ``alarm``."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("fusion_node", **kwargs)
        self.declare_parameter("combine", "and", describe("'and' (paper eq. 7) or 'or'", read_only=True))
        self.declare_parameter("calibration_dir", "",
                               describe("calibration whose declared detectors are fused (empty: rnd_oe and ace)",
                                        read_only=True))
        self.declare_parameter("deadline_s", 1.0,
                               describe("a score stream older than this makes the state UNKNOWN, until the rollout's "
                                        "policy period is measured (always, if deadline_periods is 0)",
                                        low=0.01, high=600.0))
        self.declare_parameter("deadline_periods", 2.5,
                               describe("staleness deadline in measured policy periods of the rollout (0: deadline_s)",
                                        low=0.0, high=1000.0))
        self.declare_parameter("deadline_floor_s", 0.1,
                               describe("the period-based deadline is never shorter (scheduling jitter)",
                                        low=0.0, high=600.0))
        self.declare_parameter("check_period_s", 0.02,
                               describe("how often staleness is checked", read_only=True, low=0.001, high=10.0))
        self.declare_parameter("heartbeat_s", 0.5,
                               describe("republish the current state after this much silence (during a rollout: "
                                        "after one measured policy period, if shorter)", low=0.01, high=600.0))
        self.declare_parameter("buffer_size", 64,
                               describe("unmatched steps kept per rollout before eviction", low=1, high=100000, integer=True))
        self.declare_parameter("start_wait_s", 1.0,
                               describe("how long a score may wait for its rollout's START", read_only=True,
                                        low=0.0, high=60.0))
        self.declare_parameter("allow_reset", True,
                               describe("~/reset may clear a latched alarm (false: only the next START does)",
                                        read_only=True))
        self.declare_parameter("score_publishers", [f"{d}_node" for d in DETECTORS], describe(
            "nodes that may publish the score topics, one publisher each (relative names: in this node's namespace)",
            read_only=True))
        self.fuser: AlarmFuser | None = None
        self.pending: StartGate[DetectorScore] = StartGate(int(self.get_parameter("start_wait_s").value * 1e9))
        #: STARTs of the rollout already active (ignored: its latch is kept).
        self.repeated_starts = 0
        self.rollouts = RolloutTracker()
        self.lost: set[str] = set()
        self.states = {OK: 0, ALARM: 0, UNKNOWN: 0}
        self._last_publish_ns = 0
        self._last_published: tuple[int, str, str] | None = None
        self._inputs: list[Any] = []
        self._timer: Any = None
        self._alarm_pub = self.create_lifecycle_publisher(
            FailureAlarm, relative(ALARM_TOPIC), qos.ALARM_PUB,
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
            event_callbacks=self.publisher_events(relative(ALARM_TOPIC)),
        )
        # Liveliness (a DDS lease, wall clock): a supervisor counts the live publishers of the alarm.
        self.create_timer(qos.ALARM_HEARTBEAT_S, self._alarm_pub.assert_liveliness, clock=self.steady)
        self.create_service(ResetAlarm, RESET_ALARM, self._on_reset)
        #: Reset requests, by outcome ("accepted", "refused").
        self.resets: Counter[str] = Counter()
        #: Each detector's score topic relative to the namespace: what the node subscribes to, and the key of its
        #: rate on /diagnostics.
        self.score_streams = {d: relative(score_topic(d)) for d in DETECTORS}
        self.score_topics = {d: self.resolve_topic_name(topic) for d, topic in self.score_streams.items()}
        self.watch_publishers(self._on_publishers)

    def configure(self) -> None:
        combine = self.get_parameter("combine").value
        directory = self.get_parameter("calibration_dir").value
        if directory:  # relative: the working directory, the share, $FIPER_MODELS (as the scoring nodes)
            directory = str(resolve_data_path(directory))
        detectors = declared_detectors(directory) if directory else DETECTORS
        self.fuser = AlarmFuser(combine, int(self.get_parameter("deadline_s").value * 1e9),
                                self.get_parameter("buffer_size").value, self.get_parameter("deadline_periods").value,
                                int(self.get_parameter("deadline_floor_s").value * 1e9), detectors)
        alone = "" if self.fuser.combined else ": alone, combine does not apply"
        self.get_logger().info(f"fusing {', '.join(detectors)}{alone}"
                               + (f" (calibration {directory})" if directory else ""))
        self._on_publishers()

    def activate(self) -> None:
        for detector in self.fuser.detectors:
            topic = self.score_streams[detector]
            self._inputs.append(self.create_wire_subscription(
                Score, topic, self._on_score, qos.SCORE_SUB,
                event_callbacks=self.subscription_events(topic, lambda info, d=detector: self._on_liveliness(d, info)),
            ))
        self._inputs.append(self.create_subscription(
            RolloutEvent, relative(EVENTS), self._on_event, qos.EVENT,
            event_callbacks=self.subscription_events(relative(EVENTS))))
        self._timer = self.create_timer(self.get_parameter("check_period_s").value, self._on_timer)

    def deactivate(self) -> None:
        for subscription in self._inputs:
            self.destroy_subscription(subscription)
        self._inputs.clear()
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = None

    def cleanup(self) -> None:
        self.fuser = None

    def expected_publishers(self) -> list[Expected]:
        """The shell's expectations, with each score topic published by one of ``score_publishers``."""
        scorers = self.allowed("score_publishers")
        topics = set(self.score_topics.values())
        return [replace(e, nodes=scorers) if e.topic in topics else e for e in super().expected_publishers()]

    # callbacks ----------------------------------------------------------------------------------------
    def _on_publishers(self) -> None:
        """The publishers of a watched topic changed: score topics in doubt make the state UNKNOWN (said by the
        next check, within ``check_period_s``)."""
        if self.fuser is not None:
            self.fuser.suspect(self.publisher_check.watch.doubt(tuple(self.score_topics.values())))

    def _on_liveliness(self, detector: str, info: Any) -> None:
        self.publisher_check.set_liveliness(self.score_topics[detector], info.not_alive_count)
        if info.alive_count == 0:
            if detector not in self.lost:
                self.get_logger().error(f"score stream {detector} lost liveliness: its node is gone")
            self.lost.add(detector)
            self._on_timer()
        else:
            self.lost.discard(detector)

    def _on_event(self, msg: RolloutEvent) -> None:
        now = self.now_ns()
        if msg.event == RolloutEvent.EVENT_START:
            if self.fuser.active_rollout == msg.rollout_id:
                self.repeated_starts += 1
                return  # a repeated START of the running rollout: keep its state (and its latch)
            self.rollouts.start(msg.rollout_id, msg.task, msg.scenario, msg.max_steps)
            self.fuser.start(msg.rollout_id, now)
            for early in self.pending.start(msg.rollout_id):
                self._fuse(early, now)
        elif msg.event == RolloutEvent.EVENT_END:
            self.pending.end(msg.rollout_id)
            record = self.rollouts.end(msg.rollout_id, outcome_name(msg.outcome))
            self.fuser.end(msg.rollout_id)
            if record is not None:
                record.alarm_step = self.fuser.alarm_step
                self.get_logger().info(f"fusion: {record.summary()}")

    def _on_score(self, msg: Score) -> None:
        started = self.timed()
        if msg.detector not in self.fuser.detectors:  # before any per-detector state: a name must not size memory
            self.reject(InputRejected(UNKNOWN_DETECTOR, f"score of unknown detector {msg.detector!r}"))
            return
        now = self.now_ns()
        self.tick(self.score_streams[msg.detector], now)
        score = DetectorScore(msg.detector, msg.rollout_id, msg.step, msg.windowed_score, msg.threshold,
                              stamp_ns(msg.header.stamp), msg.complete, msg.exceeded, math.isfinite(msg.score))
        for expired in self.pending.expire(now):
            self._reject_unknown(expired, "no START within start_wait_s")
        if msg.rollout_id != self.fuser.rollout_id:
            if self.pending.has_ended(msg.rollout_id):  # late, after the next rollout started
                self._reject_unknown(score, f"its rollout ended, rollout {self.fuser.rollout_id} runs")
                return
            for dropped in self.pending.add(msg.rollout_id, score, now):  # its START is still on the way
                self._reject_unknown(dropped, "dropped from the full START wait buffer")
            return
        self._fuse(score, now)
        self.record_latency(started)

    def _reject_unknown(self, score: DetectorScore, why: str) -> None:
        self.reject(InputRejected(UNKNOWN_ROLLOUT, f"{score.detector} score of rollout {score.rollout_id} step "
                                                   f"{score.step}: {why}"))

    def _fuse(self, score: DetectorScore, now_ns: int) -> None:
        state = self.fuser.add(score, now_ns)
        if state is None:
            return
        active = self.rollouts.active
        if active is not None:
            active.steps += 1
        self.publish(state, now_ns)

    def _on_timer(self) -> None:
        if self.fuser is None:
            return
        now = self.now_ns()
        state = self.fuser.check(now, frozenset(self.lost))
        quiet = now - self._last_publish_ns >= self.repeat_ns()
        if state is None and self.fuser.suspicion:
            state = self.fuser.current(now)
        if state is not None:
            state = self.fuser.doubted(state)
            if quiet or self._last_published != (state.rollout_id, state.state, state.reason):
                self.publish(state, now, heartbeat=True)  # a stream just went stale, lost or in doubt: at once
        elif quiet:
            self.publish(self.fuser.current(now), now, heartbeat=True)

    def repeat_ns(self) -> int:
        """Silence after which the current state is published again: ``heartbeat_s``, or one measured policy
        period during a rollout if that is shorter, so a supervisor hears the suite every period."""
        heartbeat = int(self.get_parameter("heartbeat_s").value * 1e9)
        period = self.fuser.period.period_ns() if self.fuser.active_rollout is not None else None
        return heartbeat if period is None else max(1, min(heartbeat, period))

    def _on_reset(self, request: ResetAlarm.Request, response: ResetAlarm.Response) -> ResetAlarm.Response:
        refusal = reset_refusal(self.get_parameter("allow_reset").value, request.requester, request.reason)
        if not refusal and self.fuser is None:
            refusal = "fusion node is not configured"
        if refusal:
            self.resets["refused"] += 1
            response.success, response.message = False, f"reset refused: {refusal}"
            self.get_logger().warning(f"~/reset by {request.requester[:80]!r} ({request.reason[:80]!r}): "
                                      f"{response.message}")
            return response
        was = self.fuser.latched
        self.fuser.reset()
        self.resets["accepted"] += 1
        response.success = True
        response.message = f"latched alarm of rollout {self.fuser.rollout_id} cleared" if was else \
            "no alarm was latched"
        self.get_logger().warning(f"~/reset by {request.requester!r}, reason {request.reason!r}: {response.message}")
        return response

    def publish(self, state: AlarmState, now_ns: int, heartbeat: bool = False) -> None:
        """Publish one FailureAlarm at ``now_ns`` (the node clock; ``heartbeat``: a repeat, not a new step's
        decision); never an OK while the scores cannot be attributed (a publisher that appeared
        since the last look is judged first)."""
        if state.state == OK:
            self.publisher_check.check_if_matched()
        state = self.fuser.doubted(state)
        self._alarm_pub.publish(ALARM_WIRE.encode(ALARM_WIRE.view(
            header=header_view(state.stamp_ns), rollout_id=state.rollout_id, step=state.step,
            state=STATES[state.state], latched=state.latched, obs_exceeded=state.obs_exceeded,
            act_exceeded=state.act_exceeded, eta_obs=state.eta_obs, gamma_obs=state.gamma_obs, eta_act=state.eta_act,
            gamma_act=state.gamma_act, combine=state.combine, reason=state.reason, heartbeat=heartbeat)))
        self.states[state.state] += 1
        self._last_publish_ns = now_ns
        self._last_published = (state.rollout_id, state.state, state.reason)

    def running_taint(self) -> str:
        """Why scores of the running rollout could not be attributed (``""``: they could, or none runs). An ended
        rollout's taint still doubts its late steps, but is no doubt about the suite now: late (durable) scores of
        it, taken by a respawned fusion node before its graph named their node, kept ``scores_in_doubt`` from
        saying ``no`` until the next START."""
        return self.fuser.tainted if self.fuser.active_rollout is not None else ""

    def diagnostic_values(self) -> dict[str, str]:
        values = {f"published.{k}": str(v) for k, v in self.states.items()}
        values |= {f"resets.{outcome}": str(self.resets[outcome]) for outcome in ("accepted", "refused")}
        if self.fuser is not None:
            values |= {"matched": str(self.fuser.matched), "evicted": str(self.fuser.evicted),
                       "unmatched": str(self.fuser.unmatched_stale), "latched": str(self.fuser.latched),
                       "lost_streams": ",".join(sorted(self.lost)) or "none",
                       "detectors": ",".join(self.fuser.detectors),
                       "waiting_for_start": str(len(self.pending)),
                       "repeated_starts": str(self.repeated_starts),
                       "scores_in_doubt": self.fuser.suspicion or self.running_taint() or "no",
                       "deadline_ms": f"{self.fuser.deadline() / 1e6:.1f}",
                       "policy_period_ms": "unknown" if (p := self.fuser.period.period_ns()) is None else f"{p / 1e6:.1f}"}
        return values


#: The node class, for in-process launching.
NODE_CLASS = FusionNode


def main(args: list[str] | None = None) -> int:
    """Entry point: ``python -m fiper_ros.nodes.fusion_node --ros-args ...``."""
    return run_node(FusionNode, args, executor=EXECUTOR_EVENTS)


if __name__ == "__main__":
    sys.exit(main())
