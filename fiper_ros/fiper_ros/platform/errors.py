"""The platform's user error: what the process and middleware set-up refuses."""
from __future__ import annotations

from fiper_ros.errors import FiperError


class PlatformError(FiperError):
    """An environment the process set-up refuses: a variable with a value it does not offer, no free ROS domain."""
