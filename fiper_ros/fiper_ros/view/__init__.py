"""The live view of the suite in Foxglove (docs/view.md), without rclpy: what the view node serves and how.

The view node (:mod:`fiper_ros.nodes.view_node`, ``fiper view``) subscribes to the suite's topics and hands each
message to these modules, which never see DDS:

- :mod:`.translate`: a ROS 2 message as the JSON Foxglove reads (field for field, as Foxglove shows the same
  message from a bag), its JSON Schema, and a camera image as a ``foxglove.RawImage``.
- :mod:`.server`: the Foxglove WebSocket server (the ``foxglove-sdk``): one channel per topic, a bounded
  queue per client that drops the oldest message for a client that does not keep up.
- :mod:`.layout`: the shipped Foxglove layout (``fiper_ros/config/foxglove/fiper.layout.json``), made from
  the SDK's layout classes.
"""
from __future__ import annotations

__all__ = ["layout", "server", "translate"]
