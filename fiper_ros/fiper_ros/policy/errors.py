"""The policies' user error: a model folder that cannot be read, training input that does not fit."""
from __future__ import annotations

from fiper_ros.errors import FiperError


class PolicyError(FiperError):
    """A policy model folder that is missing, unreadable or not a policy of this code; demonstrations or a training
    schedule that training refuses."""
