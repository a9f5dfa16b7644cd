"""The bridge node's rollout logic without ROS: rollouts, command checks, execution, outcomes.

One :class:`BridgeSession` owns at most one running rollout (a :class:`TaskEnv` episode). A command
(the first ``n`` actions of a chunk) is checked and queued by :meth:`BridgeSession.accept`; the node
executes the queue one control step at a time with :meth:`BridgeSession.execute_one` and publishes an
observation when the queue is empty (the policy-step boundary). The environment renders nothing
itself: the session renders both cameras only for observations (once per policy step, not per
control step).
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from fiper_ros.runtime import validation
from fiper_ros.runtime.validation import BUSY, InputRejected

from .env import make_env
from .render import CameraRenderer
from .robot import ARM_JOINTS, FINGER_JOINTS
from .scenarios import get_scenario
from .tasks import Obs, TaskEnv

#: Action space of each task, as in ``fiper_msgs/ActionCommand.ACTION_SPACE_*``.
ACTION_SPACES: dict[str, str] = {"sorting": "ee_position", "stacking": "joint_velocity", "pusht": "ee_position"}
#: Names of the proprioception channels (``env.observation()["proprio"]``) per task.
PROPRIO_NAMES: dict[str, tuple[str, ...]] = {
    "sorting": ("tcp_x", "tcp_y", "tcp_z", "gripper_width"),
    "pusht": ("tcp_x", "tcp_y", "tcp_z", "gripper_width"),
    "stacking": ("tcp_x", "tcp_y", "tcp_z", "gripper_width", *ARM_JOINTS),
}
#: Joints of ``/joint_states``: the seven arm joints and both fingers.
JOINT_NAMES: tuple[str, ...] = (*ARM_JOINTS, *FINGER_JOINTS)

SUCCESS, FAILURE = "success", "failure"


@dataclass
class Rollout:
    """The running rollout."""

    rollout_id: int
    task: str
    scenario: str
    seed: int
    max_steps: int
    """The time limit in policy steps: the task's, or the session's lower cap."""
    policy_step: int = 0
    """Commands accepted so far (policy steps); the next command must carry this ``step``."""


@dataclass(frozen=True)
class Ended:
    """How a rollout ended."""

    rollout_id: int
    outcome: str
    """``"success"`` or ``"failure"``."""
    reason: str
    """``success``, ``failed`` (e.g. an object fell off the table), ``timeout``, ``halted``,
    ``aborted`` (a reset replaced it) or ``deactivated``."""
    policy_step: int
    """Commands accepted in the rollout."""
    control_step: int
    """Control steps executed in the rollout."""


def bridge_rollout_id(counter: int, seed: int) -> int:
    """Rollout id: the bridge run's rollout counter (from 1) in the high 32 bits, the seed's low 32 bits
    in the low 32 bits; unique within one run of the bridge and never 0."""
    return (counter << 32) | (int(seed) & 0xFFFFFFFF)


class BridgeSession:
    """Rollouts of the simulated tasks, fed with action commands one control step at a time."""

    def __init__(self, images: bool, max_policy_steps: int = 0) -> None:
        """``images``: render the wrist and third-person cameras into observations; ``max_policy_steps``:
        end every rollout after this many policy steps as a ``timeout`` failure, like
        ``run_episode(max_policy_steps=...)`` (0: the task's time limit only)."""
        self.images = images
        self.max_policy_steps = max_policy_steps
        self.env: TaskEnv | None = None
        self.rollout: Rollout | None = None
        self.started = 0
        self._renderer: CameraRenderer | None = None
        self._pending: deque[np.ndarray] = deque()
        #: Observations the last command asked for before its tick.
        self._history = 0
        self._qpos_adr = np.zeros(0, dtype=int)
        self._dof_adr = np.zeros(0, dtype=int)

    @property
    def busy(self) -> bool:
        """Whether actions of the last command are still waiting to be executed."""
        return bool(self._pending)

    def start(self, task: str, scenario: str, seed: int) -> tuple[Rollout, Ended | None]:
        """Build the episode ``(task, scenario, seed)`` and start a rollout.

        Returns:
            The new rollout and how the previous one ended (``aborted``), if one was running.

        Raises:
            ScenarioError: Unknown task or scenario (the running rollout, if any, keeps running).
        """
        get_scenario(task, scenario)  # a ScenarioError naming the known tasks / scenarios
        env = make_env(task, scenario, seed, images=False)
        aborted = self.end("aborted")
        self.close()
        self.env = env
        if self.images:
            self._renderer = CameraRenderer(env.model)
        self._qpos_adr = np.array([env.model.joint(j).qposadr[0] for j in JOINT_NAMES])
        self._dof_adr = np.array([env.model.joint(j).dofadr[0] for j in JOINT_NAMES])
        env.reset()
        self.started += 1
        limit = min(env.max_policy_steps, self.max_policy_steps) if self.max_policy_steps else env.max_policy_steps
        self.rollout = Rollout(bridge_rollout_id(self.started, seed), task, scenario, int(seed), limit)
        return self.rollout, aborted

    def end(self, reason: str) -> Ended | None:
        """End the running rollout as a failure (``halted``, ``aborted``, ...); None if none runs."""
        if self.rollout is None:
            return None
        return self._finish(FAILURE, reason)

    @property
    def observation_due(self) -> bool:
        """Whether the state the last control step left is one of the observations the command asked for
        before its tick (those of its last ``observation_history`` control steps before the tick's)."""
        return self.rollout is not None and 0 < len(self._pending) <= self._history

    def accept(self, rollout_id: int, step: int, action_space: str, num_actions: int, action_dim: int,
               data: np.ndarray, observation_history: int) -> None:
        """Check a command and queue its actions (``observation_history``: see :attr:`observation_due`).

        Raises:
            InputRejected: With reason ``unknown_rollout``, ``busy``, ``duplicate_step``,
                ``out_of_order_step``, ``action_space``, ``shape`` or ``non_finite``.
        """
        rollout, env = self.rollout, self.env
        if rollout is None or env is None:
            raise InputRejected(validation.UNKNOWN_ROLLOUT, f"rollout {rollout_id}: no rollout is running")
        if rollout_id != rollout.rollout_id:
            raise InputRejected(validation.UNKNOWN_ROLLOUT,
                                f"rollout {rollout_id} is not the running rollout {rollout.rollout_id}")
        if self._pending:
            raise InputRejected(BUSY, f"step {step}: {len(self._pending)} action(s) of step "
                                      f"{rollout.policy_step - 1} still executing")
        if step != rollout.policy_step:
            reason = validation.DUPLICATE_STEP if step < rollout.policy_step else validation.OUT_OF_ORDER_STEP
            raise InputRejected(reason, f"step {step}, expected step {rollout.policy_step}")
        expected_space = ACTION_SPACES[rollout.task]
        if action_space != expected_space:
            raise InputRejected(validation.ACTION_SPACE,
                                f"action space {action_space!r}, {rollout.task} expects {expected_space!r}")
        if action_dim != env.action_dim or not 0 < num_actions <= env.horizon:
            raise InputRejected(validation.SHAPE, f"{num_actions} x {action_dim} actions, {rollout.task} takes "
                                                  f"1..{env.horizon} x {env.action_dim}")
        actions = validation.action_batch(data, 1, num_actions, action_dim, num_actions)[0]
        self._pending.extend(actions.astype(np.float64))
        self._history = min(observation_history, num_actions - 1)
        rollout.policy_step += 1

    def execute_one(self) -> Ended | None:
        """Execute the next queued action for one control step; returns how the rollout ended, if it did."""
        assert self.env is not None and self.rollout is not None and self._pending
        env = self.env
        env.step(self._pending.popleft())
        if env.done:
            info = env.info()
            if info["success"]:
                return self._finish(SUCCESS, "success")
            return self._finish(FAILURE, "failed" if info["failed"] else "timeout")
        if self.max_policy_steps and not self._pending and self.rollout.policy_step >= self.rollout.max_steps:
            return self._finish(FAILURE, "timeout")  # the session's cap: the last command was executed
        return None

    def observation(self) -> Obs:
        """Current observation: ``wrist_rgb``, ``third_rgb`` (with images) and ``proprio``."""
        assert self.env is not None
        obs = self._renderer.render(self.env.data) if self._renderer is not None else {}
        obs["proprio"] = self.env.observation()["proprio"]
        return obs

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Positions and velocities of :data:`JOINT_NAMES` (arm joints, then fingers)."""
        assert self.env is not None
        return self.env.data.qpos[self._qpos_adr], self.env.data.qvel[self._dof_adr]

    def close(self) -> None:
        """Release the environment and the renderer (the rollout, if any, is dropped silently)."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self.env is not None:
            self.env.close()
            self.env = None
        self.rollout = None
        self._pending.clear()

    def _finish(self, outcome: str, reason: str) -> Ended:
        assert self.rollout is not None and self.env is not None
        ended = Ended(self.rollout.rollout_id, outcome, reason, self.rollout.policy_step, self.env.control_step)
        self.rollout = None
        self._pending.clear()
        return ended
