"""The core's user error: what every error of :mod:`fiper_ros.core` derives from."""
from __future__ import annotations

from fiper_ros.errors import FiperError


class CoreError(FiperError):
    """Input the method refuses: a calibration, a model file, rollouts or scores that are missing, malformed or do not fit."""


class ChoiceError(CoreError):
    """A name the core does not offer: an unknown detector (or one a calibration cannot declare), combine or
    profile; the one-line message names what it offers."""
