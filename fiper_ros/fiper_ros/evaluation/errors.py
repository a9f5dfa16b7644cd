"""The offline evaluation's user error: what every error of :mod:`fiper_ros.evaluation` derives from."""
from __future__ import annotations

from fiper_ros.errors import FiperError


class EvaluationError(FiperError):
    """Data, a calibration or settings the offline evaluation or the replay oracle refuses."""


class SettingsError(EvaluationError):
    """Evaluation settings the engine refuses before any work: a method, a combination, the sweep's grid or a
    protocol option (the message names the setting, and the ``fiper evaluate`` flag where it has one)."""
