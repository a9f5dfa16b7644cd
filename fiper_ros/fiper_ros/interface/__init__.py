"""The suite's interface on the wire: topic names and types, QoS, message constants, msg <-> numpy.

Everything a node, a bag tool or a client needs to agree on lives here once. Only :mod:`.qos` imports
rclpy (it builds the rclpy profiles from :mod:`.qos_spec`); the other modules need only the generated
``fiper_msgs`` classes, so reading and writing bags works without rclpy.

- :mod:`.topics`: topic names, their message types and offered QoS, the Panda arm joint names.
- :mod:`.qos_spec`: the QoS of every stream as plain values (docs/alarm-contract.md).
- :mod:`.qos`: the same profiles as rclpy ``QoSProfile`` objects.
- :mod:`.messages`: state and outcome names of the message codes, message classes by type name.
- :mod:`.conversions`: message <-> numpy array conversions.
- :mod:`.cdr`: the wire codec: messages as CDR bytes read and written without the generated classes (the nodes'
  hot topics).
"""
from __future__ import annotations

__all__ = ["cdr", "conversions", "messages", "qos", "qos_spec", "topics"]
