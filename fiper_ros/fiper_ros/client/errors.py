"""The client's user error: what talking to a running suite raises."""
from __future__ import annotations

from fiper_ros.errors import FiperError


class ClientError(FiperError):
    """A suite that cannot be started, reached or driven as asked."""
