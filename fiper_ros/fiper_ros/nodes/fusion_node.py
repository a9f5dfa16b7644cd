"""Fusion node: matches the declared detectors' ``scores/<detector>`` per (rollout_id, step), votes (eq. 7,
generalised: AND by default) and publishes FailureAlarm on ``alarm`` (/fiper/alarm) every policy step.
With ``calibration_dir`` it fuses the detectors that calibration declares, with its combine (a joint combine's
thresholds are calibrated for it); without one, FIPER's pair with the ``combine`` parameter.

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

from rclpy.parameter import Parameter
from rclpy.qos_overriding_options import QoSOverridingOptions

from fiper_msgs.msg import FailureAlarm, RolloutEvent, Score
from fiper_msgs.srv import ResetAlarm
from fiper_ros.core.calibration_file import declared
from fiper_ros.core.combine_mode import CombineMode
from fiper_ros.core.detectors import ACE, DETECTORS, RND_OE
from fiper_ros.data_paths import resolve_data_path
from fiper_ros.interface import qos
from fiper_ros.interface.cdr import codec
from fiper_ros.interface.conversions import header_view, stamp_ns
from fiper_ros.interface.messages import AlarmStateName, outcome_name
from fiper_ros.interface.topics import ALARM_TOPIC, EVENTS_TOPIC, RESET_ALARM_SERVICE, relative, score_topic
from fiper_ros.nodes.base import FiperNode, describe
from fiper_ros.nodes.errors import NodeError
from fiper_ros.nodes.settings import FROM_CALIBRATION, FusionSettings, fusion_settings
from fiper_ros.platform.process import EXECUTOR_EVENTS, run_node, run_reported
from fiper_ros.runtime.alarm import AlarmFuser, AlarmState, DetectorScore, reset_refusal
from fiper_ros.runtime.rollout_gate import Route
from fiper_ros.runtime.stats import DEADLINE_PERIODS
from fiper_ros.runtime.trusted_publishers import Expected, resolve_node
from fiper_ros.runtime.validation import UNKNOWN_DETECTOR, UNKNOWN_ROLLOUT, InputRejected

#: The FailureAlarm on the wire: the node publishes its bytes.
ALARM_WIRE = codec(FailureAlarm)

class FusionNode(FiperNode):
    """Publishes the fused failure prediction on ``alarm``."""

    settings: FusionSettings

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("fusion_node", **kwargs)
        self.declare_parameter("combine", FROM_CALIBRATION, describe(
            f"'{FROM_CALIBRATION}': the calibration's own combine (and without one); 'and' (paper eq. 7), 'or', 'max' "
            "or 'kth:K' must be the calibration's, whose thresholds are calibrated for it", read_only=True))
        self.declare_parameter("calibration_dir", "",
                               describe("calibration whose declared detectors are fused (empty: rnd_oe and ace)",
                                        read_only=True))
        self.declare_parameter("deadline_s", 1.0,
                               describe("a score stream older than this makes the state UNKNOWN, until the rollout's "
                                        "policy period is measured (always, if deadline_periods is 0)",
                                        low=0.01, high=600.0))
        self.declare_parameter("deadline_periods", DEADLINE_PERIODS,
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
        self.declare_parameter("score_publishers", Parameter.Type.STRING_ARRAY, describe(
            "nodes that may publish the score topics, one publisher each (relative names: in this node's namespace; "
            "empty: each declared detector's <detector>_node)", read_only=True))
        self.fuser: AlarmFuser | None = None
        self.lost: set[str] = set()
        self.states = dict.fromkeys(AlarmStateName, 0)
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
        self.create_service(ResetAlarm, RESET_ALARM_SERVICE, self._on_reset)
        #: Reset requests, by outcome ("accepted", "refused").
        self.resets: Counter[str] = Counter()
        self._declare_streams(DETECTORS)
        self.watch_publishers(self._on_publishers)
        self.settle(fusion_settings)  # a refused combine: every configure fails with it

    def _declare_streams(self, detectors: tuple[str, ...]) -> None:
        """The score topics of ``detectors``: what the node subscribes to and watches, and the keys of their rates on
        /diagnostics (relative to the namespace; fully qualified in :attr:`score_topics`)."""
        self.score_streams = {d: relative(score_topic(d)) for d in detectors}
        self.score_topics = {d: self.resolve_topic_name(topic) for d, topic in self.score_streams.items()}

    def configure(self) -> None:
        settings = self.settings
        combine, directory = settings.combine, settings.calibration_dir
        detectors = DETECTORS
        if directory:  # relative: the working directory, the share, $FIPER_MODELS (as the scoring nodes)
            directory = str(resolve_data_path(directory))
            own = declared(directory)
            if combine not in (FROM_CALIBRATION, own.combine) and len(own.detectors) > 1:
                raise NodeError(f"parameter combine is {combine!r}, but calibration {directory} was calibrated for "
                                f"{own.combine!r}: set combine {FROM_CALIBRATION!r}, or calibrate for it")
            detectors, combine = own.detectors, own.combine
        self._declare_streams(detectors)
        self.fuser = AlarmFuser(CombineMode.AND if combine == FROM_CALIBRATION else combine, settings.deadline_ns,
                                settings.buffer_size, settings.deadline_periods, settings.deadline_floor_ns, detectors,
                                settings.start_wait_ns)
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
            RolloutEvent, relative(EVENTS_TOPIC), self._on_event, qos.EVENT,
            event_callbacks=self.subscription_events(relative(EVENTS_TOPIC))))
        self._timer = self.create_timer(self.settings.check_period_s, self._on_timer)

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
        """The shell's expectations, with each score topic published by one of ``score_publishers`` (empty: each
        declared detector's own node)."""
        named = self.settings.score_publishers if self.settings is not None else ()
        scorers = self.allowed(named) or frozenset(resolve_node(f"{d}_node", self.get_namespace())
                                                              for d in self.score_streams)
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
            waited = self.fuser.start(msg.rollout_id, now, msg.task, msg.scenario, msg.max_steps)
            for early in waited or ():  # None: a repeated START of the running rollout, its state (and latch) kept
                self._fuse(early, now)
        elif msg.event == RolloutEvent.EVENT_END:
            record = self.fuser.end(msg.rollout_id, outcome_name(msg.outcome))
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
        gate = self.fuser.gate
        for expired in gate.expire(now):
            self._reject_unknown(expired, "no START within start_wait_s")
        route = gate.route(msg.rollout_id)
        if route is Route.LATE:  # late, after the next rollout started
            self._reject_unknown(score, f"its rollout ended, rollout {self.fuser.rollout_id} runs")
            return
        if route is Route.WAIT:  # its START is still on the way
            for dropped in gate.wait(msg.rollout_id, score, now):
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
        active = self.fuser.gate.active
        if active is not None:
            active.steps += 1
        self.publish(state, now_ns)

    def _on_timer(self) -> None:
        if self.fuser is None:
            return
        now = self.now_ns()
        state = self.fuser.heartbeat(now, self.settings.heartbeat_ns, self._last_publish_ns, self._last_published,
                                     frozenset(self.lost))
        if state is not None:
            self.publish(state, now, heartbeat=True)

    def _on_reset(self, request: ResetAlarm.Request, response: ResetAlarm.Response) -> ResetAlarm.Response:
        refusal = "" if self.settings is None else reset_refusal(self.settings.allow_reset, request.requester,
                                                                 request.reason)
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
        if state.state == AlarmStateName.OK:
            self.publisher_check.check_if_matched()
        state = self.fuser.doubted(state)
        (obs_exceeded, eta_obs, gamma_obs), (act_exceeded, eta_act, gamma_act) = state.of(RND_OE), state.of(ACE)
        self._alarm_pub.publish(ALARM_WIRE.encode(ALARM_WIRE.view(
            header=header_view(state.stamp_ns), rollout_id=state.rollout_id, step=state.step,
            state=state.state.code, latched=state.latched, detectors=list(state.detectors),
            eta=list(state.windowed), gamma=list(state.thresholds), exceeded=list(state.exceeded), votes=state.votes,
            obs_exceeded=obs_exceeded, act_exceeded=act_exceeded, eta_obs=eta_obs, gamma_obs=gamma_obs,
            eta_act=eta_act, gamma_act=gamma_act, combine=state.combine, reason=state.reason, heartbeat=heartbeat)))
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
                       "waiting_for_start": str(len(self.fuser.gate.waiting)),
                       "repeated_starts": str(self.fuser.gate.repeated_starts),
                       "scores_in_doubt": self.fuser.suspicion or self.running_taint() or "no",
                       "deadline_ms": f"{self.fuser.deadline() / 1e6:.1f}",
                       "policy_period_ms": "unknown" if (p := self.fuser.period.period_ns()) is None else f"{p / 1e6:.1f}"}
        return values


#: The node class, for in-process launching.
NODE_CLASS = FusionNode


def main(args: list[str] | None = None) -> int:
    """Entry point: ``python -m fiper_ros.nodes.fusion_node --ros-args ...``."""
    return run_reported("fusion_node", run_node, FusionNode, args, executor=EXECUTOR_EVENTS)


if __name__ == "__main__":
    sys.exit(main())
