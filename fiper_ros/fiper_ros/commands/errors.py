"""The commands' user error: a command-line flag or combination of flags a ``fiper`` sub-command refuses."""
from __future__ import annotations

from fiper_ros.errors import FiperError


class UsageError(FiperError):
    """A flag value or combination a sub-command refuses (the message names the flag)."""
