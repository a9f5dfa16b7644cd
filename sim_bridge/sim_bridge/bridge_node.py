"""ROS 2 bridge node: the simulated Franka stand-in behind the driver's topics (docs/sim.md, "The bridge node").

A thin shell around :class:`sim_bridge.bridge_session.BridgeSession`: ``/sim/reset`` starts a rollout
(RolloutEvent START, then the first observation), ``/sim/action`` commands (the first ``h`` actions of
a chunk) are executed one per control step at the task's control rate times ``realtime_factor``
(0: as fast as possible), and after every executed command the observation "tick" is published:
``/joint_states``, both camera images and ``/sim/proprio`` with one ``header.stamp``. A command with
``observation_history`` n > 0 (a policy with T_h = n + 1) gets, before the tick, the images and
proprioception of its last n control steps before the tick's, each with its control step's stamp, so
that the policy's history holds consecutive control steps as in training. While no command
for a tick has arrived, its images and proprioception are re-published unchanged every
``observation_resend_s``: a policy whose subscriptions were matched after the tick (discovery under
load, a policy node started late) still gets it, and one that already has it drops the repetition
(same stamp). The rollout ends with a RolloutEvent END (success, failure, time limit, ``/sim/halt``,
a new reset). In sim-time mode the bridge publishes ``/clock``: simulated time, which only advances
while actions execute.
"""
from __future__ import annotations

import sys
from collections import Counter
from typing import Any

from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Image, JointState
from std_srvs.srv import Trigger

from fiper_msgs.msg import ActionCommand, RolloutEvent
from fiper_msgs.srv import ResetRollout
from fiper_ros.interface import qos
from fiper_ros.interface.conversions import floats_of, rollout_event_msg, to_stamp
from fiper_ros.interface.topics import (CAMERA_THIRD_TOPIC, CAMERA_WRIST_TOPIC, CLOCK_TOPIC, EVENTS_TOPIC,
                                        JOINT_STATES_TOPIC, SIM_ACTION_TOPIC, SIM_HALT_SERVICE, SIM_PROPRIO_TOPIC,
                                        SIM_RESET_SERVICE)
from fiper_ros.nodes.base import FiperNode, describe
from fiper_ros.platform.process import run_node, run_reported
from fiper_ros.runtime.validation import INTERNAL, InputRejected

from .bridge_session import FAILURE, JOINT_NAMES, PROPRIO_NAMES, SUCCESS, BridgeSession, Ended, Rollout
from .render import CAMERAS
from .scenarios import ScenarioError, get_scenario

#: Simulated time of the first /clock message: ROS tools read a zero stamp as "unset".
SIM_EPOCH_NS = 1_000_000_000
#: /clock: RELIABLE serves rclpy's BEST_EFFORT time source as well as reliable subscribers.
CLOCK_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
OUTCOME_CODES = {SUCCESS: RolloutEvent.OUTCOME_SUCCESS, FAILURE: RolloutEvent.OUTCOME_FAILURE}
#: Observation key -> parameter naming its topic.
IMAGE_TOPIC_PARAMS = {"wrist_rgb": "wrist_image_topic", "third_rgb": "third_image_topic"}
MAX_SEED = (1 << 63) - 1


class BridgeNode(FiperNode):
    """Runs rollouts of the MuJoCo tasks for a policy over ROS 2, like a robot driver would."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("bridge_node", **kwargs)
        declare = self.declare_parameter
        declare("task", "sorting", describe("task of start_on_activate and of a reset with an empty task",
                                            read_only=True))
        declare("scenario", "id", describe("scenario of start_on_activate", read_only=True))
        declare("seed", 0, describe("seed of start_on_activate", read_only=True, low=0, high=MAX_SEED, integer=True))
        declare("start_on_activate", False, describe("start a rollout (task, scenario, seed) on activation",
                                                     read_only=True))
        declare("images", True, describe("render and publish the two 96x96 rgb8 cameras", read_only=True))
        declare("max_policy_steps", 0, describe("end every rollout after this many policy steps (a timeout "
                                                "failure); 0 = the task's time limit", read_only=True, low=0,
                                                high=1_000_000, integer=True))
        declare("realtime_factor", 1.0, describe("simulated / wall time while actions execute; 0 = as fast as "
                                                 "possible", read_only=True, low=0.0, high=1000.0))
        declare("sim_time", False, describe("publish /clock and stamp everything with simulated time",
                                            read_only=True))
        declare("publish_rate_hz", 10.0, describe("re-publish /joint_states (and /clock) at this rate while "
                                                  "idle; 0 = off", read_only=True, low=0.0, high=1000.0))
        declare("observation_resend_s", 2.0, describe("re-publish a tick's images and proprioception at this period "
                                                      "until its command arrives; 0 = off", read_only=True,
                                                      low=0.0, high=3600.0))
        declare("joint_state_topic", JOINT_STATES_TOPIC, describe("sensor_msgs/JointState of the 9 joints",
                                                                read_only=True))
        declare("wrist_image_topic", CAMERA_WRIST_TOPIC, describe("wrist camera image", read_only=True))
        declare("third_image_topic", CAMERA_THIRD_TOPIC, describe("third-person camera image",
                                                                         read_only=True))
        declare("proprio_topic", SIM_PROPRIO_TOPIC, describe("the policy's proprioception (sensor_msgs/JointState)",
                                                          read_only=True))
        declare("action_topic", SIM_ACTION_TOPIC, describe("fiper_msgs/ActionCommand input", read_only=True))
        declare("events_topic", EVENTS_TOPIC, describe("RolloutEvent output", read_only=True))
        self.sim_time = bool(self.get_parameter("sim_time").value)
        self.realtime_factor = float(self.get_parameter("realtime_factor").value)
        self.session: BridgeSession | None = None
        self.sim_ns = SIM_EPOCH_NS
        self.ended: Counter[str] = Counter()
        self._period_ns = 0
        self._step_timer: Any = None
        self._action_sub: Any = None
        #: The running rollout's newest tick (images, proprioception) while its command has not arrived.
        self._unanswered: list[tuple[Any, Any]] = []
        self._unanswered_since = 0
        self._resend_ns = round(float(self.get_parameter("observation_resend_s").value) * 1e9)
        self.observation_resends = 0

        def publisher(msg_type: Any, parameter: str, profile: QoSProfile) -> Any:
            topic = self.get_parameter(parameter).value
            return self.create_publisher(msg_type, topic, profile, event_callbacks=self.publisher_events(topic))

        self._joint_pub = publisher(JointState, "joint_state_topic", qos.INPUT)
        self._proprio_pub = publisher(JointState, "proprio_topic", qos.INPUT)
        self._image_pubs = ({key: publisher(Image, param, qos.INPUT) for key, param in IMAGE_TOPIC_PARAMS.items()}
                            if self.get_parameter("images").value else {})
        self._event_pub = publisher(RolloutEvent, "events_topic", qos.EVENT)
        self._clock_pub = self.create_publisher(Clock, CLOCK_TOPIC, CLOCK_QOS) if self.sim_time else None
        self.create_service(ResetRollout, SIM_RESET_SERVICE, self._on_reset)
        self.create_service(Trigger, SIM_HALT_SERVICE, self._on_halt)
        rate = float(self.get_parameter("publish_rate_hz").value)
        if rate > 0:
            self.create_timer(1.0 / rate, self._on_idle, clock=self.steady)
        if self._resend_ns > 0:
            self.create_timer(self._resend_ns / 4e9, self._on_resend, clock=self.steady)

    # lifecycle ----------------------------------------------------------------------------------------
    def configure(self) -> None:
        get_scenario(self.get_parameter("task").value, self.get_parameter("scenario").value)  # fail early
        self.session = BridgeSession(images=bool(self._image_pubs),
                                     max_policy_steps=int(self.get_parameter("max_policy_steps").value))
        self._publish_clock()

    def activate(self) -> None:
        topic = self.get_parameter("action_topic").value
        self._action_sub = self.create_subscription(ActionCommand, topic, self._on_action, qos.INPUT,
                                                    event_callbacks=self.subscription_events(topic))
        if self.get_parameter("start_on_activate").value:
            self._start(self.get_parameter("task").value, self.get_parameter("scenario").value,
                        self.get_parameter("seed").value)

    def deactivate(self) -> None:
        self.destroy_subscription(self._action_sub)
        self._action_sub = None
        self._end("deactivated")

    def cleanup(self) -> None:
        if self.session is not None:
            self.session.close()
        self.session = None

    # services -----------------------------------------------------------------------------------------
    def _on_reset(self, request: ResetRollout.Request, response: ResetRollout.Response) -> ResetRollout.Response:
        if self.lifecycle_state() != "active" or self.session is None:
            response.message = f"bridge is not active (lifecycle state {self.lifecycle_state()})"
            return response
        task = request.task or (self.session.rollout.task if self.session.rollout else self.get_parameter("task").value)
        try:
            rollout = self._start(task, request.scenario or "id", request.seed)
        except ScenarioError as error:
            response.message = str(error)
            self.get_logger().warning(f"reset refused: {response.message}")
            return response
        response.success = True
        response.rollout_id = rollout.rollout_id
        response.max_steps = rollout.max_steps
        response.message = f"rollout {rollout.rollout_id} started: {task}/{rollout.scenario} seed {rollout.seed}"
        return response

    def _on_halt(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        ended = self._end("halted")
        response.success = True
        response.message = (f"rollout {ended.rollout_id} halted after {ended.control_step} control steps"
                            if ended else "no rollout was running")
        return response

    # rollouts -----------------------------------------------------------------------------------------
    def _start(self, task: str, scenario: str, seed: int) -> Rollout:
        assert self.session is not None
        rollout, aborted = self.session.start(task, scenario, seed)
        self._stop_stepping()
        if aborted is not None:
            self._publish_end(aborted, self._stamp_ns())
        assert self.session.env is not None
        period_ns = round(1e9 / self.session.env.control_hz)
        if period_ns != self._period_ns or self._step_timer is None:
            self._make_step_timer(period_ns)
        self.sim_ns += period_ns  # a reset takes one control period: every tick's stamp is new
        self._publish_clock()
        stamp = self._stamp_ns()
        self._event_pub.publish(rollout_event_msg(rollout.rollout_id, RolloutEvent.EVENT_START, stamp, task=task,
                                                  scenario=rollout.scenario, max_steps=rollout.max_steps))
        self.get_logger().info(f"rollout {rollout.rollout_id} started: {task}/{rollout.scenario} seed {rollout.seed}, "
                               f"max {rollout.max_steps} policy steps")
        self._publish_tick(stamp)
        return rollout

    def _end(self, reason: str) -> Ended | None:
        """End the running rollout as a failure (halt, deactivation); None if none runs."""
        ended = self.session.end(reason) if self.session is not None else None
        self._stop_stepping()
        if ended is not None:
            self._publish_end(ended, self._stamp_ns())
        return ended

    def _publish_end(self, ended: Ended, stamp: int) -> None:
        self.ended[ended.reason] += 1
        self._event_pub.publish(rollout_event_msg(ended.rollout_id, RolloutEvent.EVENT_END, stamp,
                                                  outcome=OUTCOME_CODES[ended.outcome]))
        self.get_logger().info(f"rollout {ended.rollout_id} ended: {ended.outcome} ({ended.reason}) after "
                               f"{ended.policy_step} policy / {ended.control_step} control steps")

    # execution ----------------------------------------------------------------------------------------
    def _make_step_timer(self, period_ns: int) -> None:
        if self._step_timer is not None:
            self.destroy_timer(self._step_timer)
        self._period_ns = period_ns
        wall_period = period_ns / 1e9 / self.realtime_factor if self.realtime_factor > 0 else 0.0
        self._step_timer = self.create_timer(wall_period, self._on_step_timer, clock=self.steady)
        self._step_timer.cancel()

    def _stop_stepping(self) -> None:
        self._unanswered = []
        if self._step_timer is not None:
            self._step_timer.cancel()

    def _on_action(self, msg: ActionCommand) -> None:
        started = self.timed()
        self.tick("action", self.now_ns())
        assert self.session is not None
        try:
            self.session.accept(msg.rollout_id, msg.step, msg.action_space, msg.num_actions, msg.action_dim,
                                floats_of(msg.data), msg.observation_history)
        except InputRejected as error:
            self.reject(error)
            return
        self._unanswered = []
        self._execute_step()  # the first action at once, the others on the step timer
        if self.session.rollout is not None:
            self._step_timer.reset()
        self.record_latency(started)

    def _on_step_timer(self) -> None:
        if self.session is not None and self.session.busy:
            self._execute_step()
            return
        self._step_timer.cancel()
        if self.session is not None and self.session.rollout is not None:
            self._publish_tick(self._stamp_ns())  # the last action's control step elapsed: policy step boundary

    def _execute_step(self) -> None:
        assert self.session is not None
        try:
            ended = self.session.execute_one()
        except Exception as error:  # noqa: BLE001 - a simulation error ends the rollout, never the node
            self.reject(InputRejected(INTERNAL, f"simulation step failed: {error!r}"))
            ended = self.session.end("error")
        self.sim_ns += self._period_ns
        self.tick("control_step", self.now_ns())
        self._publish_clock()
        stamp = self._stamp_ns()
        self._publish_joint_state(stamp)
        if ended is not None:
            self._stop_stepping()
            self._publish_end(ended, stamp)
        elif self.session.observation_due:
            for pub, msg in self._observation(stamp):
                pub.publish(msg)
            self.tick("history_observation", self.now_ns())

    # publishing ---------------------------------------------------------------------------------------
    def _stamp_ns(self) -> int:
        """Stamp of what is published now: simulated time in sim-time mode, else the node clock."""
        return self.sim_ns if self.sim_time else self.now_ns()

    def _publish_clock(self) -> None:
        if self._clock_pub is not None:
            self._clock_pub.publish(Clock(clock=to_stamp(self.sim_ns)))

    def _publish_joint_state(self, stamp: int) -> None:
        assert self.session is not None
        position, velocity = self.session.joint_state()
        msg = JointState(name=list(JOINT_NAMES), position=position.tolist(), velocity=velocity.tolist())
        msg.header.stamp = to_stamp(stamp)
        self._joint_pub.publish(msg)

    def _publish_tick(self, stamp: int) -> None:
        """The observation of a policy step: joint states, both images, proprioception; one stamp."""
        self._publish_joint_state(stamp)
        parts = self._observation(stamp)
        for pub, msg in parts:
            pub.publish(msg)
        self._unanswered, self._unanswered_since = parts, self.steady.now().nanoseconds
        self.tick("observation", self.now_ns())

    def _observation(self, stamp: int) -> list[tuple[Any, Any]]:
        """The current observation's messages (both images, proprioception), stamped ``stamp``, with their
        publishers."""
        assert self.session is not None and self.session.rollout is not None
        obs = self.session.observation()
        parts: list[tuple[Any, Any]] = []
        for key, pub in self._image_pubs.items():
            image = obs[key]
            msg = Image(height=image.shape[0], width=image.shape[1], encoding="rgb8", is_bigendian=0,
                        step=image.shape[1] * 3, data=image.tobytes())
            msg.header.stamp = to_stamp(stamp)
            msg.header.frame_id = CAMERAS[key]
            parts.append((pub, msg))
        proprio = JointState(name=list(PROPRIO_NAMES[self.session.rollout.task]), position=obs["proprio"].tolist())
        proprio.header.stamp = to_stamp(stamp)
        parts.append((self._proprio_pub, proprio))
        return parts

    def _on_resend(self) -> None:
        """Re-publish the tick whose command has not arrived (see the module docstring)."""
        now = self.steady.now().nanoseconds
        if not self._unanswered or now - self._unanswered_since < self._resend_ns:
            return
        for pub, msg in self._unanswered:
            pub.publish(msg)
        self._unanswered_since = now
        self.observation_resends += 1

    def _on_idle(self) -> None:
        """Keep /joint_states (and /clock) alive while the world waits for the policy."""
        if self.session is None or self.session.busy:
            return
        self._publish_clock()
        if self.session.env is not None:
            self._publish_joint_state(self._stamp_ns())

    # diagnostics --------------------------------------------------------------------------------------
    def diagnostic_values(self) -> dict[str, str]:
        rollout = self.session.rollout if self.session is not None else None
        env = self.session.env if self.session is not None else None
        values = {
            "mode": "fast" if self.realtime_factor <= 0 else f"realtime x{self.realtime_factor:g}",
            "sim_time_s": f"{self.sim_ns / 1e9:.3f}",
            "rollouts_started": str(self.session.started if self.session is not None else 0),
            "rollout_id": str(rollout.rollout_id) if rollout else "",
            "observation_resends": str(self.observation_resends),
        }
        if rollout is not None and env is not None:
            values |= {"task": rollout.task, "scenario": rollout.scenario, "seed": str(rollout.seed),
                       "policy_step": str(rollout.policy_step), "control_step": str(env.control_step)}
        values |= {f"ended.{reason}": str(n) for reason, n in sorted(self.ended.items())}
        return values


#: The node class, for in-process launching.
NODE_CLASS = BridgeNode


def main(args: list[str] | None = None) -> int:
    """Entry point: ``python -m sim_bridge.bridge_node --ros-args ...``."""
    return run_reported("bridge_node", run_node, BridgeNode, args)


if __name__ == "__main__":
    sys.exit(main())
