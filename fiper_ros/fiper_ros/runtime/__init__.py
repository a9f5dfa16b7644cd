"""Streaming logic of the node shells, without rclpy: input validation, rollout tracking, score
matching and the alarm state machine, latency and rate statistics.

The nodes translate messages to the plain values these classes take, so every rule here is tested
without DDS and the same rules serve the live nodes and the bag replay.
"""
from __future__ import annotations

__all__ = ["alarm", "halt_delivery", "joint_history", "observation_sync", "pending", "rollout_gate", "rollout_tracker",
           "stats", "supervision", "trusted_publishers", "validation", "wiring"]
