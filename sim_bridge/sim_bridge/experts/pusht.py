"""Scripted PushT expert: a sequence of straight pushes chosen with a quasi-static pushing model.

Before each push the expert samples contact points on the T's outline (pushing along the inward
normal) and push lengths, predicts the T's motion for each with the ellipsoidal limit-surface model
under sticking contact, and picks the push that brings the T closest to the goal pose (plus a small
travel cost). It then plans a path around the T to the pre-contact point, pushes slowly, backs off
and replans. A seed-drawn side preference (contacts on the left or right half of the T) gives the
demonstrations their multimodality in the approach side.
"""
from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np

from ..planar import Rect, plan_path, step_towards
from ..tasks.planar import clip_to_workspace, in_workspace
from ..tasks.pusht import TShape, coverage_many
from ..transforms import wrap_angle

PUSHER_RADIUS = 0.018
APPROACH_STEP = 0.03
PUSH_STEP = 0.012
PRE_GAP = 0.02
RETREAT = 0.025
PUSH_LENGTHS = (0.01, 0.02, 0.04, 0.07, 0.11)
POINT_SPACING = 0.012
ROT_WEIGHT = 0.15
"""Length scale turning the orientation error [rad] into metres in the pose cost."""
TRAVEL_WEIGHT = 0.004
SIDE_PENALTY = 0.15
NEAR_COVERAGE = 0.6
NEAR_ANGLE = 0.3
"""From this coverage on, and within this angle [rad] of the goal, pushes are ranked by their predicted
coverage instead of the pose cost (coverage alone has local optima, e.g. a T turned by 180 degrees)."""
NEAR_TRAVEL_WEIGHT = 0.05
_SIM_STEPS = 8


def _outline(shape: TShape) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Edges (start, end, outward normal) of the T's outline in its COM frame."""
    (bc, bh), (sc, sh) = shape.parts()
    top, bottom_bar = bc[1] + bh[1], bc[1] - bh[1]
    stem_bottom = sc[1] - sh[1]
    corners = [
        (-bh[0], top), (bh[0], top), (bh[0], bottom_bar), (sh[0], bottom_bar),
        (sh[0], stem_bottom), (-sh[0], stem_bottom), (-sh[0], bottom_bar), (-bh[0], bottom_bar),
    ]
    pts = [np.array(c) for c in corners]
    edges = []
    for i, start in enumerate(pts):
        end = pts[(i + 1) % len(pts)]
        tangent = (end - start) / np.linalg.norm(end - start)
        edges.append((start, end, np.array([-tangent[1], tangent[0]])))  # corners run clockwise
    return edges


def _predict(pose: np.ndarray, contact: np.ndarray, push_dir: np.ndarray, length: float, c2: float) -> np.ndarray:
    """Pose after pushing the contact point (COM frame) along world ``push_dir`` by ``length``."""
    x, y, yaw = pose
    ds = length / _SIM_STEPS
    u = np.array([-contact[1], contact[0]])
    a_inv = np.linalg.inv(np.eye(2) + np.outer(u, u) / c2)
    for _ in range(_SIM_STEPS):
        c, s = np.cos(yaw), np.sin(yaw)
        v_body = np.array([c * push_dir[0] + s * push_dir[1], -s * push_dir[0] + c * push_dir[1]])
        force = a_inv @ v_body
        omega = u @ force / c2
        x += (c * force[0] - s * force[1]) * ds
        y += (s * force[0] + c * force[1]) * ds
        yaw += omega * ds
    return np.array([x, y, yaw])


def pose_cost(pose: np.ndarray, goal: np.ndarray) -> float:
    """Squared planar distance of two poses, the angle weighted by ``ROT_WEIGHT``."""
    return float(np.sum((pose[:2] - goal[:2]) ** 2) + (ROT_WEIGHT * wrap_angle(pose[2] - goal[2])) ** 2)


class PushTExpert:
    """Privileged-state expert of the PushT task; ``act(state)`` returns the next planar TCP target."""

    def __init__(self, seed: int) -> None:
        """Draw the preferred contact side from ``seed``."""
        rng = np.random.default_rng([seed, 3])
        self.side = 1.0 if rng.random() < 0.5 else -1.0
        self._plan: deque[tuple[np.ndarray, float]] = deque()

    def act(self, state: dict[str, Any]) -> np.ndarray:
        """Next action for the privileged ``state`` of ``PushTEnv.state()``."""
        pusher = state["ee_cmd"]
        if not self._plan:
            self._plan = self._new_plan(state)
        waypoint, speed = self._plan[0]
        target = step_towards(pusher, waypoint, speed)
        if np.linalg.norm(target - waypoint) < 1e-6:
            self._plan.popleft()
        return target

    def _new_plan(self, state: dict[str, Any]) -> deque[tuple[np.ndarray, float]]:
        """Choose the next push and return its waypoints with per-step speeds."""
        shape: TShape = state["shape"]
        pose, goal, pusher = state["t_pose"], state["goal"], state["ee_cmd"]
        frame = Rect(pose[:2], np.zeros(2), float(pose[2]))
        rects = shape.rects(pose)
        c2 = float(np.mean(np.sum(shape.raster(0.005) ** 2, axis=1)))
        candidates: list[tuple[np.ndarray, np.ndarray, float]] = []
        predicted, penalties, travels = [], [], []
        for start, end, normal in _outline(shape):
            count = max(1, int(np.linalg.norm(end - start) // POINT_SPACING))
            for t in (np.arange(count) + 0.5) / count:
                local = start + t * (end - start)
                contact = frame.to_world(local)
                push_dir = -frame.to_world(normal) + frame.center
                pre = contact - push_dir * (PUSHER_RADIUS + PRE_GAP)
                if any(r.contains(pre, PUSHER_RADIUS + 0.004) for r in rects) or not in_workspace(pre):
                    continue
                for length in PUSH_LENGTHS:
                    if not in_workspace(contact + push_dir * (length - PUSHER_RADIUS)):
                        continue
                    candidates.append((pre, push_dir, length))
                    predicted.append(_predict(pose, local, push_dir, length, c2))
                    penalties.append(SIDE_PENALTY if np.sign(local[0]) == -self.side else 0.0)
                    travels.append(float(np.linalg.norm(pre - pusher)))
        if not candidates:
            return deque([(clip_to_workspace(goal[:2] - 0.3 * (goal[:2] - pusher)), APPROACH_STEP)])
        if state["coverage"] >= NEAR_COVERAGE and abs(wrap_angle(pose[2] - goal[2])) < NEAR_ANGLE:
            # Close to the goal the objective itself ranks the pushes.
            cost = 1.0 - coverage_many(shape, np.array(predicted), state["goal_points"])
            travel_weight = NEAR_TRAVEL_WEIGHT
        else:
            cost = np.array([pose_cost(p, goal) for p in predicted])
            travel_weight = TRAVEL_WEIGHT
        score = cost * (1.0 + np.array(penalties)) + travel_weight * np.array(travels)
        pre, push_dir, length = candidates[int(np.argmin(score))]
        plan: deque[tuple[np.ndarray, float]] = deque(
            (p, APPROACH_STEP) for p in plan_path(pusher, pre, rects, PUSHER_RADIUS + 0.006, in_workspace)
        )
        end_point = pre + push_dir * (PRE_GAP + length)
        plan.append((end_point, PUSH_STEP))
        plan.append((end_point - push_dir * RETREAT, APPROACH_STEP))
        return plan
