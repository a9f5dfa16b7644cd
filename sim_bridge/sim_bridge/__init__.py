"""MuJoCo Franka stand-in for fiper-ros: the tasks, the robot, the ROS bridge node, and the closed-loop
episodes of a policy in the simulator (:mod:`.closed_loop`, which ``fiper collect`` runs in-process)."""
from __future__ import annotations

__all__ = ["bridge_node", "bridge_session", "cli", "closed_loop", "collect_runner", "demos", "env", "evaluate",
           "experts", "figures", "ik", "multimodality", "planar", "policy_evaluation", "render", "robot", "scenarios",
           "scene", "tasks", "transforms"]
