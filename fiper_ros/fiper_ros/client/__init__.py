"""Talking to a running suite over DDS (rclpy): the session of a tool, capturing and recording topics, the
black box, the bag player, the suite process a tool starts, and the operator that drives a live sim suite.

- :mod:`.ros_session`: a private rclpy context, node and executor with the project's network rule.
- :mod:`.suite_process`: ``fiper launch`` of a suite in a child process.
- :mod:`.capture`, :mod:`.record`, :mod:`.snapshot`: topics into bags (``fiper record``, ``fiper snapshot``).
- :mod:`.replay`: bags into the suite (``fiper replay``'s player).
- :mod:`.verdicts`: a live suite's verdicts per rollout and the TPR / TNR table (``fiper launch --summary``).
- :mod:`.driver`, :mod:`.trace`, :mod:`.figure`: the operator of a live sim suite, what it saw of a rollout,
  and the figure of it (``fiper demo``, ``fiper collect --ros``); :mod:`.live_collect`: ``fiper collect --ros``.
"""
from __future__ import annotations

from fiper_ros.client.errors import ClientError

__all__ = ["ClientError", "capture", "driver", "errors", "figure", "live_collect", "record", "replay", "ros_session",
           "snapshot", "suite_process", "trace", "verdicts"]
