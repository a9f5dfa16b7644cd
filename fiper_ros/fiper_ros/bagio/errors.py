"""The bag tools' user error: what every error of :mod:`fiper_ros.bagio` derives from."""
from __future__ import annotations

from fiper_ros.errors import FiperError


class BagError(FiperError):
    """A bag (or a file a bag command reads or writes) is missing, malformed or does not fit."""
