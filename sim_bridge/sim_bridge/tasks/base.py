"""Common episode machinery of all tasks: model building, reset, stepping, observations, rendering.

A task subclass samples its layout, adds its objects to the scene spec, turns an action into actuator
targets and decides success and failure. One ``step`` is one control step (``control_hz``); a policy
step executes ``exec_steps`` control steps of an action chunk of length ``horizon``.
"""
from __future__ import annotations

import abc
from typing import Any, ClassVar

import mujoco
import numpy as np

from ..ik import DiffIK
from ..render import CameraRenderer
from ..robot import ARM_JOINTS, FINGER_JOINTS, FINGER_MAX, GRIPPER_ACTUATORS, TCP_SITE
from ..scenarios import Scenario, knob_values, layout_rng, scene_params
from ..scene import TIMESTEP, build_scene

Obs = dict[str, np.ndarray]
OFF_TABLE_Z = -0.05
"""An object whose centre drops below this height [m] has left the table top."""


class TaskEnv(abc.ABC):
    """Base class of the Sorting, Stacking and PushT environments.

    Attributes:
        scenario: The episode's scenario.
        seed: The episode's seed; with ``scenario`` it fixes the whole episode.
        knobs: Knob values of this episode (see ``scenarios.knob_values``).
        model, data: MuJoCo model and state.
    """

    name: ClassVar[str]
    action_dim: ClassVar[int]
    proprio_dim: ClassVar[int]
    horizon: ClassVar[int]
    exec_steps: ClassVar[int]
    max_policy_steps: ClassVar[int]
    control_hz: ClassVar[float] = 10.0

    def __init__(self, scenario: Scenario, seed: int, images: bool = True) -> None:
        """Build the episode's model.

        Args:
            scenario: Scenario of this task.
            seed: Episode seed.
            images: Render camera images into observations; ``False`` leaves out the image keys
                (faster, e.g. to measure expert success rates).
        """
        if scenario.task != self.name:
            raise ValueError(f"scenario {scenario.name!r} belongs to {scenario.task}, not {self.name}")
        self.scenario = scenario
        self.seed = int(seed)
        self.knobs = knob_values(scenario, self.seed)
        self._sample_layout(layout_rng(self.seed))
        spec = build_scene(scene_params(self.knobs))
        self._add_objects(spec)
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        self.ik = DiffIK(self.model)
        self._cameras = CameraRenderer(self.model) if images else None
        self._arm_qpos = np.array([self.model.joint(j).qposadr[0] for j in ARM_JOINTS])
        self._finger_qpos = np.array([self.model.joint(j).qposadr[0] for j in FINGER_JOINTS])
        self._arm_act = np.array([self.model.actuator(j).id for j in ARM_JOINTS])
        self._gripper_act = np.array([self.model.actuator(a).id for a in GRIPPER_ACTUATORS])
        self._tcp = self.model.site(TCP_SITE).id
        self._substeps = int(round(1.0 / (self.control_hz * TIMESTEP)))
        self.q_cmd = np.zeros(7)
        self.control_step = 0
        self._success = False
        self._failed = False

    # ----------------------------------------------------------------- task interface
    @abc.abstractmethod
    def _sample_layout(self, rng: np.random.Generator) -> None:
        """Draw the episode's object poses, sizes and targets (uses ``self.knobs``)."""

    @abc.abstractmethod
    def _add_objects(self, spec: mujoco.MjSpec) -> None:
        """Add the task's objects and markers to ``spec``."""

    @abc.abstractmethod
    def _initial_arm(self) -> tuple[np.ndarray, float]:
        """Return the initial arm joint positions (7,) and finger opening [m] per finger."""

    @abc.abstractmethod
    def _place_objects(self) -> None:
        """Write the objects' initial poses into ``self.data.qpos``."""

    @abc.abstractmethod
    def _apply_action(self, action: np.ndarray) -> None:
        """Turn a (validated) action into ``self.q_cmd`` and the gripper target."""

    @abc.abstractmethod
    def _evaluate(self) -> tuple[bool, bool]:
        """Return ``(success, failed)`` for the current state."""

    @abc.abstractmethod
    def state(self) -> dict[str, Any]:
        """Privileged state for scripted experts (object poses, targets, EE pose, ...)."""

    @abc.abstractmethod
    def _proprio(self) -> np.ndarray:
        """Proprioceptive observation (float32, ``proprio_dim``)."""

    # ----------------------------------------------------------------- public API
    @property
    def max_control_steps(self) -> int:
        """Episode time limit in control steps (``max_policy_steps * exec_steps``)."""
        return self.max_policy_steps * self.exec_steps

    @property
    def success(self) -> bool:
        """Whether the task has been completed."""
        return self._success

    @property
    def failed(self) -> bool:
        """Whether an unrecoverable failure happened (e.g. an object left the table)."""
        return self._failed

    @property
    def done(self) -> bool:
        """Whether the episode is over (success, failure or time limit)."""
        return self._success or self._failed or self.control_step >= self.max_control_steps

    def reset(self) -> Obs:
        """Restore the episode's initial state and return the first observation."""
        mujoco.mj_resetData(self.model, self.data)
        q_arm, finger = self._initial_arm()
        self.q_cmd = q_arm.copy()
        self.data.qpos[self._arm_qpos] = q_arm
        self.data.qpos[self._finger_qpos] = finger
        self.data.ctrl[self._arm_act] = q_arm
        self.data.ctrl[self._gripper_act] = finger
        self._place_objects()
        mujoco.mj_forward(self.model, self.data)
        self.control_step = 0
        self._success, self._failed = self._evaluate()
        return self.observation()

    def step(self, action: np.ndarray) -> tuple[Obs, bool, dict[str, Any]]:
        """Apply one action for one control step.

        Returns:
            ``(observation, done, info)`` with ``info`` keys ``success``, ``failed``, ``timeout``,
            ``control_step``.
        """
        if self.done:
            raise RuntimeError("episode is over; call reset()")
        action = np.asarray(action, dtype=float)
        if action.shape != (self.action_dim,) or not np.all(np.isfinite(action)):
            raise ValueError(f"{self.name} expects a finite action of shape ({self.action_dim},), got {action}")
        self._apply_action(action)
        self.data.ctrl[self._arm_act] = self.q_cmd
        mujoco.mj_step(self.model, self.data, nstep=self._substeps)
        self.control_step += 1
        self._success, self._failed = self._evaluate()
        return self.observation(), self.done, self.info()

    def step_chunk(self, actions: np.ndarray) -> tuple[Obs, bool, dict[str, Any]]:
        """Execute the first ``exec_steps`` actions of a chunk (H, D), stopping early when done."""
        actions = np.asarray(actions, dtype=float)
        if actions.ndim != 2 or actions.shape[0] < self.exec_steps:
            raise ValueError(f"expected a chunk of at least {self.exec_steps} actions, got {actions.shape}")
        for action in actions[: self.exec_steps]:
            obs, done, info = self.step(action)
            if done:
                break
        return obs, done, info

    def info(self) -> dict[str, Any]:
        """Episode status flags."""
        timeout = not (self._success or self._failed) and self.control_step >= self.max_control_steps
        return {"success": self._success, "failed": self._failed, "timeout": timeout,
                "control_step": self.control_step}

    def observation(self) -> Obs:
        """Current observation: ``wrist_rgb``, ``third_rgb`` (if images are on) and ``proprio``."""
        obs = self.render() if self._cameras is not None else {}
        obs["proprio"] = self._proprio().astype(np.float32)
        return obs

    def render(self) -> dict[str, np.ndarray]:
        """Images of both cameras, ``{"wrist_rgb", "third_rgb"}`` -> uint8 (96, 96, 3)."""
        if self._cameras is None:
            raise RuntimeError("environment was created with images=False")
        return self._cameras.render(self.data)

    def close(self) -> None:
        """Release the renderer."""
        if self._cameras is not None:
            self._cameras.close()
            self._cameras = None

    def __enter__(self) -> "TaskEnv":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ----------------------------------------------------------------- helpers for subclasses
    def tcp_pos(self) -> np.ndarray:
        """Current TCP position (3,)."""
        return self.data.site_xpos[self._tcp].copy()

    def gripper_width(self) -> float:
        """Current distance between the fingers [m]."""
        return float(self.data.qpos[self._finger_qpos].sum())

    def arm_qpos(self) -> np.ndarray:
        """Current arm joint positions (7,)."""
        return self.data.qpos[self._arm_qpos].copy()

    def set_gripper(self, opening: float) -> None:
        """Command the finger opening as a fraction in [0, 1] of the full stroke."""
        self.data.ctrl[self._gripper_act] = FINGER_MAX * float(np.clip(opening, 0.0, 1.0))

    def set_free_pose(self, joint: str, pos: np.ndarray, quat: np.ndarray) -> None:
        """Write position and quaternion of the free joint ``joint`` into ``qpos``."""
        adr = self.model.joint(joint).qposadr[0]
        self.data.qpos[adr : adr + 3] = pos
        self.data.qpos[adr + 3 : adr + 7] = quat

    def free_pose(self, joint: str) -> tuple[np.ndarray, np.ndarray]:
        """Position and quaternion of the free joint ``joint``."""
        adr = self.model.joint(joint).qposadr[0]
        return self.data.qpos[adr : adr + 3].copy(), self.data.qpos[adr + 3 : adr + 7].copy()
