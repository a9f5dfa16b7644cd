"""Bag I/O without rclpy: the FIPER bag schema, reading and writing rosbag2 / MCAP bags, unfinished bags,
and bags <-> core :class:`~fiper_ros.core.rollout.Rollout` records (docs/bags.md).

Bags are rosbag2 directories (``metadata.yaml`` + one MCAP file, format version 9) written with
``rosbags``; nothing here needs ``ros2 bag``, which the pip wheels do not provide, nor rclpy: messages are
(de)serialised with the ``rosbags`` typestore of the ``fiper_msgs`` definitions.

- :mod:`.schema`: ``custom_data`` (:class:`~.schema.BagInfo`), offered QoS, the typestore, CDR.
- :mod:`.reader`, :mod:`.writer`, :mod:`.storage`: reading, writing, the files of a bag on disk.
- :mod:`.chunks`: how a live bag goes to disk. :mod:`.atomic`: outputs that appear complete or not at all.
- :mod:`.recover`: unfinished bags. :mod:`.errors`: :class:`BagError`, the package's error.
- :mod:`.rollout_bags`: rollouts <-> bags. :mod:`.collect_index`: the index of a ``fiper collect`` folder.
"""
from __future__ import annotations

from fiper_ros.bagio.errors import BagError

__all__ = ["BagError", "atomic", "chunks", "collect_index", "errors", "reader", "recover", "rollout_bags", "schema",
           "storage", "writer"]
