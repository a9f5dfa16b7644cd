"""Starting the suite: launch files (:mod:`.config`: reading, writing), the one way to adapt one
(:mod:`.overrides`: parameters, node selection, sim time), and running its nodes (:mod:`.processes`:
one OS process per node, or all in one). ``fiper launch`` is :mod:`fiper_ros.commands.launch`.
"""
from __future__ import annotations

from fiper_ros.launcher.errors import LaunchError

__all__ = ["LaunchError", "config", "errors", "overrides", "processes"]
