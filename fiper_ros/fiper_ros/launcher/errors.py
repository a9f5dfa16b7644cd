"""The launcher's user error: a launch file, a launch argument or an override the launcher refuses."""
from __future__ import annotations

from fiper_ros.errors import FiperError


class LaunchError(FiperError):
    """The launch file is unusable (the message names the file, the entry and why, on one line)."""
