"""PushT coverage and the experts' planar path planner."""
from __future__ import annotations

import numpy as np

from sim_bridge.planar import Rect, plan_path
from sim_bridge.tasks.pusht import BAR, STEM, TShape, coverage


def test_coverage_of_goal_pose_and_shifts() -> None:
    shape = TShape(BAR[0], BAR[1], STEM[0], STEM[1])
    goal = np.array([0.5, 0.0, np.pi / 4])
    points = Rect(goal[:2], np.zeros(2), goal[2]).to_world(shape.raster())
    area = BAR[0] * BAR[1] + STEM[0] * STEM[1]
    assert abs(len(points) * 0.0025**2 - area) / area < 0.02
    assert coverage(shape, goal, points) == 1.0
    assert 0.8 < coverage(shape, goal + [0.01, 0.0, 0.0], points) < 0.97
    assert coverage(shape, goal + [0.0, 0.0, np.pi], points) < 0.5
    assert coverage(shape, goal + [0.5, 0.0, 0.0], points) == 0.0


def test_path_avoids_obstacle() -> None:
    box = Rect(np.array([0.0, 0.0]), np.array([0.1, 0.05]), 0.3)
    start, goal = np.array([-0.3, 0.0]), np.array([0.3, 0.0])
    path = plan_path(start, goal, [box], clearance=0.02)
    assert np.allclose(path[-1], goal) and len(path) > 1
    points = np.concatenate([np.linspace(a, b, 50) for a, b in zip([start, *path[:-1]], path)])
    assert not box.contains(points, 0.019).any()
