"""Planar geometry for the scripted experts: oriented rectangles and shortest paths around them.

Paths are found on a visibility graph whose nodes are the corners of the obstacles inflated by a
little more than the clearance; an edge is usable if it does not cut any obstacle inflated by the
clearance. Obstacles that contain the start (or goal) point are ignored for edges leaving it (or
entering it), so a pusher touching an object can still leave it.
"""
from __future__ import annotations

import heapq
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

_CORNER_FACTOR = 1.25
_EPS = 1e-9


@dataclass(frozen=True)
class Rect:
    """Rectangle with centre (2,), half extents (2,) and rotation ``yaw`` [rad] in the plane."""

    center: np.ndarray
    half: np.ndarray
    yaw: float

    def to_local(self, points: np.ndarray) -> np.ndarray:
        """Express world points (..., 2) in the rectangle's frame."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        rel = np.asarray(points) - self.center
        return np.stack([c * rel[..., 0] + s * rel[..., 1], -s * rel[..., 0] + c * rel[..., 1]], axis=-1)

    def to_world(self, points: np.ndarray) -> np.ndarray:
        """Express rectangle-frame points (..., 2) in the world frame."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        pts = np.asarray(points)
        return self.center + np.stack([c * pts[..., 0] - s * pts[..., 1], s * pts[..., 0] + c * pts[..., 1]], axis=-1)

    def contains(self, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Whether points (..., 2) lie inside the rectangle grown by ``margin``."""
        local = np.abs(self.to_local(points))
        return np.all(local <= self.half + margin, axis=-1)

    def corners(self, margin: float = 0.0) -> np.ndarray:
        """Corners (4, 2) of the rectangle grown by ``margin``, counter-clockwise."""
        hx, hy = self.half + margin
        return self.to_world(np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]]))

    def blocks_segment(self, start: np.ndarray, end: np.ndarray, margin: float) -> bool:
        """Whether the segment ``start``-``end`` passes through the rectangle grown by ``margin``."""
        a, b = self.to_local(start), self.to_local(end)
        direction = b - a
        t0, t1 = 0.0, 1.0
        for axis in range(2):
            bound = self.half[axis] + margin
            if abs(direction[axis]) < _EPS:
                if abs(a[axis]) >= bound:
                    return False
                continue
            ta = (-bound - a[axis]) / direction[axis]
            tb = (bound - a[axis]) / direction[axis]
            t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
            if t1 - t0 <= 1e-6:
                return False
        return True


def plan_path(
    start: np.ndarray,
    goal: np.ndarray,
    obstacles: list[Rect],
    clearance: float,
    allowed: Callable[[np.ndarray], bool] | None = None,
) -> list[np.ndarray]:
    """Shortest collision-free polyline from ``start`` to ``goal`` (waypoints after ``start``).

    Args:
        allowed: Optional test of intermediate waypoints (e.g. reachability); others are not used.

    Falls back to the straight line ``[goal]`` when the graph has no path.
    """
    start, goal = np.asarray(start, dtype=float), np.asarray(goal, dtype=float)
    ignore_start = {i for i, o in enumerate(obstacles) if o.contains(start, clearance)}
    ignore_goal = {i for i, o in enumerate(obstacles) if o.contains(goal, clearance)}
    corners = [c for o in obstacles for c in o.corners(_CORNER_FACTOR * clearance)]
    corners = [
        c for c in corners
        if not any(o.contains(c, clearance) for o in obstacles) and (allowed is None or allowed(c))
    ]
    nodes = [start, goal, *corners]

    def free(i: int, j: int) -> bool:
        skip = (ignore_start if 0 in (i, j) else set()) | (ignore_goal if 1 in (i, j) else set())
        return not any(
            o.blocks_segment(nodes[i], nodes[j], clearance) for k, o in enumerate(obstacles) if k not in skip
        )

    dist = {0: 0.0}
    previous: dict[int, int] = {}
    queue = [(0.0, 0)]
    done: set[int] = set()
    while queue:
        d, i = heapq.heappop(queue)
        if i in done:
            continue
        done.add(i)
        if i == 1:
            break
        for j in range(1, len(nodes)):
            if j in done or not free(i, j):
                continue
            nd = d + float(np.linalg.norm(nodes[j] - nodes[i]))
            if nd < dist.get(j, np.inf):
                dist[j], previous[j] = nd, i
                heapq.heappush(queue, (nd, j))
    if 1 not in previous:
        return [goal]
    path, node = [], 1
    while node != 0:
        path.append(nodes[node])
        node = previous[node]
    return path[::-1]


def step_towards(current: np.ndarray, target: np.ndarray, max_step: float) -> np.ndarray:
    """Move ``current`` towards ``target`` by at most ``max_step``."""
    delta = np.asarray(target) - current
    norm = np.linalg.norm(delta)
    return np.asarray(target, dtype=float) if norm <= max_step else current + delta * (max_step / norm)


def follow_path(current: np.ndarray, path: list[np.ndarray], max_step: float) -> np.ndarray:
    """Advance ``max_step`` along the polyline ``current`` -> ``path`` and return the new point."""
    point, budget = np.asarray(current, dtype=float), max_step
    for waypoint in path:
        gap = float(np.linalg.norm(waypoint - point))
        if gap >= budget:
            return step_towards(point, waypoint, budget)
        point, budget = np.asarray(waypoint, dtype=float), budget - gap
    return point
