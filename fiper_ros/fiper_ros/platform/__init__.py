"""The process and middleware platform every ROS process of the project stands on, below the nodes, the launcher
and the clients that all use it:

- :mod:`.process`: running nodes in a process (init, the executor, spin, a bounded clean shutdown on SIGINT /
  SIGTERM), the suite's Fast DDS discovery profile, the process' age.
- :mod:`.dds`: DDS isolation (a ROS domain of one's own, discovery on loopback), child processes that die with
  their parent, interrupting a process group.
- :mod:`.shm`: Fast DDS shared-memory hygiene (the ``/dev/shm`` files of dead processes removed).
- :mod:`.errors`: :class:`PlatformError`, what every error of the platform derives from.
"""
from __future__ import annotations

from fiper_ros.platform.errors import PlatformError

__all__ = ["PlatformError", "dds", "errors", "process", "shm"]
